"""canguard's own ASC reader (:mod:`canguard.io.asc_blocks`) against python-can's, file by file.

python-can's ``ASCReader`` (through :func:`~canguard.io.pycan_blocks.python_can_chunks`) is
the reference: for every file here the frames (every field), the read statistics and the
error, if any, must be the same from both readers, whether canguard's reader takes the
file itself or hands (the rest of) it to python-can. Files: written by python-can's
``ASCWriter`` from random messages; CANalyzer-style files with every kind of line around
plain ones; a line python-can reads and canguard's reader does not, after several blocks;
compressed files; and a whole ``canguard replay`` with each reader.
"""

from __future__ import annotations

import gzip
import inspect
import json
import lzma
import math
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import can
import can.io.asc
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

import canguard.io.asc_blocks
import canguard.io.logs
from canguard.cli.main import main
from canguard.errors import LogFormatError
from canguard.io.asc_blocks import asc_chunks
from canguard.io.candump import Columns
from canguard.io.frame import Frame
from canguard.io.logs import read_log
from canguard.io.logtypes import LogFrames, ReadStats
from canguard.io.pycan_blocks import python_can_chunks
from checkout import REPO

STATS = ("frames", "lines", "bad_lines", "backwards_timestamps", "repeated_timestamps")
"""What both readers must count alike (``bytes_read`` is the progress position, read a block at a time)."""

HEADER = "date Wed Nov 25 03:52:07.453 pm 2026\nbase hex  timestamps absolute\ninternal events logged\n" \
         "// version 13.0.0\nBegin Triggerblock Wed Nov 25 03:52:07.453 pm 2026\n   0.000000 Start of measurement\n"


def _read(fn: Any, path: Path, gz: str) -> tuple[list[Frame], dict[str, int], str | None, list[Any]]:
    """Frames, counts, error text and the pieces of one reader."""
    stats = ReadStats()
    pieces: list[Any] = []
    error = None
    try:
        for piece in fn(path, gz, stats, LogFrames(path, stats, None)):
            pieces.append(piece)
    except LogFormatError as exc:
        error = str(exc)
    frames = [fr for piece in pieces for fr in (piece if type(piece) is list else piece.frames())]
    return frames, {k: getattr(stats, k) for k in STATS}, error, pieces


def _check_block(cols: Columns) -> None:
    """A block as pycan_blocks makes them: one channel, ordered, ids and data as it writes them."""
    assert type(cols) is Columns and cols.n > 0 and cols.ordered and cols.fd is None and cols.remote is None
    assert cols.channel is not None and cols.chans == [cols.channel] * cols.n
    assert all(a <= b for a, b in zip(cols.ts, cols.ts[1:], strict=False))
    assert all(type(t) is float and math.isfinite(t) for t in cols.ts)
    assert all(re.fullmatch(r"[0-7][0-9A-F]{2}|[01][0-9A-F]{7}", i) for i in cols.ids)
    assert all(re.fullmatch(r"(?:[0-9a-f]{2}){0,8}", d) for d in cols.data)
    assert list(cols.frames()) == [cols.frame(i) for i in range(cols.n)]


