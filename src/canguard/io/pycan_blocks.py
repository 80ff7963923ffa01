"""python-can's log readers (ASC, BLF, TRC, CSV, MF4) a block at a time: :class:`Columns` where the rows allow.

The replay engine works on :class:`~canguard.io.candump.Columns` blocks (one channel,
timestamps that never go back) as columns; this module gives it python-can's
messages in that shape, so that every format reaches the column path, not only
candump logs. Each block of up to :data:`BLOCK` messages is taken apart into columns
at once (one ``attrgetter`` over the messages), and each row is written the way
:class:`Columns` holds a candump row and :meth:`Columns.frame` reads it back:
``ts`` the ``repr`` of the frame's float timestamp (``float`` gives back the same
float, and distinct floats have distinct texts), ``ids`` 3 (standard) or 8
(extended) upper-case hex digits, ``data`` the payload as hex text, ``fd`` the
BRS / ESI flags digit of CAN FD rows, ``remote`` the DLC of remote rows (-1: none).
``Columns.frame(i)`` is, field for field, what :func:`~canguard.io.pycan.frame_from_message`
makes of the same message.

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
from collections.abc import Iterator, Sequence
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

BLOCK = 4096
"""Messages taken from python-can's reader at a time (one block when all of them fit)."""

MIN_BLOCK = 16
"""Shorter runs of rows a block could hold go as frames."""

_FIELDS = attrgetter(
    "timestamp", "channel", "arbitration_id", "is_extended_id", "data", "dlc",
    "is_fd", "is_remote_frame", "is_error_frame", "bitrate_switch", "error_state_indicator",
)


def _id_text(key: tuple[Any, Any]) -> str | None:
    """How candump -L writes the id of ``(arbitration_id, is_extended_id)``; None when it cannot."""
    cid, ext = int(key[0]), key[1]
    if ext:
        return f"{cid:08X}" if 0 <= cid <= CAN_EFF_MASK else None
    return f"{cid:03X}" if 0 <= cid <= CAN_SFF_MASK else None


class _Batch:
    """One batch of python-can messages as columns, and which rows a :class:`Columns` block can hold."""

    def __init__(self, msgs: list[can.Message], names: dict[Any, str], ids: dict[tuple[Any, Any], str | None]) -> None:
        self.msgs = msgs
        self.n = n = len(msgs)
        (raw_ts, raw_ch, cids, exts, datas, dlcs, fds, rems, errs, brss, esis) = zip(*map(_FIELDS, msgs), strict=True)
        self.ts = ts = [float(x or 0.0) for x in raw_ts]  # as frame_from_message: float(msg.timestamp or 0.0)
        for c in set(raw_ch) - names.keys():
            names[c] = channel_name(c)
        self.chans = list(map(names.__getitem__, raw_ch))
        keys = list(zip(cids, exts, strict=True))
        for k in set(keys) - ids.keys():
            ids[k] = _id_text(k)
        self.ids: list[str | None] = list(map(ids.__getitem__, keys))
        if None in datas:
            datas = tuple(b"" if d is None else d for d in datas)
        if set(map(type, datas)) == {bytearray}:  # python-can's Message keeps its data as a bytearray
            self.hexes = list(map(bytearray.hex, datas))
        else:
            self.hexes = [bytes(d).hex() for d in datas]
        lens = list(map(len, datas))
        self.fd: dict[int, int] = {}
        self.remote: dict[int, int] = {}
        if (
            not (any(fds) or any(rems) or any(errs) or any(brss) or any(esis))
            and lens == list(dlcs) and max(lens) <= 8 and None not in self.ids and math.isfinite(sum(ts))
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
        ts = self.ts if whole else self.ts[a:b]
        ids: list[Any] = self.ids if whole else self.ids[a:b]
        channel = self.chans[a]
        return Columns(b - a, list(map(repr, ts)), [channel] * (b - a), ids, self.hexes if whole else self.hexes[a:b],
                       True, channel, fd or None, remote or None)

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


def python_can_chunks(p: Path, fmt: str, gz: str, st: ReadStats, owner: LogFrames) -> Iterator[Columns | list[Frame]]:
    """One of python-can's readers as :class:`Columns` blocks and frame lists; its errors as LogFormatError."""
    reader: _Messages | None = None
    frames = 0
    last_t = -math.inf
    names: dict[Any, str] = {}
    ids: dict[tuple[Any, Any], str | None] = {}
    try:
        reader = _Messages(p, fmt, gz)
        while msgs := reader.next_batch(BLOCK):
            batch = _Batch(msgs, names, ids)
            ts = batch.ts
            prev = [last_t, *ts[:-1]]
            st.backwards_timestamps += sum(map(lt, ts, prev))
            st.repeated_timestamps += sum(map(eq, ts, prev))
            last_t = ts[-1]
            frames += batch.n
            st.frames += batch.n
            yield from batch.pieces()
            owner._position(reader.position(st))
    finally:
        if reader is not None:
            reader.close()
        owner._done()
    if frames == 0:
        raise LogFormatError(f"{p}: empty log: no frames")
