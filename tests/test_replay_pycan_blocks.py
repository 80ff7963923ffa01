"""python-can's formats (ASC, BLF, TRC, CSV; plain and compressed) on the replay column path (issue 16 item 3).

:mod:`canguard.io.pycan_blocks` hands python-can's messages to the engine as
:class:`~canguard.io.candump.Columns` blocks. Each log here is written again by
python-can's own writers and replayed three ways:

(a) as the candump -L log it came from;
(b) in the format, on the column path (the reader's blocks);
(c) in the format, frame by frame (a reader without blocks, the reference path).

(b) and (c) must agree byte for byte: summary, ``--events``, ``--emit`` and the
engine's state (``test_replay_columns.assert_same``), at the reader's block size and,
for the logs whose frames end blocks (error frames, CAN FD, remote), at a small one
(block boundaries everywhere), and (b) must really have taken column
blocks. (a) is the candump twin of the frames the format gives back (:func:`twin`:
the same frames, timestamps written with as many decimals as they need to come back
to the bit), and its summary must equal (b)'s but for the log's name. What the
formats cannot carry, and so what the twin holds instead of the original log:

* time base: python-can's ASC and BLF readers give timestamps relative to the first
  frame, its TRC reader adds the offsets to a start kept in days (float noise of
  about 1e-13 s), BLF keeps nanoseconds (0.009999999 for 0.01). Against the original
  candump log these shift a tick boundary now and then: the summary of the original
  is held to every count, margin and trip (node, reason, source) being equal and to
  the times (first/last frame, trips, time stopped) within one tick period.
* channel names: ASC and BLF give ``can0``, TRC ``can1``, CSV none; the configs here
  have one bus, which takes every channel, and the twin names them all ``can0``.
* frames: python-can's TRC writer writes neither CAN FD, remote nor error frames (dropped);
  CSV keeps no FD flag (a 64-byte FD frame comes back as a classic frame of 64
  bytes, which a block cannot hold: it goes as a frame). For the FD / remote log
  only ASC and BLF are compared with the original; every format with its twin.
"""

from __future__ import annotations

import gzip
import json
import lzma
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import can
import pytest

import canguard.io.pycan
import canguard.io.pycan_blocks
from canguard.config.loader import load_config
from canguard.config.schema import Config
from canguard.errors import LogFormatError
from canguard.io.candump import Columns
from canguard.io.frame import Frame
from canguard.io.logs import format_candump_line, read_log
from checkout import REPO
from test_replay_columns import DEFAULT_CHUNK, ROBOT_GUARD, assert_same, reference, replay
from test_replay_random_logs import write_case

EXAMPLES = REPO / "examples"
FORMATS = ("asc", "blf", "trc", "csv")
BLOCK = canguard.io.pycan_blocks.BLOCK
SMALL_BLOCK = 97
"""Messages per block besides the reader's default: a few hundred blocks in an example log."""

FD_SPEC: dict[str, Any] = {
    "messages": [
        {"id": 0x123, "ext": False, "fd": True, "length": 64, "muxed": False, "name": "M0", "signals": [
            {"name": "S0_0", "start": 7, "length": 16, "motorola": True, "signed": True, "float": False,
             "scale": 0.01, "offset": 0.0, "page": None}]},
        {"id": 0x1ABCDE, "ext": True, "fd": False, "length": 8, "muxed": True, "name": "M1", "signals": [
            {"name": "S1_0", "start": 16, "length": 16, "motorola": False, "signed": True, "float": False,
             "scale": 0.5, "offset": -5.0, "page": 0}]},
    ],
    "max_age": 0.2, "over": 50.0, "seed": 2, "frames": 1200,
}
"""CAN FD Motorola frames (BRS on every third), an extended multiplexed message, remote frames, wrong lengths.

1,200 frames of seed 2 (10 s, 441 CAN FD and 28 remote frames) reach every line and branch of src/canguard that
3,000 of seed 7 reached in this file, at two fifths of the replays' cost."""


def to_message(frame: Frame, brs: bool = False) -> can.Message:
    return can.Message(
        timestamp=frame.t, channel=0, arbitration_id=frame.arbitration_id, data=frame.data,
        is_extended_id=frame.is_extended_id, is_fd=frame.is_fd, is_error_frame=frame.is_error_frame,
        is_remote_frame=frame.is_remote_frame, bitrate_switch=frame.bitrate_switch or brs,
        error_state_indicator=frame.error_state_indicator, dlc=None if frame.dlc == -1 else frame.dlc,
    )