@contextmanager
def _spied(block_chars: int | None = None) -> Iterator[list[int]]:
    """The ``skip`` of each hand-over to python-can while in the block; blocks of ``block_chars`` characters."""
    skips: list[int] = []
    real = canguard.io.asc_blocks.python_can_chunks

    def spy(*args: Any, skip: int = 0, **kwargs: Any) -> Any:
        skips.append(skip)
        return real(*args, skip=skip, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(canguard.io.asc_blocks, "python_can_chunks", spy)
        if block_chars is not None:
            mp.setattr(canguard.io.asc_blocks, "BLOCK_CHARS", block_chars)
        yield skips


def same(path: Path, gz: str = "", block_chars: int | None = None) -> tuple[list[Frame], list[int], list[Any]]:
    """Both readers on ``path``: equal; (the frames, the hand-overs to python-can, canguard's pieces)."""
    ref = _read(lambda p, g, s, o: python_can_chunks(p, "asc", g, s, o), path, gz)
    with _spied(block_chars) as skips:
        got = _read(asc_chunks, path, gz)
    assert got[0] == ref[0], f"{path.name}: frames differ"
    assert [tuple(map(type, f)) for f in got[0]] == [tuple(map(type, f)) for f in ref[0]]
    assert got[1:3] == ref[1:3], f"{path.name}: counts or error differ"
    stats = ReadStats()
    if ref[2] is None:  # read_log's frame stream (io.logs) is the same as well
        assert list(read_log(path, stats=stats)) == ref[0]
    else:
        with pytest.raises(LogFormatError) as exc:
            list(read_log(path, stats=stats))
        assert str(exc.value) == ref[2]
    assert {k: getattr(stats, k) for k in STATS} == ref[1]
    for piece in got[3]:
        if type(piece) is list:
            assert piece
        else:
            _check_block(piece)
    return got[0], skips, got[3]


def write_asc(path: Path, msgs: list[can.Message]) -> Path:
    with can.ASCWriter(str(path)) as writer:
        for msg in msgs:
            writer.on_message_received(msg)
    return path


def test_regexes_are_python_cans() -> None:
    """The rules copied from python-can's ASCReader are still its own (checked against the installed version)."""
    if not hasattr(can.io.asc, "ASC_TRIGGER_REGEX"):
        pytest.skip("python-can before 4.6 keeps its ASC rules inside ASCReader: the file-by-file tests here "
                    "compare the frames with its reader's")
    assert canguard.io.asc_blocks.ASC_TRIGGER_REGEX.pattern == can.io.asc.ASC_TRIGGER_REGEX.pattern
    assert canguard.io.asc_blocks.ASC_TRIGGER_REGEX.flags == can.io.asc.ASC_TRIGGER_REGEX.flags
    assert canguard.io.asc_blocks.ASC_MESSAGE_REGEX.pattern == can.io.asc.ASC_MESSAGE_REGEX.pattern
    assert canguard.io.asc_blocks.ASC_MESSAGE_REGEX.flags == can.io.asc.ASC_MESSAGE_REGEX.flags
    source = re.sub(r'"\s*r"', "", inspect.getsource(can.io.asc.ASCReader))  # r"..." r"..." joined
    for name in ("START_REGEX", "DATE_REGEX", "BASE_REGEX", "COMMENT_REGEX"):
        assert f'r"{getattr(canguard.io.asc_blocks, name).pattern}"' in source, name


# --------------------------------------------------------------------------- (1) python-can's writer, random

_MSG = st.tuples(
    st.booleans(),  # extended
    st.integers(0, 0x1FFFFFFF),
    st.binary(max_size=8),
    st.sampled_from([0.0, 0.0, 0.000001, 0.0005, 0.25, -0.0003, -1.0]),  # steps: repeats and steps back
    st.booleans(),  # Rx / Tx
)


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(1, 40), st.lists(_MSG, min_size=1, max_size=3)),
                min_size=1, max_size=8),
       st.sampled_from([None, 150, 700, 4000]))
def test_python_can_writer_random(tmp_path_factory: pytest.TempPathFactory, runs: list[tuple[int, int, list[Any]]],
                                  block_chars: int | None) -> None:
    """Random classic data frames on channels 0-3, runs of one channel or interleaved: taken, and equal."""
    msgs, t = [], 5.0
    for channel, repeat, pattern in runs:
        for k in range(repeat):
            for ext, cid, data, step, rx in pattern:
                t = max(t + step, 0.0)
                msgs.append(can.Message(timestamp=t, arbitration_id=cid if ext else cid & 0x7FF, is_extended_id=ext,
                                        data=data, channel=channel if k % 5 else (channel + k) % 4, is_rx=rx))
    path = write_asc(tmp_path_factory.mktemp("asc") / "random.asc", msgs)
    frames, skips, _ = same(path, block_chars=block_chars)
    assert skips == [] and len(frames) == len(msgs)


