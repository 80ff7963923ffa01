"""python-can's log readers (ASC, BLF, TRC, CSV, MF4) a block at a time: :class:`Columns` where the rows allow.

The replay engine works on :class:`~canguard.io.candump.Columns` blocks (one channel,
timestamps that never go back) as columns; this module gives it python-can's
messages in that shape, so that every format reaches the column path, not only
candump logs. Each block of up to :data:`BLOCK` messages is taken apart into columns
at once (one C-level ``attrgetter`` pass per field), and each row is held the way
:class:`Columns` holds a candump row and :meth:`Columns.frame` reads it back: ``ids``
3 (standard) or 8 (extended) upper-case hex digits, ``data`` the payload as hex
text, ``fd`` the BRS / ESI flags digit of CAN FD rows, ``remote`` the DLC of remote
rows (-1: none); ``ts`` are the frames' float timestamps themselves (a candump
block keeps its texts; both give the time with ``float``, which is all the engine
asks of them; formatting python-can's floats to exact texts cost more than the
column path saves). ``Columns.frame(i)`` is, field for field, what
:func:`~canguard.io.pycan.frame_from_message` makes of the same message.

Rows a block cannot hold go as lists of frames (``frame_from_message``), exactly as
the candump reader sends lines its block parser refuses: error frames, ids out of
range, a DLC other than the payload's length (raw DLCs, FD frames whose DLC is not
their length), BRS / ESI on a classic frame, remote frames with data or a DLC
above 8, payloads of no CAN (FD) length, timestamps that are not finite. A block
also ends where the channel changes or a timestamp goes back (that row goes as a
frame); runs shorter than :data:`MIN_BLOCK` rows go as frames too (a log whose
channels interleave frame by frame would otherwise make one-row blocks, which the
engine takes frame by frame anyway).
"""

from __future__ import annotations

import math
import operator
from collections.abc import Iterator, Sequence
from itertools import compress
from operator import attrgetter, eq, le, lt
from pathlib import Path
from typing import TYPE_CHECKING, Any

from canguard.errors import LogFormatError
from canguard.io.candump import Columns
from canguard.io.frame import Frame
from canguard.io.logtypes import CAN_EFF_MASK, CAN_SFF_MASK, CANFD_BRS, CANFD_ESI, CANFD_LENGTHS, LogFrames, ReadStats
from canguard.io.pycan import _Messages, channel_name, frame_from_message

if TYPE_CHECKING:
    import can

BLOCK = 2048
"""Messages taken from python-can's reader at a time (one block when all of them fit; 2048 replayed a
600 k-frame BLF log 3-5 % faster than 4096 or 1024: caches, and fewer live messages for the garbage collector)."""

MIN_BLOCK = 16
"""Shorter runs of rows a block could hold go as frames."""

_TIMESTAMP, _CHANNEL, _ID, _EXTENDED, _DATA, _DLC = map(
    attrgetter, ("timestamp", "channel", "arbitration_id", "is_extended_id", "data", "dlc"))
_FLAGS = tuple(map(attrgetter, ("is_fd", "is_remote_frame", "is_error_frame", "bitrate_switch",
                                "error_state_indicator")))
"""The flags of a row a block holds: only CAN FD (with BRS / ESI) and remote rows, with their dict."""


def _texts(cache: dict[Any, str | None], cids: list[Any], extended: bool) -> dict[Any, str | None]:
    """``cache`` (id -> how candump -L writes it, None when it cannot) completed for ``cids``."""
    for cid in set(cids) - cache.keys():
        i = int(cid)
        if extended:
            cache[cid] = f"{i:08X}" if 0 <= i <= CAN_EFF_MASK else None
        else:
            cache[cid] = f"{i:03X}" if 0 <= i <= CAN_SFF_MASK else None
    return cache


