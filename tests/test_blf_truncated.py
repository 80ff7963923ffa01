"""A BLF log cut short fails the replay, as a cut .gz or .xz does: exit 2, the file and how far it got.

python-can's reader stops quietly where a BLF file stops, so a log cut in half replayed
as half a log, exit 0. The file header records the file's size and every object header
its object's; :mod:`canguard.io.blf_length` holds the file to them. The logs here are
written by python-can's own BLFWriter (small containers, so a short log has many) and
cut at several points: inside a compressed container, inside an object header, inside
the file header, and exactly between two objects (only the file header's size tells).
"""

from __future__ import annotations

import gzip
import struct
import subprocess
from pathlib import Path

import can
import pytest

from canguard.errors import LogFormatError
from canguard.io.logs import read_log
from checkout import REPO
from clikit import cli

ROBOT = REPO / "config" / "examples" / "robot_guard.yaml"
FILE_HEADER_SIZE = 144
OBJ = struct.Struct("<4sHHLL")


def write_blf(path: Path, messages: list[can.Message], **kwargs: object) -> Path:
    """``messages`` through python-can's BLFWriter into ``path``."""
    writer = can.BLFWriter(str(path), **kwargs)
    for msg in messages:
        writer.on_message_received(msg)
    writer.stop()
    return path


def objects(data: bytes) -> list[tuple[int, int]]:
    """(start, size) of every top-level object (log container) of a BLF file."""
    pos, found = FILE_HEADER_SIZE, []
    while pos < len(data):
        size = OBJ.unpack_from(data, pos)[3]
        found.append((pos, size))
        pos += size + size % 4
    return found


def robot_messages(n: int) -> list[can.Message]:
    """``n`` plain frames, 1 ms apart."""
    return [can.Message(timestamp=1_700_000_000 + i / 1000, arbitration_id=0x100 + i % 8, is_extended_id=False,
                        data=bytes([i % 256] * 8)) for i in range(n)]


@pytest.fixture
def whole(tmp_path: Path) -> Path:
    """3000 frames in 4-kB containers (about 36 of them)."""
    return write_blf(tmp_path / "whole.blf", robot_messages(3000), max_container_size=4096)


def cut(whole: Path, where: str) -> tuple[Path, int]:
    """A copy of ``whole`` cut at ``where``; the byte it ends at."""
    data = whole.read_bytes()
    objs = objects(data)
    at = {
        "mid container": objs[1][0] + 100,
        "mid object header": objs[2][0] + 7,
        "mid file header": 100,
        "between objects": objs[2][0],
    }[where]
    path = whole.with_name(f"cut-{where.replace(' ', '-')}.blf")
    path.write_bytes(data[:at])
    return path, at


def read_until_error(path: Path, blocks: bool) -> tuple[int, LogFormatError]:
    """Frames read (frame by frame or as the replay's blocks) before the LogFormatError that must come."""
    frames = read_log(path)
    n = 0
    with pytest.raises(LogFormatError) as err:
        if blocks:
            for chunk in frames.chunks():
                n += len(chunk) if isinstance(chunk, list) else chunk.n
        else:
            for _ in frames:
                n += 1
    return n, err.value