_ODD = st.sampled_from(["error", "remote", "remote0", "fd", "fd_brs", "dlc", "std_high"])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(_MSG, _ODD), min_size=1, max_size=120), st.sampled_from([None, 120, 600]))
def test_python_can_writer_odd_frames(tmp_path_factory: pytest.TempPathFactory, items: list[Any],
                                      block_chars: int | None) -> None:
    """Error, remote and CAN FD frames, raw DLCs, ids above 7FF among plain ones: python-can's frames, anywhere."""
    msgs, t = [], 1.0
    for item in items:
        t += 0.001
        if isinstance(item, tuple):
            ext, cid, data, _step, rx = item
            msgs.append(can.Message(timestamp=t, arbitration_id=cid if ext else cid & 0x7FF, is_extended_id=ext,
                                    data=data, channel=0, is_rx=rx))
        else:
            kw: dict[str, Any] = {
                "error": {"is_error_frame": True},
                "remote": {"is_remote_frame": True, "dlc": 4},
                "remote0": {"is_remote_frame": True},
                "fd": {"is_fd": True, "data": bytes(range(12))},
                "fd_brs": {"is_fd": True, "bitrate_switch": True, "data": b"\x01\x02"},
                "dlc": {"data": b"\x01\x02", "dlc": 8},
                "std_high": {"arbitration_id": 0x7FF + 0x100},
            }[item]
            msgs.append(can.Message(**{"timestamp": t, "arbitration_id": 0x123, "is_extended_id": False,
                                       "channel": 1, **kw}))
    path = write_asc(tmp_path_factory.mktemp("asc") / "odd.asc", msgs)
    _, skips, _ = same(path, block_chars=block_chars)
    assert len(skips) == (not all(isinstance(i, tuple) for i in items))


# --------------------------------------------------------------------------- (2) CANalyzer-style files, hand-written

PLAIN = [
    "   0.001249 2  303             Rx   d 8 9C FC 15 FF 02 FF 34 FF  Length = 231910 BitCount = 119 ID = 771",
    "   0.001500 1  18fef100x       Tx   d 8 9c fc 15 ff 02 ff 34 ff  Length = 231910 BitCount = 119 ID = 419361024x",
    "   0.001500 1  7FF             Rx   d 0",
    "   0.001700 1  0               Rx   d 3 01 02 03 AB",
    "   0.002000 3  1FFFFFFFX       Rx   d 2 aA Bb",
    "0.002100 1 123 Rx d 1 01",
    "\t0.002200\t1\t124\tRx\td 2\t01 02\tLength = 1",
]

