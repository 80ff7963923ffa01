"""Vector ASC logs read by canguard itself: plain classic CAN data lines a block at a time, the rest by python-can.

python-can's :class:`can.ASCReader` is the reference, and what this reader gives is,
frame for frame and count for count, what :func:`~canguard.io.pycan_blocks.python_can_chunks`
gives for the same file (``tests/test_asc_blocks.py`` proves it against python-can on
random and hand-written logs). Only one line shape is parsed here, the one python-can's
``ASCWriter`` and CANalyzer / CANoe write for classic CAN data frames::

       0.001249 2  303             Rx   d 8 9C FC 15 FF 02 FF 34 FF  Length = 231910 BitCount = 119 ID = 771

a timestamp (digits, a dot, digits), a channel number (ASC channel 1 is python-can's
channel 0: ``can0``), a hex id (``x`` after it: extended) within 7FF / 1FFFFFFF, ``Rx``
or ``Tx``, ``d``, a DLC of 0 to 8 and at least that many two-digit hex bytes (python-can
takes the first DLC of them and ignores whatever follows). Spaces and tabs separate
the fields. A whole text block is matched by one regular expression (one C-level
``findall``); its columns become a :class:`~canguard.io.candump.Columns` block the way
:class:`~canguard.io.pycan_blocks._Batch` makes one of python-can's messages.

Every other line is judged by python-can's own rules (its regular expressions, copied
here and checked against python-can's by the tests): a line python-can skips (comments,
``Begin Triggerblock``, ``Start of measurement``, events, statistics...) is skipped. A
line python-can would read as a frame and that has not the plain shape (error frames,
remote frames, CAN FD, a raw DLC, a short payload, an id out of range...), a header
this reader does not handle (``base dec``), or a decompression error, and the rest of
the file is python-can's: before anything of that block is given, the file is read
again by ``python_can_chunks``, which passes over the messages given already.
"""

from __future__ import annotations

import io
import math
import re
import sys
from collections.abc import Iterator
from itertools import compress
from operator import itemgetter
from pathlib import Path
from typing import Any

from canguard.errors import LogFormatError
from canguard.io.candump import Columns
from canguard.io.frame import Frame
from canguard.io.logtypes import (
    CAN_EFF_MASK,
    CAN_SFF_MASK,
    LogFrames,
    ReadStats,
    _new,
    decompress_errors,
    open_decompressed,
)
from canguard.io.pycan import channel_name
from canguard.io.pycan_blocks import _Batch, count_batch, python_can_chunks

BLOCK_CHARS = 1 << 17
"""Characters read per block (about 2,000 lines of python-can's ASC writer, as many as pycan_blocks.BLOCK messages;
reading 300 k frames in-process: 0.30 s CPU, 0.33 s with blocks of 1 << 18, 0.35 s with 1 << 19: caches)."""

# python-can 4.6's ASCReader (can/io/asc.py), copied: tests/test_asc_blocks.py checks them against python-can's.
ASC_TRIGGER_REGEX = re.compile(r"begin\s+triggerblock\s+\w+\s+(?P<datetime_string>.+)", re.IGNORECASE)
ASC_MESSAGE_REGEX = re.compile(r"\d+\.\d+\s+(\d+\s+(\w+\s+(Tx|Rx)|ErrorFrame)|CANFD)", re.ASCII | re.IGNORECASE)
START_REGEX = re.compile(r"^\d+\.\d+\s+Start of measurement")
DATE_REGEX = re.compile(r"date\s+\w+\s+(?P<datetime_string>.+)", re.IGNORECASE)
BASE_REGEX = re.compile(r"base\s+(?P<base>hex|dec)(?:\s+timestamps\s+(?P<timestamp_format>absolute|relative))?",
                        re.IGNORECASE)
COMMENT_REGEX = re.compile(r"//.*")

_PLAIN = (r"S*+(\d++\.\d++)S++(\d++)S++([0-9A-Fa-f]++[xX]?+)S++[RT]xS++dS++([0-8])((?:S++[0-9A-Fa-f][0-9A-Fa-f])*+)"
          r"(?:S[^\n]*+)?+\n|([^\n]*+)\n")
if sys.version_info < (3, 11):
    # Python 3.10's re has no possessive quantifiers: the greedy ones. They read every field the same (each ends
    # at a separator it cannot hold); on a line whose data has a malformed token ("02x", "023") a greedy match can
    # give back whole byte pairs from the end of the data to the trailing text instead of taking the line as not
    # plain. The bytes kept are still the line's first tokens, so either the DLC check finds them short (python-can's
    # reader takes the line, as with possessive quantifiers) or they hold the DLC bytes python-can would read.
    _PLAIN = _PLAIN.replace("*+", "*").replace("++", "+").replace("?+", "?")
_LINE = re.compile(_PLAIN.replace("S", " "), re.ASCII)
"""One line: a plain data line's timestamp, channel, id, DLC and bytes (each a whole token: nothing is given back
once matched); or any other line. Spaces separate the fields: blocks without tabs (faster than a class)."""
_LINE_TABS = re.compile(_PLAIN.replace("S", "[ \t]"), re.ASCII)
"""The same, with tabs as well as spaces between the fields."""
_COLUMNS = tuple(map(itemgetter, range(5)))
_TWICE = {str(d): 2 * d for d in range(9)}
_F = False


class _Fallback(Exception):
    """This block is not all of the plain shape: python-can reads the file from here."""


def _skipped(line: str) -> bool:
    """True when python-can's ASCReader passes over ``line`` (a line of the measurement, after the header)."""
    s = line.strip()
    return bool(ASC_TRIGGER_REGEX.match(s) or START_REGEX.match(s)) or not ASC_MESSAGE_REGEX.match(s)


