"""Every log reader against one contract: the same frames written by python-can's writers, read back as blocks.

Each format (candump -L and its -ta twin, ASC, BLF, TRC, CSV; plain and compressed) is
written here by python-can's own writer from one list of frames (classic, extended, CAN FD
with BRS / ESI, remote, error frames, two channels) and must give, as
:class:`~canguard.io.block.Block` s only, exactly the frames python-can's own reader gives for
the same file (python-can is the reference; for candump it keeps no error frame's id, data
or channel, which canguard does). A cut file and a file of garbage are a
:class:`~canguard.errors.LogFormatError` naming the file (and the line, for candump's text),
or the frames before the cut.
"""

from __future__ import annotations

import gzip
import lzma
import random
import struct
import threading
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

import canguard.io.candump
import canguard.io.pycan
from canguard.errors import LogFormatError
from canguard.io.block import Block, frame_from_message
from canguard.io.candump import format_candump_line
from canguard.io.candump_np import parse_block
from canguard.io.frame import Frame
from canguard.io.logs import read_log

T0 = 1_700_000_000.0


def frames() -> list[Frame]:
    """Classic, extended, CAN FD (BRS / ESI), remote and error frames on two channels, in time order."""
    rng = random.Random(5)
    out = []
    for i in range(60):
        t = T0 + i * 0.001
        channel = f"can{i % 2}"
        kind = i % 6
        if kind == 3:
            out.append(Frame(t, channel, 0x1ABCDE0 + i, bytes(rng.randrange(256) for _ in range(12)), True,
                             is_fd=True, bitrate_switch=bool(i % 4), error_state_indicator=i % 5 == 0))
        elif kind == 4:
            out.append(Frame(t, channel, 0x300 + i, b"", False, is_remote_frame=True, dlc=i % 9 or -1))
        elif kind == 5 and i % 4 == 1:
            out.append(Frame(t, channel, 0x80, bytes(8), True, is_error_frame=True))  # python-can writes 0x80
        else:
            ext = kind == 2
            out.append(Frame(t, channel, (0x1FFFF00 if ext else 0x100) + i,
                             bytes(rng.randrange(256) for _ in range(i % 9)), ext))
    return out


def message(f: Frame) -> can.Message:
    return can.Message(timestamp=f.t, channel=int(f.channel[3:]), arbitration_id=f.arbitration_id, data=f.data,
                       is_extended_id=f.is_extended_id, is_fd=f.is_fd, is_error_frame=f.is_error_frame,
                       is_remote_frame=f.is_remote_frame, bitrate_switch=f.bitrate_switch,
                       error_state_indicator=f.error_state_indicator, dlc=None if f.dlc == -1 else f.dlc)


FORMATS = ("log", "ta.log", "asc", "blf", "trc", "csv", "log.gz", "asc.xz", "blf.gz")


def long_line(f: Frame) -> str:
    """``f`` as candump -ta writes it (``-x`` columns on CAN FD frames, an ASCII dump on classic ones)."""
    cid = f"{f.arbitration_id | (0x20000000 if f.is_error_frame else 0):{'08X' if f.is_extended_id else '03X'}}"
    data = " ".join(f"{b:02X}" for b in f.data)
    if f.is_fd:
        return (f"({f.t:.6f})  {f.channel}  RX {'B' if f.bitrate_switch else '-'} "
                f"{'E' if f.error_state_indicator else '-'}  {cid}  [{len(f.data):02d}]  {data}")
    if f.is_remote_frame:
        return f"({f.t:.6f})  {f.channel}  {cid}   [{max(f.dlc, 0)}]  remote request"
    if f.is_error_frame:
        return f"({f.t:.6f})  {f.channel}  {cid}   [{len(f.data)}]  {data}   ERRORFRAME"
    return f"({f.t:.6f})  {f.channel}  {cid}   [{len(f.data)}]  {data}   '{'.' * len(f.data)}'"


def written(fmt: str, directory: Path) -> tuple[Path, Path]:
    """The frames written in ``fmt`` (python-can's writer; -ta by hand) -> (the file, its uncompressed twin)."""
    plain = directory / f"x.{fmt.split('.')[0] if fmt != 'ta.log' else 'log'}"
    if fmt == "ta.log":
        plain.write_text("".join(long_line(f) + "\n" for f in frames()), encoding="ascii")
    else:
        with can.Logger(str(plain)) as writer:
            for f in frames():
                writer.on_message_received(message(f))
    how = fmt.split(".")[-1] if fmt.count(".") == 1 and fmt != "ta.log" else ""
    if not how:
        return plain, plain
    packed = plain.with_name(plain.name + "." + how)
    opener: Any = gzip.open if how == "gz" else lzma.open
    with opener(packed, "wb") as out:
        out.write(plain.read_bytes())
    return packed, plain