def write_format(frames: list[Frame], path: Path, brs: Callable[[int, Frame], bool] = lambda i, f: False) -> Path:
    """``frames`` written by python-can's writer for ``path``'s suffix (no compression: see :func:`compressed`)."""
    with can.Logger(str(path)) as writer:
        for i, frame in enumerate(frames):
            writer.on_message_received(to_message(frame, brs(i, frame)))
    return path


def compressed(path: Path, how: str) -> Path:
    """``path`` compressed to ``path.gz`` / ``path.xz`` / ``path.zst``."""
    out = path.with_name(path.name + "." + how)
    if how == "zst":
        zstandard = pytest.importorskip("zstandard")
        out.write_bytes(zstandard.ZstdCompressor().compress(path.read_bytes()))
        return out
    opener: Any = gzip.open if how == "gz" else lzma.open
    with opener(out, "wb") as f:
        f.write(path.read_bytes())
    return out


def replay_both(cfg: Config, log: Path, out: Path, block: int, monkeypatch: pytest.MonkeyPatch,
                columns: bool = True) -> dict[str, Any]:
    """(b) and (c) of the module docstring at ``block`` messages a block: equal; (b)'s summary.

    ``columns``: (b) must have taken column blocks at the reader's block size (small
    blocks of a log full of frames no block holds may have none).
    """
    monkeypatch.setattr(canguard.io.pycan_blocks, "BLOCK", block)
    ref = reference(cfg, log, out / f"ref-{log.name}")  # frame by frame: one run serves every block size
    col = replay(cfg, log, out / f"col-{log.name}-{block}", columns=True, chunk=DEFAULT_CHUNK)
    assert_same(ref, col, f"{log.name}, blocks of {block} messages")
    if columns and block == BLOCK:
        assert col.column_blocks > 0, f"{log.name}: the column path never ran: this proves nothing"
        assert col.handled_rows > 0, f"{log.name}: no row taken by a message plan"
    summary: dict[str, Any] = json.loads(col.summary)
    return summary


def twin(frames: list[Frame], path: Path) -> Path:
    """``frames`` as a candump -L log that reads back to the same frames (channel ``can0``), to the bit."""
    for decimals in (6, 9, 12, 17, 20):  # 20: 17 significant digits of a time below 0.1 s (0.009000000000000001)
        if all(float(f"{f.t:.{decimals}f}") == f.t for f in frames):
            break
    lines = []
    for f in frames:
        line = format_candump_line(f._replace(channel="can0"))
        lines.append(f"({f.t:.{decimals}f})" + line[line.index(")") + 1:] + "\n")
    path.write_text("".join(lines), encoding="ascii")
    assert list(read_log(path)) == [f._replace(channel="can0") for f in frames], "the twin is not the same frames"
    return path


def check_format(cfg: Config, path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                 candump_can: bool = True, blocks: tuple[int, ...] = (BLOCK, SMALL_BLOCK),
                 ) -> tuple[dict[str, Any], list[Frame]]:
    """(a), (b) and (c) of the module docstring for one log: equal; (b)'s summary at the reader's block size,
    and the frames the format gave back.

    ``candump_can=False``: (b) and (c) only, and no column block required: for the frames
    of CSV's FD log, classic frames of 64 bytes, which neither candump nor a block holds.
    ``blocks``: the block sizes (b) is compared at, the reader's first.
    """
    summaries = [replay_both(cfg, path, tmp_path, block, monkeypatch, columns=candump_can) for block in blocks]
    frames = list(read_log(path))
    if candump_can:
        candump = replay(cfg, twin(frames, tmp_path / f"{path.name}.twin.log"), tmp_path / "twin",
                         columns=True, chunk=DEFAULT_CHUNK)
        want = json.loads(candump.summary)
        for block, got in zip(blocks, summaries, strict=True):
            assert dict(got, log="") == dict(want, log=""), f"{path.name}, blocks of {block}: not its candump twin's"
    return summaries[0], frames


def same_but_time_base(got: dict[str, Any], want: dict[str, Any], tick: float) -> None:
    """Every count, margin and trip equal; times as offsets from the first frame within one tick.

    I²t margins integrate current² over time: they are held to 1e-6 of their value.
    """
    timed = ("first_t", "last_t", "stopped_s", "trips", "log", "margins")
    assert {k: v for k, v in got.items() if k not in timed} == {k: v for k, v in want.items() if k not in timed}
    exact = [m for m in want["margins"] if m["kind"] != "i2t"]
    assert [m for m in got["margins"] if m["kind"] != "i2t"] == exact
    heat = [(m["node"], pytest.approx(m["margin"], rel=1e-6, abs=1e-6)) for m in want["margins"] if m["kind"] == "i2t"]
    assert [(m["node"], m["margin"]) for m in got["margins"] if m["kind"] == "i2t"] == heat
    assert [(t["node"], t["reason"], t["source"]) for t in got["trips"]] == \
        [(t["node"], t["reason"], t["source"]) for t in want["trips"]]
    for t_got, t_want in zip(got["trips"], want["trips"], strict=True):
        assert abs((t_got["t"] - got["first_t"]) - (t_want["t"] - want["first_t"])) <= tick + 1e-6
    assert abs((got["last_t"] - got["first_t"]) - (want["last_t"] - want["first_t"])) <= 1e-6
    assert abs(got["stopped_s"] - want["stopped_s"]) <= tick + 1e-6