class TestReader:
    """read_log on cut BLF files, frame by frame and in blocks."""

    @pytest.mark.parametrize("blocks", [False, True], ids=["frames", "blocks"])
    @pytest.mark.parametrize("where", ["mid container", "mid object header", "between objects", "mid file header"])
    def test_a_cut_file_is_an_error_naming_it_and_how_far(self, whole: Path, where: str, blocks: bool) -> None:
        """The error names the file, the byte it ends at and the frames read; those frames all came first."""
        path, at = cut(whole, where)
        n, err = read_until_error(path, blocks)
        assert str(err).startswith(f"{path}: truncated BLF log: the file ends at byte {at}")
        assert str(err).endswith(f"; {n} frames were read before the cut")
        assert (n == 0) == (where == "mid file header")

    @pytest.mark.parametrize("where", ["mid container", "mid object header"])
    def test_what_it_says_of_the_cut(self, whole: Path, where: str) -> None:
        """Inside a container: how many bytes into which; inside a header: the object it starts."""
        path, _ = cut(whole, where)
        objs = objects(whole.read_bytes())
        _, err = read_until_error(path, False)
        if where == "mid container":
            assert f"100 bytes into the {objs[1][1]}-byte log container at byte {objs[1][0]}" in str(err)
        else:
            assert f"inside the header of the object at byte {objs[2][0]}" in str(err)

    def test_frames_before_the_cut_are_the_files_own(self, whole: Path) -> None:
        """Up to the cut, the frames are exactly those of the whole file."""
        path, _ = cut(whole, "mid container")
        full = list(read_log(whole))
        got = []
        with pytest.raises(LogFormatError):
            for frame in read_log(path):
                got.append(frame)
        assert got and got == full[: len(got)]

    def test_a_whole_file_reads_whole(self, whole: Path) -> None:
        """No false alarm: every frame of an uncut file, no error."""
        assert len(list(read_log(whole))) == 3000

    def test_a_header_without_its_size(self, whole: Path, tmp_path: Path) -> None:
        """A writer that never filled in the file size (a crash, a pipe): the framing alone still catches a cut
        inside an object, and the whole file reads without complaint."""
        data = bytearray(whole.read_bytes())
        struct.pack_into("<Q", data, 32, FILE_HEADER_SIZE)  # the header's file size, as BLFWriter first writes it
        unsized = tmp_path / "unsized.blf"
        unsized.write_bytes(bytes(data))
        assert len(list(read_log(unsized))) == 3000
        cut_at = objects(bytes(data))[3][0] + 50
        (tmp_path / "unsized-cut.blf").write_bytes(bytes(data[:cut_at]))
        _, err = read_until_error(tmp_path / "unsized-cut.blf", True)
        assert f"the file ends at byte {cut_at}, 50 bytes into" in str(err)

    def test_not_a_blf_is_not_called_truncated(self, tmp_path: Path) -> None:
        """A file that is not BLF at all is 'not a valid BLF log', not a cut one."""
        path = tmp_path / "text.blf"
        path.write_bytes(b"this is not a BLF file, only some text\n" * 10)
        with pytest.raises(LogFormatError, match=r"text\.blf: not a valid BLF log"):
            list(read_log(path))

    def test_a_cut_blf_gz_still_says_so(self, whole: Path, tmp_path: Path) -> None:
        """A .blf.gz cut short fails too (gzip's own end-of-stream check), naming the file."""
        packed = gzip.compress(whole.read_bytes())
        path = tmp_path / "x.blf.gz"
        path.write_bytes(packed[: len(packed) // 2])
        _, err = read_until_error(path, True)
        assert str(err).startswith(f"{path}: ")


@pytest.mark.slow
def test_replay_of_a_cut_blf_fails_and_keeps_its_events(installed_canguard: Path, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """`canguard replay half.blf --events ev.jsonl --fail-on-trip` from the installed wheel: exit 2, one line naming
    the file and the frames read, no traceback, no summary; the events of the half it read are kept."""
    sim = tmp_path / "overload.log"  # the log is only material here: simulated in-process (the wheel smoke runs it)
    code, _, err = cli(capsys, "simulate", "--scenario", "overload", "--duration", "8", "--out", sim)
    assert code == 0, err
    full = write_blf(tmp_path / "overload.blf", list(can.LogReader(str(sim))))
    half = tmp_path / "half.blf"
    half.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    events = tmp_path / "ev.jsonl"
    proc = subprocess.run([str(installed_canguard), "replay", str(half), "-c", str(ROBOT), "--events", str(events),
                           "--fail-on-trip"], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout[-1000:] + proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and proc.stdout == ""
    [line] = [line for line in proc.stderr.splitlines() if "truncated BLF log" in line]
    assert line.startswith(f"{half}: truncated BLF log: the file ends at byte {half.stat().st_size}")
    assert events.read_text().count("\n") >= 1