class _Batch:
    """One batch of python-can messages as columns, and which rows a :class:`Columns` block can hold."""

    def __init__(self, msgs: list[can.Message], names: dict[Any, str], std: dict[Any, str | None],
                 ext: dict[Any, str | None]) -> None:
        self.msgs = msgs
        self.n = n = len(msgs)
        raw_ts = list(map(_TIMESTAMP, msgs))
        if 0.0 in raw_ts or None in raw_ts:  # as frame_from_message: float(msg.timestamp or 0.0)
            self.ts = ts = [float(x or 0.0) for x in raw_ts]
        else:
            self.ts = ts = list(map(float, raw_ts))  # float(x) is x for a float: no new object
        raw_ch = list(map(_CHANNEL, msgs))
        distinct = set(raw_ch)
        for c in distinct - names.keys():
            names[c] = channel_name(c)
        self.chans = [names[raw_ch[0]]] * n if len(distinct) == 1 else list(map(names.__getitem__, raw_ch))
        cids = list(map(_ID, msgs))
        exts = list(map(_EXTENDED, msgs))
        self.ids: list[str | None]
        if not any(exts):
            self.ids = list(map(_texts(std, cids, False).__getitem__, cids))
        elif all(exts):
            self.ids = list(map(_texts(ext, cids, True).__getitem__, cids))
        else:
            _texts(std, list(compress(cids, map(operator.not_, exts))), False)
            _texts(ext, list(compress(cids, exts)), True)
            self.ids = [ext[c] if e else std[c] for c, e in zip(cids, exts, strict=True)]
        datas = list(map(_DATA, msgs))
        if set(map(type, datas)) == {bytearray}:  # python-can's Message keeps its data as a bytearray
            self.hexes = list(map(bytearray.hex, datas))
        else:
            datas = [b"" if d is None else bytes(d) for d in datas]
            self.hexes = list(map(bytes.hex, datas))
        lens = list(map(len, datas))
        dlcs = list(map(_DLC, msgs))
        flags = [list(map(get, msgs)) for get in _FLAGS]
        fds, rems, errs, brss, esis = flags
        self.fd: dict[int, int] = {}
        self.remote: dict[int, int] = {}
        if (
            not any(map(any, flags))
            and lens == dlcs and max(lens) <= 8 and math.isfinite(sum(ts))
            and ((None not in std.values() and None not in ext.values()) or None not in self.ids)
        ):
            self.good: Sequence[bool] | None = None  # every row
            return
        good = [True] * n
        for i in range(n):
            d, dlc = lens[i], dlcs[i]
            if errs[i] or self.ids[i] is None or not math.isfinite(ts[i]):
                good[i] = False
            elif rems[i]:
                if fds[i] or brss[i] or esis[i] or d or type(dlc) is not int or not 0 <= dlc <= 8:
                    good[i] = False
                else:
                    self.remote[i] = dlc or -1
            elif fds[i]:
                if d != dlc or d not in CANFD_LENGTHS:
                    good[i] = False
                else:
                    self.fd[i] = (CANFD_BRS if brss[i] else 0) | (CANFD_ESI if esis[i] else 0)
            elif brss[i] or esis[i] or d != dlc or d > 8:
                good[i] = False
        self.good = good

    def frame(self, i: int) -> Frame:
        """Row ``i`` as a frame (what the frame-by-frame reader gives)."""
        return frame_from_message(self.msgs[i], self.chans[i])

    def columns(self, a: int, b: int) -> Columns:
        """Rows ``a..b-1`` (all of them good, one channel, ordered) as a block."""
        n = self.n
        whole = a == 0 and b == n
        fd = {i - a: v for i, v in self.fd.items() if a <= i < b} if self.fd else None
        remote = {i - a: v for i, v in self.remote.items() if a <= i < b} if self.remote else None
        ids: list[Any] = self.ids if whole else self.ids[a:b]
        channel = self.chans[a]
        return Columns(b - a, self.ts if whole else self.ts[a:b], [channel] * (b - a), ids,
                       self.hexes if whole else self.hexes[a:b], True, channel, fd or None, remote or None)

    def pieces(self) -> Iterator[Columns | list[Frame]]:
        """The batch as blocks and frame lists, in order."""
        ts, chans, n = self.ts, self.chans, self.n
        if self.good is None and all(map(le, ts, ts[1:])) and chans.count(chans[0]) == n:
            yield self.columns(0, n)  # the usual case: one channel, in order, every row plain
            return
        good = self.good if self.good is not None else [True] * n
        frames: list[Frame] = []
        start = -1  # the first row of the run being gathered; -1: none
        for i in range(n + 1):
            if start >= 0 and (i == n or not good[i] or chans[i] != chans[start] or ts[i] < ts[i - 1]):
                if i - start >= MIN_BLOCK:
                    if frames:
                        yield frames
                        frames = []
                    yield self.columns(start, i)
                else:
                    frames.extend(map(self.frame, range(start, i)))
                cont = i < n and good[i] and ts[i] >= ts[i - 1]  # a new channel: a new run from here
                start = i if cont else -1
                if i < n and not cont:
                    frames.append(self.frame(i))
            elif start < 0 and i < n:
                if good[i]:
                    start = i
                else:
                    frames.append(self.frame(i))
        if frames:
            yield frames


def count_batch(st: ReadStats, batch: _Batch, last_t: float) -> float:
    """Count ``batch``'s frames in ``st``, and its timestamps that go back or repeat (the first against
    ``last_t``); the batch's last timestamp."""
    ts = batch.ts
    prev = [last_t, *ts[:-1]]
    st.backwards_timestamps += sum(map(lt, ts, prev))
    st.repeated_timestamps += sum(map(eq, ts, prev))
    st.frames += batch.n
    return ts[-1]


def python_can_chunks(p: Path, fmt: str, gz: str, st: ReadStats, owner: LogFrames, skip: int = 0,
                      last_t: float = -math.inf) -> Iterator[Columns | list[Frame]]:
    """One of python-can's readers as :class:`Columns` blocks and frame lists; its errors as LogFormatError.

    ``skip``: messages to pass over first, given (and counted) already by another reader of the same file
    (:mod:`canguard.io.asc_blocks`), the last of them at ``last_t``."""
    reader: _Messages | None = None
    frames = skip
    names: dict[Any, str] = {}
    std: dict[Any, str | None] = {}
    ext: dict[Any, str | None] = {}
    try:
        reader = _Messages(p, fmt, gz)
        while skip > 0:
            if not (passed := len(reader.next_batch(min(skip, BLOCK)))):
                raise LogFormatError(f"{p}: {skip} frames fewer than the first reader read")
            skip -= passed
        while msgs := reader.next_batch(BLOCK):
            batch = _Batch(msgs, names, std, ext)
            last_t = count_batch(st, batch, last_t)
            frames += batch.n
            yield from batch.pieces()
            owner.reached(reader.position(st))
    finally:
        if reader is not None:
            reader.close()
        owner.finished()
    if frames == 0:
        raise LogFormatError(f"{p}: empty log: no frames")