# (what, the line): python-can skips the line, reads it as a frame canguard's reader does not take, or fails on it
ODD = [
    ("blank", ""),
    ("comment", "// a comment in the middle"),
    ("chip status", "   0.002000 CAN 1 Status:chip status error active"),
    ("statistic", "   0.002100 1  Statistic: D 0 R 0 XD 0 XR 0 E 0 O 0 B 0.00%"),
    ("event", "   0.002200 SV: 1 0 1 ::Env::x = 5"),
    ("j1939", "   0.002300 1  J1939TP FEE3p 6 0 0 - Rx d 23 FF FF FF FF FF FF FF"),
    ("trigger", "Begin Triggerblock Wed Nov 25 03:52:09.000 pm 2026"),
    ("end", "End TriggerBlock"),
    ("start", "   0.002400 Start of measurement"),
    ("negative time", "  -0.002500 1  123             Rx   d 1 01"),
    ("error frame", "   0.003000 1  ErrorFrame"),
    ("error frame, flags", "   0.003000 1  ErrorFrame ECC: 10100010"),
    ("remote", "   0.004000 1  123             Rx   r"),
    ("remote dlc", "   0.004100 1  123             Rx   r 4"),
    ("can fd", "   0.005000 CANFD   1 Rx        123                                   1 0 9 12 00 01 02 03 04 05 "
               "06 07 08 09 0A 0B   0    0     1000        0        0        0        0        0"),
    ("can fd error", "   0.005100 CANFD   1 Rx   ErrorFrame"),
    ("canfd lower", "   0.005200 canfd   1 Rx 123 1 0 2 2 01 02"),
    ("short payload", "   0.006000 1  123             Rx   d 8 01 02"),
    ("payload fails", "   0.006100 1  123             Rx   d 8 01 02 Length = 5"),
    ("raw dlc", "   0.006200 1  123             Rx   d 9 01 02 03 04 05 06 07 08 09 0A 0B 0C"),
    ("raw dlc F", "   0.006200 1  123             Rx   d F 01 02 03 04 05 06 07 08"),
    ("dlc 08", "   0.006300 1  123             Rx   d 08 01 02 03 04 05 06 07 08"),
    ("one-digit byte", "   0.006400 1  123             Rx   d 2 1 02"),
    ("three-digit byte", "   0.006500 1  123             Rx   d 2 001 02"),
    ("byte above FF", "   0.006600 1  123             Rx   d 2 100 02"),
    ("0x id", "   0.006700 1  0x123           Rx   d 1 01"),
    ("id underscore", "   0.006800 1  1_23            Rx   d 1 01"),
    ("id above 7FF", "   0.006900 1  800             Rx   d 1 01"),
    ("id above 1FFFFFFF", "   0.007000 1  20000000x       Rx   d 1 01"),
    ("x alone", "   0.007100 1  x               Rx   d 1 01"),
    ("channel 0", "   0.007200 0  123             Rx   d 1 01"),
    ("channel 007", "   0.007300 007  123           Rx   d 1 01"),
    ("lower rx", "   0.007400 1  123             rx   d 1 01"),
    ("TX", "   0.007500 1  123             TX   d 1 01"),
    ("capital D", "   0.007600 1  123             Rx   D 1 01"),
    ("no type", "   0.007700 1  123             Rx   8 01"),
    ("type alone", "   0.007800 1  123             Rx   d"),
    ("long timestamp", "   " + "9" * 400 + ".5 1  123             Rx   d 1 01"),
    ("exponent", "   1.5e3 1  123             Rx   d 1 01"),
    ("formfeed", "\x0c   0.007900 1  123             Rx   d 1 01"),
    ("nbsp", "   0.008000 1  123\xa0Rx   d 1 01"),
    ("nbsp in data", "   0.008000 1  123 Rx   d 2 01\xa002"),
    ("unicode digits", "   0.008100 \u0661  123 Rx   d 1 01"),
    ("vertical tab", "   0.008200 1\x0b123 Rx d 1 01"),
    ("rx stuck", "   0.008300 1  123 Rxx d 1 01"),
    ("tail in data", "   0.008400 1  123 Rx d 2 01 02x"),
    ("extra bytes", "   0.008500 1  123 Rx d 1 01 02 03"),
    # after the DLC's bytes: a greedy match (Python 3.10) takes the line, a possessive one hands it over
    ("tail after the DLC's bytes", "   0.008600 1  123 Rx d 1 01 02x"),
    ("a 3-digit byte", "   0.008700 1  123 Rx d 2 01 023"),
]


def _file(tmp_path: Path, body: list[str], header: str = HEADER, name: str = "x.asc", newline: str = "\n") -> Path:
    path = tmp_path / name
    text = header + "".join(line + "\n" for line in body) + "End TriggerBlock\n"
    path.write_bytes(text.replace("\n", newline).encode("utf-8"))
    return path


