"""MF4 logs (ASAM MDF 4: python-can's MF4Writer / MF4Reader over asammdf) on canguard's reader and replay.

The logs are written here by python-can's :class:`can.io.mf4.MF4Writer` from frames the
tests build, then:

(a) ``read_log`` gives, frame for frame, what python-can's own MF4Reader yields
    (ids, data, flags, channel ``canN`` from MDF's bus channel N, timestamps), both
    frame by frame and in the blocks of :mod:`canguard.io.pycan` (:class:`~canguard.io.block.Block`);
(b) the replay's column path on an MF4 log is held to the frame-by-frame reference
    (``test_replay_columns.compare``), at the reader's block size and a small one, and
    its summary is that of the same frames as a candump -L log;
(c) ``canguard replay LOG.mf4 --json`` as a process: exit 0 and the frames counted; a
    truncated .mf4 exits 2 with one message naming the file and no traceback.

What MF4 keeps: timestamps as float64 offsets from the file's start time (MF4Writer
takes ``datetime.now()``), so they come back as the reader adds the two, within a
float64 ulp of the original (exact for epoch timestamps); channels as an 8-bit bus
number (``can.util.channel2int``); CAN FD with BRS / ESI; remote frames with their
DLC; error frames. Data frames come back with ``dlc`` = their length.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import can
import pytest

import canguard.io.pycan
from canguard.config.loader import load_config
from canguard.io.block import FLAG_ERROR, FLAG_FD, FLAG_REMOTE, Block, frame_from_message
from canguard.io.candump import format_candump_line
from canguard.io.frame import Frame
from canguard.io.logs import ReadStats, read_log
from checkout import SRC
from test_replay_columns import (
    DEFAULT_CHUNK,
    compare,
    replay,
    two_bus_config,
    two_channel_log,
)

pytest.importorskip("asammdf", reason="MF4 logs need asammdf: pip install -e '.[test,mf4]' (not in the test extra:"
                    " with it, `import can` imports asammdf and pandas, +0.35 s on every canguard process)")

T0 = 1_700_000_000.25
FD_LENGTHS = (0, 3, 8, 12, 16, 20, 24, 32, 48, 64)
SMALL_BLOCK = 97
"""Messages per block besides the reader's default: block boundaries everywhere."""


def built_messages(n: int = 4000) -> list[can.Message]:
    """Classic standard and extended, CAN FD (BRS, ESI), remote and error frames on channels 0, 1 and 2.

    Channels come in runs of 100 frames (blocks of one channel), but for frames 1000-1299,
    where they interleave frame by frame (rows no block takes). Timestamps only go forward:
    MF4Writer keeps data, remote and error frames in three groups that MF4Reader merges by time.
    """
    msgs = []
    for i in range(n):
        kw: dict[str, Any] = {
            "timestamp": T0 + i * 0.0005,
            "channel": i % 3 if 1000 <= i < 1300 else (i // 100) % 3,
            "arbitration_id": 0x100 + i % 0x600,
            "is_extended_id": False,
            "data": bytes((i + k) % 256 for k in range(i % 9)),
        }
        if i % 7 == 3:
            kw.update(arbitration_id=0x18FF0000 | (i * 37) % 0x10000, is_extended_id=True)
        elif i % 11 == 5:
            kw.update(is_fd=True, data=bytes(range(FD_LENGTHS[i % len(FD_LENGTHS)])), bitrate_switch=bool(i % 2),
                      error_state_indicator=i % 4 == 1)
        elif i % 53 == 9:
            kw.update(is_remote_frame=True, data=None, dlc=i % 9)
        elif i % 401 == 17:
            kw.update(is_error_frame=True, arbitration_id=0x80, data=bytes(8))
        msgs.append(can.Message(**kw))
    return msgs


def write_mf4(messages: list[can.Message], path: Path) -> Path:
    """``messages`` written by python-can's MF4Writer."""
    writer = can.MF4Writer(str(path))
    for msg in messages:
        writer.on_message_received(msg)
    writer.stop()
    return path


def to_message(frame: Frame) -> can.Message:
    """A candump frame as a message for MF4Writer (channel ``canN`` -> bus channel N)."""
    return can.Message(
        timestamp=frame.t, channel=int(frame.channel.removeprefix("can")), arbitration_id=frame.arbitration_id,
        data=frame.data, is_extended_id=frame.is_extended_id, is_fd=frame.is_fd, is_error_frame=frame.is_error_frame,
        is_remote_frame=frame.is_remote_frame, bitrate_switch=frame.bitrate_switch,
        error_state_indicator=frame.error_state_indicator, dlc=None if frame.dlc == -1 else frame.dlc,
    )


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[can.Message], Path]:
    """The built messages and their MF4 log."""
    msgs = built_messages()
    return msgs, write_mf4(msgs, tmp_path_factory.mktemp("mf4") / "built.mf4")