_ORIGINALS: dict[str, dict[str, Any]] = {}
"""An example log's own replay summary, by name: once per process for the formats it is written in."""


def original_summary(cfg: Config, example: str, out: Path) -> dict[str, Any]:
    if example not in _ORIGINALS:
        run = replay(cfg, EXAMPLES / f"{example}.log.gz", out, columns=True, chunk=DEFAULT_CHUNK)
        _ORIGINALS[example] = json.loads(run.summary)
    return _ORIGINALS[example]


# Every format and every example log, not every pair: the formats differ in what python-can's readers
# give back (time base, channel, error frames), which any log shows; the logs in what the engine does.
# Error frames go both to ASC, whose block reader hands such a file over to python-can's, and to TRC,
# which drops them. Small blocks (boundaries everywhere) for the error burst, whose error frames end
# blocks; test_fd_and_remote_frames takes every format at small blocks too.
@pytest.mark.parametrize(("example", "fmt"), [
    ("overload", "asc"), ("overload", "blf"), ("errorburst", "asc"), ("errorburst", "trc"), ("garbage", "csv"),
])
def test_examples_same_in_every_format(example: str, fmt: str, tmp_path: Path,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """An example log (trips, stops, error frames) in a format: as its candump twin, on either path."""
    cfg = load_config(ROBOT_GUARD)
    source = EXAMPLES / f"{example}.log.gz"
    frames = list(read_log(source))
    original = original_summary(cfg, example, tmp_path / "original")
    if example != "errorburst":
        assert original["trip_count"] >= 1 and original["stops"] >= 1, "the example should trip"
    path = write_format(frames, tmp_path / f"{example}.{fmt}")
    blocks = (BLOCK, SMALL_BLOCK) if example == "errorburst" else (BLOCK,)
    got, read = check_format(cfg, path, tmp_path, monkeypatch, blocks=blocks)
    if len(read) == len(frames):  # python-can's TRC writer drops error frames
        same_but_time_base(got, original, 1.0 / cfg.tree.tick_hz)
    else:
        assert fmt == "trc" and example == "errorburst", f"{path.name}: frames lost"


def test_compressed_formats(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """.gz, .xz and .zst python-can logs reach the column path too, with the plain file's replay."""
    cfg = load_config(ROBOT_GUARD)
    frames = list(read_log(EXAMPLES / "overload.log.gz"))[:3000]  # two blocks of every reader: as many as 15,000
    for fmt, how in (("blf", "gz"), ("asc", "xz"), ("csv", "gz"), ("trc", "zst")):
        plain = write_format(frames, tmp_path / f"overload.{fmt}")
        packed = compressed(plain, how)
        # each format's column path is held to its frame-by-frame reference by the tests above
        want, got = (replay(cfg, p, tmp_path / f"run-{p.name}", columns=True, chunk=DEFAULT_CHUNK)
                     for p in (plain, packed))
        assert got.column_blocks > 1 and got.column_blocks == want.column_blocks, f"{fmt}.{how}: several blocks"
        assert dict(json.loads(got.summary), log="") == dict(json.loads(want.summary), log=""), f"{fmt}.{how}"
        assert_same(replace(want, summary=""), replace(got, summary=""), f"{fmt}.{how} against {fmt}")


def test_fd_and_remote_frames(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """CAN FD (BRS, 64 bytes, Motorola), remote frames and an extended multiplexed message, in every format."""
    cfg_path, source = write_case(FD_SPEC, tmp_path / "case")
    cfg = load_config(cfg_path)
    frames = list(read_log(source))
    assert sum(f.is_fd for f in frames) > 100 and sum(f.is_remote_frame for f in frames) > 20

    def brs(i: int, f: Frame) -> bool:
        return f.is_fd and i % 3 == 0

    with_brs = [f._replace(bitrate_switch=brs(i, f)) for i, f in enumerate(frames)]
    original_log = twin(with_brs, tmp_path / "fd.log")
    original = json.loads(replay(cfg, original_log, tmp_path / "original", columns=True, chunk=DEFAULT_CHUNK).summary)
    assert original["frames"]["remote_frames"] > 20
    for fmt in FORMATS:
        path = write_format(frames, tmp_path / f"fd.{fmt}", brs)
        got, read = check_format(cfg, path, tmp_path, monkeypatch, candump_can=fmt != "csv")
        if fmt in ("asc", "blf"):  # they carry FD, BRS and remote frames: the same frames but for the time base
            assert [f._replace(t=0.0) for f in read] == [f._replace(t=0.0) for f in with_brs]
            same_but_time_base(got, original, 1.0 / cfg.tree.tick_hz)


def chunks(path: Path) -> list[Columns | list[Frame]]:
    return list(read_log(path).chunks())


def test_blocks_are_the_frames(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The blocks and frame lists hold, in order, exactly the frames the frame-by-frame reader gives.

    Error frames, a channel change, a timestamp going back, a raw DLC, a CAN FD frame
    whose DLC is not its length: each ends a block and goes as a frame; short runs
    go as frames; the rest are blocks of one channel, in order.
    """
    monkeypatch.setattr(canguard.io.pycan_blocks, "BLOCK", 64)
    msgs = []
    t = 100.0
    for i in range(600):
        t += 0.001 if i % 50 else -0.5 if i % 100 else 0.0  # a step back every 100 frames, a repeat at 50, 150...
        kw: dict[str, Any] = {"timestamp": t, "channel": 1 if 200 <= i < 260 else 0, "arbitration_id": i % 0x7FF,
                              "data": bytes([i % 256] * (i % 9))}
        if i % 97 == 5:
            kw.update(is_error_frame=True)
        elif i % 89 == 7:
            kw.update(is_remote_frame=True, data=None, dlc=i % 9)
        elif i % 83 == 11:
            kw.update(is_fd=True, data=bytes(12), bitrate_switch=True, is_extended_id=True, arbitration_id=0x1ABCDE)
        elif i % 79 == 13:
            kw.update(dlc=15, data=bytes(8))  # a raw DLC: the frame keeps it, a block cannot
        elif i % 73 == 17:
            kw.update(is_fd=True, data=bytes(20), dlc=24)  # an FD DLC that is not its length
        msgs.append(can.Message(**kw))
    path = tmp_path / "mixed.blf"
    with can.Logger(str(path)) as writer:
        for m in msgs:
            writer.on_message_received(m)
    frames = list(read_log(path))
    parts = chunks(path)
    flat = [f for part in parts for f in (part if isinstance(part, list) else part.frames())]
    assert flat == frames
    blocks = [part for part in parts if isinstance(part, Columns)]
    assert len(blocks) >= 10 and {b.channel for b in blocks} == {"can0", "can1"}
    for b in blocks:
        assert b.ordered and b.n >= canguard.io.pycan_blocks.MIN_BLOCK and set(b.chans) == {b.channel}
        assert [float(x) for x in b.ts] == sorted(float(x) for x in b.ts)
        assert [b.frame(i) for i in range(b.n)] == list(b.frames())
    listed = [f for part in parts if isinstance(part, list) for f in part]
    assert sum(f.is_error_frame for f in listed) == sum(f.is_error_frame for f in frames) > 0
    assert any(f.dlc == 15 for f in listed)
    assert any(b.remote for b in blocks) and any(b.fd for b in blocks)


@pytest.mark.parametrize("blocks", [True, False])
def test_reader_failure_part_way(blocks: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """python-can failing part-way: every frame before the failure first, then a LogFormatError naming the file."""
    frames = list(read_log(EXAMPLES / "overload.log.gz"))[:300]
    path = write_format(frames, tmp_path / "x.blf")
    whole = list(read_log(path))

    def failing(fmt: str) -> Callable[[Any], Any]:
        def read(fobj: Any) -> Any:
            for i, msg in enumerate(can.BLFReader(fobj)):
                if i == 250:
                    raise ValueError("corrupt object")
                yield msg
        return read

    monkeypatch.setattr(canguard.io.pycan, "_reader_class", failing)
    got: list[Frame] = []
    with pytest.raises(LogFormatError, match=r"x\.blf: BLF reader failed after 250 frames: ValueError: corrupt object"):
        if blocks:
            for part in read_log(path).chunks():
                got.extend(part if isinstance(part, list) else part.frames())
        else:
            got.extend(read_log(path))
    assert got == whole[:250]


def test_bad_header(tmp_path: Path) -> None:
    """A file python-can cannot open as its format is a LogFormatError naming it, on either reading."""
    path = tmp_path / "x.blf"
    path.write_bytes(b"not a BLF file at all" * 10)
    with pytest.raises(LogFormatError, match=r"x\.blf: not a valid BLF log"):
        list(read_log(path).chunks())
    with pytest.raises(LogFormatError, match=r"x\.blf: not a valid BLF log"):
        list(read_log(path))