_SEP = st.sampled_from([" ", " ", "  ", "\t", " \t ", "\xa0", "\x0c", ""])
_TOKEN = st.sampled_from([
    "0.001000", "0.0015", "12.5", "-0.5", "1.5e3", "1", "0", "2", "007", "CANFD", "canfd", "123", "7FF", "800", "1Fx",
    "1FFFFFFFx", "20000000x", "0x12", "abcX", "Rx", "Tx", "rx", "TX", "d", "D", "r", "R", "8", "2", "0", "9", "F",
    "01", "ab", "FF", "1", "001", "100", "ErrorFrame", "Length", "=", "Start", "of", "measurement", "//", "x",
])
_TIMES = st.sampled_from(["0.001000", "0.002000", "0.0005", "3.25"])


@settings(max_examples=100, deadline=None)
@given(st.lists(st.one_of(
    # lines near the plain shape: a field or a separator changed here and there
    st.tuples(_TIMES, st.sampled_from(["1", "2", "0"]), st.sampled_from(["123", "1ABx", "7ff", "800", "0x1"]),
              st.sampled_from(["Rx", "Tx", "rx"]), st.sampled_from(["d", "r", "D"]),
              st.sampled_from(["0", "1", "2", "8", "9"]), st.lists(st.sampled_from(["01", "aB", "1", "100", "Ff"]),
                                                                   max_size=9), _SEP, st.booleans())
    .map(lambda f: f[7].join(f[:6]) + "".join(" " + b for b in f[6]) + ("  Length = 1" if f[8] else "")),
    st.lists(st.tuples(_TOKEN, _SEP), max_size=8).map(lambda ts: "".join(a + b for a, b in ts)),  # token soup
), max_size=40), st.sampled_from([None, 64, 300]))
def test_random_lines(tmp_path_factory: pytest.TempPathFactory, lines: list[str], block_chars: int | None) -> None:
    """Lines of fields and separators drawn at random, around plain ones: python-can's frames, counts and errors."""
    plain = "   0.000500 1  123             Rx   d 2 01 02"
    path = _file(tmp_path_factory.mktemp("asc"), [plain, *lines, plain])
    frames, skips, _ = same(path, block_chars=block_chars)
    event(f"handed over after {'no' if skips == [0] else 'some'} frames" if skips else "taken")
    event(f"{min(len(frames), 3)}+ frames")


@pytest.mark.parametrize(("what", "line"), ODD, ids=[w for w, _ in ODD])
def test_canalyzer_lines(tmp_path: Path, what: str, line: str) -> None:
    """Each kind of line among plain ones, alone and at a block's start, middle and end: equal to python-can."""
    for block_chars in (None, 100, 200):
        same(_file(tmp_path, [*PLAIN * 3, line, *PLAIN * 3]), block_chars=block_chars)
    same(_file(tmp_path, [line]))


def test_plain_canalyzer_is_taken(tmp_path: Path) -> None:
    """Plain lines with trailing fields, hex in any case, tabs, skipped lines between them: no hand-over."""
    skipped = [line for _, line in ODD[:10]]
    frames, skips, pieces = same(_file(tmp_path, [*PLAIN * 5, *skipped, *PLAIN * 30]))
    assert skips == [] and len(frames) == 35 * len(PLAIN)
    assert frames[0] == Frame(0.001249, "can1", 0x303, bytes.fromhex("9CFC15FF02FF34FF"))
    assert frames[1] == Frame(0.0015, "can0", 0x18FEF100, bytes.fromhex("9CFC15FF02FF34FF"), True)
    assert frames[4] == Frame(0.002, "can2", 0x1FFFFFFF, b"\xaa\xbb", True)
    frames, skips, pieces = same(_file(tmp_path, [*PLAIN[:2] * 40, *skipped, *PLAIN[1:2] * 40]), block_chars=500)
    assert skips == [] and sum(type(p) is Columns for p in pieces) >= 3