@pytest.fixture(scope="module")
def two_channels(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """The two-bus config, the first 3.5 s of test_replay_columns' two-channel candump log, and those as MF4.

    3.5 s: the interleaved stretch, windows of one channel, the BMS spike and the I²t trip
    (at 3 s), in 27,000 frames (MF4Writer writes about 20,000 messages a second).
    """
    d = tmp_path_factory.mktemp("mf4_channels")
    whole = two_channel_log(d / "whole.log")
    frames = list(read_log(whole))
    frames = [f for f in frames if f.t < frames[0].t + 3.5]
    log = d / "channels.log"
    log.write_text("".join(format_candump_line(f) + "\n" for f in frames), encoding="ascii")
    assert list(read_log(log)) == frames
    return two_bus_config(d / "cfg"), log, write_mf4([to_message(f) for f in frames], d / "channels.mf4")


# --------------------------------------------------------------------------- (a) reading


def test_frames_are_python_cans(built: tuple[list[can.Message], Path]) -> None:
    """read_log gives what python-can's MF4Reader yields, and the built frames but for the time (within 1 µs)."""
    msgs, path = built
    reader = can.MF4Reader(str(path))
    try:
        theirs = [frame_from_message(m) for m in reader]
    finally:
        reader.stop()
    stats = ReadStats()
    frames = list(read_log(path, stats=stats))
    assert frames == theirs
    assert (stats.frames, stats.backwards_timestamps) == (len(msgs), 0)
    built_frames = [frame_from_message(m) for m in msgs]
    assert [f._replace(t=0.0) for f in frames] == [f._replace(t=0.0) for f in built_frames]
    assert max(abs(f.t - b.t) for f, b in zip(frames, built_frames, strict=True)) <= 1e-6
    assert {f.channel for f in frames} == {"can0", "can1", "can2"}
    kinds = {"ext": sum(f.is_extended_id for f in frames), "fd": sum(f.is_fd for f in frames),
             "brs": sum(f.bitrate_switch for f in frames), "esi": sum(f.error_state_indicator for f in frames),
             "remote": sum(f.is_remote_frame for f in frames), "error": sum(f.is_error_frame for f in frames),
             "fd64": sum(f.is_fd and len(f.data) == 64 for f in frames)}
    assert all(kinds.values()), kinds
    assert any(f.is_remote_frame and f.dlc == 5 for f in frames)


def test_blocks_are_the_frames(built: tuple[list[can.Message], Path], monkeypatch: pytest.MonkeyPatch) -> None:
    """The reader's blocks hold, in order, the frames (CAN FD, remote and error rows among them), at the reader's
    block size and a small one."""
    _, path = built
    frames = list(read_log(path))
    for block in (canguard.io.pycan.BLOCK, SMALL_BLOCK):
        monkeypatch.setattr(canguard.io.pycan, "BLOCK", block)
        parts = list(read_log(path).chunks())
        assert all(type(part) is Block for part in parts)
        assert [f for part in parts for f in part.frames()] == frames
        assert {name for b in parts for name in b.channels} == {"can0", "can1", "can2"}
        flags = {int(f) for b in parts for f in b.flags.tolist()}
        assert all(any(f & kind for f in flags) for kind in (FLAG_FD, FLAG_REMOTE, FLAG_ERROR)), flags


# --------------------------------------------------------------------------- (b) replay


def test_replay_columns_against_reference(two_channels: tuple[Path, Path, Path], tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """The MF4 log on two buses: column path == frame by frame, at two block sizes; == its candump log's summary."""
    cfg_path, log, mf4 = two_channels
    cfg = load_config(cfg_path)
    frames = list(read_log(log))
    got = list(read_log(mf4))
    assert [f._replace(t=0.0) for f in got] == [f._replace(t=0.0) for f in frames]
    assert max(abs(g.t - f.t) for g, f in zip(got, frames, strict=True)) <= 1e-6
    summaries = []
    for block in (canguard.io.pycan.BLOCK, SMALL_BLOCK):
        monkeypatch.setattr(canguard.io.pycan, "BLOCK", block)
        # one "chunk": compare()'s block sizes are candump's characters, not python-can's messages
        [col] = compare(cfg, mf4, tmp_path / f"b{block}", (DEFAULT_CHUNK,))
        assert col.column_blocks > 0, f"blocks of {block}: the column path never ran, so this proves nothing"
        assert col.handled_rows > 1000, f"blocks of {block}: the row handlers took {col.handled_rows} rows"
        summaries.append(json.loads(col.summary))
    # the same frames as a candump -L log (MF4's timestamps to the bit), channels kept
    decimals = next(d for d in (6, 9, 12, 17) if all(float(f"{f.t:.{d}f}") == f.t for f in got))
    lines = [format_candump_line(f) for f in got]
    twin = tmp_path / "twin.log"
    twin.write_text("".join(f"({f.t:.{decimals}f}){line[line.index(')') + 1:]}\n" for f, line in zip(got, lines,
                                                                                                  strict=True)))
    assert list(read_log(twin)) == got
    want = json.loads(replay(cfg, twin, tmp_path / "twin", columns=True, chunk=DEFAULT_CHUNK).summary)
    for summary in summaries:
        assert dict(summary, log="") == dict(want, log="")
    assert summaries[0]["unmapped_channels"]["can2"] > 0
    assert {t["source"] for t in summaries[0]["trips"]} >= {"/battery_state", "axis0"}


# --------------------------------------------------------------------------- (c) the command


def console(*argv: Any, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``python -m canguard *argv`` in a process of its own (what asammdf prints at exit is seen too)."""
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    return subprocess.run([sys.executable, "-m", "canguard", *map(str, argv)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.slow
def test_command(built: tuple[list[can.Message], Path], tmp_path: Path) -> None:
    """canguard replay LOG.mf4 --json: exit 0, every frame counted; a truncated .mf4: exit 2, the file named."""
    msgs, path = built
    cfg = two_bus_config(tmp_path / "cfg")
    proc = console("replay", path, "-c", cfg, "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["frames"]["read"] == len(msgs)
    assert summary["unmapped_channels"] == {"can2": sum(m.channel == 2 for m in msgs)}  # no bus takes can2
    assert summary["frames"]["error_frames"] == sum(m.is_error_frame and m.channel != 2 for m in msgs) > 0
    assert summary["frames"]["remote_frames"] == sum(m.is_remote_frame and m.channel != 2 for m in msgs) > 0

    cut = tmp_path / "cut.mf4"
    data = path.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    proc = console("replay", cut, "-c", cfg, "--json", cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert f"{cut}: not a valid MF4 log" in proc.stderr
    assert "Traceback" not in proc.stderr and "Exception ignored" not in proc.stderr, proc.stderr