def theirs(plain: Path, fmt: str) -> list[Frame]:
    """What python-can's own reader gives for ``plain`` (candump -ta: its -L twin's, the error frames' kept)."""
    if fmt == "ta.log":
        return frames()
    with can.LogReader(str(plain)) as reader:
        got = [frame_from_message(m) for m in reader]
    if plain.suffix == ".log":  # python-can's candump reader keeps no error frame's id, data or channel
        ours = frames()
        got = [o if g.is_error_frame else g for g, o in zip(got, ours, strict=True)]
    return got


@pytest.fixture(params=FORMATS)
def log(request: pytest.FixtureRequest, tmp_path: Path) -> tuple[str, Path, Path]:
    fmt = request.param
    path, plain = written(fmt, tmp_path)
    return fmt, path, plain


class TestEveryReader:
    """The contract each format's reader keeps."""

    def test_blocks_hold_python_cans_frames(self, log: tuple[str, Path, Path]) -> None:
        """Only blocks, holding in order the frames python-can's reader gives for the file."""
        fmt, path, plain = log
        blocks = list(read_log(path).chunks())
        assert blocks and all(type(b) is Block for b in blocks)
        assert [f for b in blocks for f in b.frames()] == theirs(plain, fmt)

    def test_small_blocks_are_the_same_frames(self, log: tuple[str, Path, Path], monkeypatch: pytest.MonkeyPatch
                                              ) -> None:
        """Blocks of a few frames (every frame kind at a block's edge): the same frames."""
        fmt, path, plain = log
        monkeypatch.setattr(canguard.io.pycan, "BLOCK", 7)
        monkeypatch.setattr(canguard.io.candump, "CHUNK_CHARS", 150)
        assert list(read_log(path)) == theirs(plain, fmt)

    def test_a_cut_file_names_itself_or_gives_the_frames_before_the_cut(self, log: tuple[str, Path, Path]) -> None:
        """The file cut at about three fifths (a text file a few characters into a line): a LogFormatError naming
        the file (candump: its last line), or frames that begin the whole file's."""
        _fmt, path, plain = log
        whole = list(read_log(path))
        data = plain.read_bytes()
        cut = path.with_name("cut" + "".join(plain.suffixes))
        kept = data[: data.rfind(b"\n", 0, len(data) * 3 // 5) + 6]
        cut.write_bytes(kept)
        last_line = kept.count(b"\n") + 1
        try:
            got = list(read_log(cut))
        except LogFormatError as exc:
            assert str(cut) in str(exc)
            if cut.suffix == ".log":
                assert f"{cut}:{last_line}: " in str(exc)
        else:
            assert 0 < len(got) < len(whole) and got == whole[: len(got)]

    def test_garbage_names_the_file(self, log: tuple[str, Path, Path]) -> None:
        """A file of random bytes under the format's name: a LogFormatError naming it (candump: file:line)."""
        _fmt, _path, plain = log
        junk = plain.with_name("junk" + plain.suffix)
        junk.write_bytes(random.Random(3).randbytes(3000))
        with pytest.raises(LogFormatError) as err:
            list(read_log(junk))
        assert str(junk) in str(err.value)
        if junk.suffix == ".log":
            assert f"{junk}:1: " in str(err.value)


class TestCandumpParser:
    """The candump parser's columns: exact times, channels, threads."""

    @pytest.mark.parametrize("stamp", ["1700000000.000001", "0.5", "000012.250", "9007199254740993.0", "12",
                                       "123456789012345678901234.5", "1.00000000000000000000000001"])
    def test_timestamps_are_pythons_floats(self, stamp: str) -> None:
        """Every timestamp is float() of its text, to the bit (a long one too: then float() itself reads it)."""
        parsed = parse_block(f"({stamp}) can0 123#00\n".encode())
        assert parsed.block is not None and not parsed.bad
        assert struct.pack("<d", float(parsed.block.time_s[0])) == struct.pack("<d", float(stamp))

    def test_channels_ids_and_widths_mix_in_a_block(self) -> None:
        """Channel names, timestamps and ids of several widths in one block: each row its own."""
        lines = ["(1.000000) can0 123#00", "(1.0000010) can10 1aBcDeF0#01", "(10.5) vcan 7fF#R",
                 "(11.000000) can0 000#"]
        parsed = parse_block("".join(line + "\n" for line in lines).encode())
        assert parsed.block is not None and not parsed.bad
        got = list(parsed.block.frames())
        assert [(f.t, f.channel, f.arbitration_id, f.is_extended_id) for f in got] == [
            (1.0, "can0", 0x123, False), (1.000001, "can10", 0x1ABCDEF0, True), (10.5, "vcan", 0x7FF, False),
            (11.0, "can0", 0, False)]
        assert parsed.block.channels == ("can0", "can10", "vcan")

    def test_rows_read_alone_are_the_whole_blocks(self) -> None:
        """The payloads of some rows (a message's, as the engine reads them), and frames row by row, are those of the
        whole block: CAN FD, remote, empty and short payloads, the last line's too."""
        lines = ["(1.0) can0 123#1122334455667788", "(1.1) can0 1aBcDeF0##1" + "a5" * 64, "(1.2) can0 7FF#R",
                 "(1.3) can0 001#", "(1.4) can1 002#0102030405060708_C", "(1.5) can0 003#C0fFeE"]
        text = "".join(line + "\n" for line in lines).encode()
        whole = parse_block(text).block
        assert whole is not None
        n = whole.n
        for rows in ([0, n - 1], [n - 1], [1, 2, 3], [1, n - 1], list(range(n))):
            block = parse_block(text).block
            assert block is not None
            got = block.payload_rows(np.array(rows))
            width = got.shape[1]
            assert got.tobytes() == whole.payload[rows, :width].tobytes() and not whole.payload[rows, width:].any()
        block = parse_block(text).block
        assert block is not None
        asked = [block.payload_rows(np.array([i % n]))[0].tobytes() for i in range(3 * n)]  # each row, asked again
        assert asked == [whole.payload[i % n, :len(asked[i])].tobytes() for i in range(3 * n)]
        block = parse_block(text).block
        assert block is not None
        assert [block.frame(i) for i in range(n)] == list(whole.frames())
        assert whole.payload[n - 1, :4].tobytes() == bytes.fromhex("c0ffee00")

    def test_threads_parse_at_once(self) -> None:
        """Each thread has its own scratch: blocks parsed by four threads at once read as parsed one by one."""
        blocks = [b"".join(b"(%d.%06d) can%d %03X#%016X\n" % (1_700_000_000 + k, i, k, (k * 97 + i) % 0x7FF, i)
                           for i in range(4_000)) for k in range(4)]
        alone = [parse_block(b).block for b in blocks]
        got: dict[int, list[Any]] = {k: [] for k in range(4)}

        def parse(k: int) -> None:
            for _ in range(4):
                block = parse_block(blocks[k]).block
                assert block is not None
                got[k].append((block.time_s.tolist(), block.can_id.tolist(), block.payload.tobytes()))

        threads = [threading.Thread(target=parse, args=(k,)) for k in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for k, block in enumerate(alone):
            assert block is not None
            assert got[k] == [(block.time_s.tolist(), block.can_id.tolist(), block.payload.tobytes())] * 4

    def test_written_lines_read_back(self, tmp_path: Path) -> None:
        """What canguard writes (--emit, simulate --out) reads back to the same frames."""
        log = tmp_path / "w.log"
        want = frames()
        log.write_text("".join(format_candump_line(f) + "\n" for f in want), encoding="ascii")
        assert list(read_log(log)) == want


def test_reader_failure_part_way(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """python-can failing part-way: every frame before the failure first, then a LogFormatError naming the file."""
    path, _ = written("blf", tmp_path)
    whole = list(read_log(path))

    reader = can.BLFReader

    def failing(fobj: Any) -> Any:
        for i, msg in enumerate(reader(fobj)):
            if i == 25:
                raise ValueError("corrupt object")
            yield msg

    monkeypatch.setattr(can, "BLFReader", failing)
    monkeypatch.setattr(canguard.io.pycan, "BLOCK", 10)
    got: list[Frame] = []
    with pytest.raises(LogFormatError, match=r"x\.blf: BLF reader failed after 25 frames: ValueError: corrupt object"):
        for block in read_log(path).chunks():
            got.extend(block.frames())
    assert got == whole[:25]