@pytest.mark.parametrize(("header", "python_cans"), [
    ("", False), ("base hex\n", False), ("base dec  timestamps absolute\n", True), ("base HEX\n", True),
    ("base dec\nbase hex\n", False), ("base hex\nbase dec\n", True), ("base HEX\nbase hex\n", True),
    ("date Mon Jan 01 00:00:00 2024\nbase hex timestamps relative\nno internal events logged\n", False),
    ("\ufeffdate Mon Jan 01 00:00:00 2024\nbase hex  timestamps absolute\n", False), ("// only a comment\n", False),
    ("date garbage\n", False), ("   0.000100 1  100             Rx   d 1 01\n", False), ("\n\n", False),
], ids=lambda h: repr(h)[:30])
def test_headers(tmp_path: Path, header: str, python_cans: bool) -> None:
    """Headers python-can reads (its last line dropped, whatever it is), ``base dec``, odd ones: equal."""
    frames, skips, _ = same(_file(tmp_path, PLAIN * 4, header=header))
    assert skips == ([0] if python_cans else [])
    if header == "":  # python-can drops the line that ends its header: here the first data line
        assert len(frames) == 4 * len(PLAIN) - 1
    assert all(f.t != 0.0001 for f in frames)


@pytest.mark.parametrize("newline", ["\r\n", "\r"])
def test_line_endings(tmp_path: Path, newline: str) -> None:
    """CR LF and CR line ends read as python-can reads them (universal newlines), split across blocks too."""
    for block_chars in (None, 101):
        _, skips, _ = same(_file(tmp_path, PLAIN * 20, newline=newline), block_chars=block_chars)
        assert skips == []


def test_no_line_break_at_end_and_empty(tmp_path: Path) -> None:
    """A last line without its line break; files with no frame (empty, header only, bad base): the same error."""
    path = tmp_path / "x.asc"
    path.write_text(HEADER + "\n".join(PLAIN))
    frames, skips, _ = same(path)
    assert skips == [] and len(frames) == len(PLAIN)
    for text in ("", HEADER, HEADER + "End TriggerBlock\n", "base dec\n", "base hex\n" + PLAIN[0] + "\n"):
        path.write_text(text)
        with pytest.raises(LogFormatError, match="empty log"):
            list(read_log(path))
        same(path)


# --------------------------------------------------------------------------- (3) python-can from the middle on


@pytest.mark.parametrize(("what", "line"), [o for o in ODD if o[0] in ("error frame", "can fd", "payload fails",
                                                                      "remote dlc", "short payload")])
def test_hand_over_after_blocks(tmp_path: Path, what: str, line: str) -> None:
    """An odd line after several blocks: the blocks before are canguard's, python-can passes over them."""
    body = [f"   {i / 1000:.6f} {1 + (i // 50) % 2}  {0x100 + i % 7:X}             Rx   d 2 {i % 256:02X} 00"
            for i in range(1500)]
    body[1250] = line
    body[1400] = "   1.000000 1  123             Rx   d 1 01"  # a step back after the hand-over
    _, skips, pieces = same(_file(tmp_path, body), block_chars=2048)
    assert len(skips) == 1 and skips[0] >= 1000 and sum(type(p) is Columns for p in pieces) >= 20
    if what == "payload fails":
        with pytest.raises(LogFormatError, match=r"ASC reader failed after 1250 frames: ValueError"):
            list(read_log(_file(tmp_path, body)))


def test_hand_over_counts_against_the_last_frame(tmp_path: Path) -> None:
    """python-can's first frame after the hand-over repeats (or goes back from) canguard's last: counted so."""
    for odd in ("   1.000000 1  ErrorFrame", "   0.500000 1  ErrorFrame", "   1.000000 1  123 Rx r 2"):
        for at in range(3, 9):
            body = ["   1.000000 1  123             Rx   d 1 01"] * 12
            body[at] = odd
            for block_chars in (40, 90, 130):
                _, skips, _ = same(_file(tmp_path, body, header=""), block_chars=block_chars)
                assert len(skips) == 1