def _header(f: Any) -> bool:
    """Read the header lines as python-can does (its last line, whatever it is, is consumed); False: not base hex."""
    base = "hex"
    while line := f.readline():
        s = line.strip()
        if DATE_REGEX.match(s):  # timestamps are relative (python-can's default): the date changes nothing
            continue
        if m := BASE_REGEX.match(s):
            if m.group("base") not in ("hex", "dec"):  # "HEX": python-can fails, now or after a good one
                return False
            base = m.group("base")  # "dec" is python-can's
            continue
        if COMMENT_REGEX.match(s):
            continue
        break  # "internal events logged" or anything else: python-can drops this line
    return base == "hex"


class _AscBatch(_Batch):
    """A block of plain ASC data rows, every one of which a :class:`Columns` block can hold."""

    def __init__(self, ts: list[float], chans: list[str], ids: list[str | None], hexes: list[str]) -> None:
        self.n, self.ts, self.chans, self.ids, self.hexes = len(ts), ts, chans, ids, hexes
        self.fd, self.remote, self.good = {}, {}, None

    def frame(self, i: int) -> Frame:
        text = self.ids[i]
        assert text is not None
        return _new(Frame, (self.ts[i], self.chans[i], int(text, 16), bytes.fromhex(self.hexes[i]), len(text) == 8,
                            _F, _F, _F, _F, _F, -1))


class _Parser:
    """The columns of plain blocks; what it has learnt (channels, ids) is kept from block to block."""

    def __init__(self) -> None:
        self.names: dict[str, str] = {}
        self.ids: dict[str, str] = {}

    def batch(self, block: str) -> _AscBatch | None:
        """The data rows of ``block`` (whole lines) as a batch, None when it has none; _Fallback when not plain."""
        rows = (_LINE_TABS if "\t" in block else _LINE).findall(block)
        if not rows:
            return None
        ts, chs, cids, dlcs, datas = (list(map(get, rows)) for get in _COLUMNS)
        if "" in ts:  # lines not of the plain shape: python-can must skip every one of them
            if not all(map(_skipped, map(itemgetter(5), compress(rows, map((0).__eq__, map(len, ts)))))):
                raise _Fallback
            keep = list(map(bool, ts))
            ts, chs, cids, dlcs, datas = (list(compress(c, keep)) for c in (ts, chs, cids, dlcs, datas))
            if not ts:
                return None
        times = list(map(float, ts))
        if not math.isfinite(sum(times)):
            raise _Fallback
        names = self.names
        distinct = set(chs)
        for c in distinct - names.keys():
            names[c] = channel_name(int(c) - 1)  # python-can: ASC channel 1 is its channel 0
        chans = [names[chs[0]]] * len(chs) if len(distinct) == 1 else list(map(names.__getitem__, chs))
        known = self.ids
        for tok in set(cids) - known.keys():
            ext = tok[-1] in "xX"
            value = int(tok[:-1] if ext else tok, 16)
            if value > (CAN_EFF_MASK if ext else CAN_SFF_MASK):
                raise _Fallback  # python-can gives it; a block cannot hold it
            known[tok] = f"{value:08X}" if ext else f"{value:03X}"
        ids: list[str | None] = list(map(known.__getitem__, cids))
        joined = "\n".join(datas).replace(" ", "")
        if "\t" in joined:
            joined = joined.replace("\t", "")
        hexes = joined.lower().split("\n")
        want = list(map(_TWICE.__getitem__, dlcs))
        if list(map(len, hexes)) != want:
            for i, (text, size) in enumerate(zip(hexes, want, strict=True)):
                if len(text) < size:
                    raise _Fallback  # fewer bytes than the DLC (python-can: a short payload, or a failure)
                hexes[i] = text[:size]  # python-can takes the first DLC bytes and ignores the rest
        return _AscBatch(times, chans, ids, hexes)


def _block(f: Any) -> str:
    """The next block of whole lines ("" at the end of the log)."""
    block: str = f.read(BLOCK_CHARS)
    if block and block[-1] != "\n":
        block += f.readline()
        if block[-1] != "\n":
            block += "\n"  # the last line, without its line break
    return block


def asc_chunks(p: Path, gz: str, st: ReadStats, owner: LogFrames) -> Iterator[Columns | list[Frame]]:
    """An ASC log as :class:`Columns` blocks and frame lists: what ``python_can_chunks(p, "asc", ...)`` gives."""
    frames = 0
    last_t = -math.inf
    fallback = False
    raw = open(p, "rb")  # noqa: SIM115 -- closed in the finally
    f = None
    block = ""
    try:
        try:
            f = io.TextIOWrapper(open_decompressed(raw, gz), encoding="utf-8", errors="replace")  # as python-can's
            fallback = not _header(f)
            block = "" if fallback else _block(f)
        except decompress_errors():
            fallback = True  # python-can meets the same error at the same place, and says so
        parser = _Parser()
        while block and not fallback:
            try:
                batch = parser.batch(block)
            except _Fallback:
                fallback = True
                break
            if batch is not None:
                last_t = count_batch(st, batch, last_t)
                frames += batch.n
                yield from batch.pieces()
            owner.reached(raw.tell())
            try:
                block = _block(f)
            except decompress_errors():
                fallback = True
    finally:
        if f is not None:
            f.close()
        raw.close()
        if not fallback:
            owner.finished()
    if fallback:  # the rest of the file is python-can's, which passes over the frames given already
        yield from python_can_chunks(p, "asc", gz, st, owner, skip=frames, last_t=last_t)
    elif frames == 0:
        raise LogFormatError(f"{p}: empty log: no frames")