# --------------------------------------------------------------------------- (4) compressed


@pytest.mark.parametrize("how", ["gz", "xz"])
def test_compressed(tmp_path: Path, how: str) -> None:
    """.asc.gz and .asc.xz: equal to python-can, taken by canguard's reader; truncated: the same frames and error."""
    path = _file(tmp_path, PLAIN * 300)
    data = path.read_bytes()
    packed = tmp_path / f"x.asc.{how}"
    packed.write_bytes(gzip.compress(data) if how == "gz" else lzma.compress(data))
    frames, skips, _ = same(packed, how, block_chars=1000)
    assert skips == [] and len(frames) == 300 * len(PLAIN)
    assert list(read_log(packed)) == frames
    packed.write_bytes(packed.read_bytes()[: len(packed.read_bytes()) // 2])
    frames, skips, _ = same(packed, how, block_chars=1000)
    assert len(skips) == 1 and 0 < len(frames) < 300 * len(PLAIN)


def test_not_compressed(tmp_path: Path) -> None:
    """A .asc.gz that is not gzip: python-can's error, word for word."""
    path = tmp_path / "x.asc.gz"
    path.write_text(HEADER + PLAIN[0] + "\n")
    _, skips, _ = same(path, "gz")
    assert skips == [0]


# --------------------------------------------------------------------------- replay


def _python_can_only(p: Path, gz: str, st: ReadStats, owner: LogFrames) -> Iterator[Columns | list[Frame]]:
    return python_can_chunks(p, "asc", gz, st, owner)


OVERLOAD_S = 4.0
"""Seconds of the overload example replayed as ASC: its I²t trip (at 3 s) and the stop, 10,285 frames."""


@pytest.fixture(scope="module")
def overload_asc(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    """The first :data:`OVERLOAD_S` of the overload example written as ASC by python-can's writer (once for the
    module), and how many frames it holds."""
    d = tmp_path_factory.mktemp("asc_overload")
    log, candump = d / "overload.asc", d / "overload.log"
    candump.write_bytes(gzip.decompress((REPO / "examples" / "overload.log.gz").read_bytes()))
    count, start = 0, None
    with can.Logger(str(log)) as writer:
        for msg in can.CanutilsLogReader(str(candump)):
            start = msg.timestamp if start is None else start
            if msg.timestamp - start >= OVERLOAD_S:
                break
            writer.on_message_received(msg)
            count += 1
    return log, count


@pytest.mark.parametrize("odd", [None, "   3.000000 1  ErrorFrame"])
def test_replay_summary(tmp_path: Path, overload_asc: tuple[Path, int], odd: str | None,
                        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """``canguard replay LOG.asc --json``: the same summary with canguard's reader as with python-can's alone."""
    log = tmp_path / "overload.asc"
    lines = overload_asc[0].read_text().splitlines(keepends=True)
    if odd is not None:
        lines.insert(len(lines) // 2, odd + "\n")
    log.write_text("".join(lines))
    argv = ["replay", str(log), "-c", str(REPO / "config" / "examples" / "robot_guard.yaml"), "--json"]

    def summary() -> dict[str, Any]:
        capsys.readouterr()
        code = main(argv)
        out, err = capsys.readouterr()
        assert code in (0, 1), err
        doc: dict[str, Any] = json.loads(out)
        return doc

    with _spied() as skips:
        ours = summary()
    assert len(skips) == (odd is not None)
    monkeypatch.setattr(canguard.io.asc_blocks, "asc_chunks", _python_can_only)
    assert summary() == ours
    assert ours["frames"]["read"] == overload_asc[1] + (odd is not None)
    assert "Axis0I2t" in {t["node"] for t in ours["trips"]}, "the overload's I²t trip is in the part replayed"
