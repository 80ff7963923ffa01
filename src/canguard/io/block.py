"""One block of CAN frames as numpy columns: what every log reader and the live drain give the engine.

``n`` frames in order as read (a live frame: a block of one); the engine never asks which format it came from::

    time_s     float64 (n,)    the frame's time in the log's (live: the bus's) time base, seconds
    can_id     uint32  (n,)    the arbitration id, without flags (an error frame's id without CAN_ERR_FLAG)
    extended   bool    (n,)    a 29-bit id
    flags      uint8   (n,)    FLAG_FD | FLAG_BRS | FLAG_ESI | FLAG_REMOTE | FLAG_ERROR
    dlc        uint8   (n,)    the data length code as python-can's ``Message.dlc`` gives it: the payload's
                               length, or what a remote frame asks for, or a classic raw DLC of 9..15
    length     uint8   (n,)    payload bytes
    payload    uint8   (n, w)  each row's payload in its first ``length`` bytes, zeros after (``w``: the longest);
                               or a :class:`PayloadSource`, read at first use (:meth:`Block.payload_rows`)
    channel    uint16  (n,)    each row's index into ``channels``
    channels   tuple[str]      the channel names (``can0``; live: the bus name)

A block is a value: nothing writes to its arrays once it is built.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from itertools import repeat
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

import numpy as np

from canguard.errors import LogFormatError
from canguard.io.frame import Frame

if TYPE_CHECKING:
    import can


FLAG_FD = 1
"""A CAN FD frame."""
FLAG_BRS = 2
"""CAN FD bit rate switch."""
FLAG_ESI = 4
"""CAN FD error state indicator."""
FLAG_REMOTE = 8
"""A remote (RTR) frame: no payload; ``dlc`` is what it asks for."""
FLAG_ERROR = 16
"""An error frame (the controller's report: ``can_id`` and payload as the driver gives them)."""

EXT_KEY = 1 << 32
"""Added to an extended id in :attr:`Block.keys` (a standard id is its value): one integer per (id, extended)."""

_NO_ROWS = np.zeros(0, dtype=np.intp)
_LANE_0 = np.zeros(1, dtype=np.uint16)
_new = tuple.__new__  # a Frame from a ready tuple: several times cheaper than Frame(...)
_COLUMNS = (("time_s", np.dtype(np.float64)), ("can_id", np.dtype(np.uint32)), ("extended", np.dtype(np.bool_)),
            ("flags", np.dtype(np.uint8)), ("dlc", np.dtype(np.uint8)), ("length", np.dtype(np.uint8)),
            ("channel", np.dtype(np.uint16)))
_U8 = np.dtype(np.uint8)
_T = TypeVar("_T")


class _cached(Generic[_T]):  # a decorator, as functools.cached_property
    """Computed at first use and kept in the instance (functools.cached_property without its lock's cost)."""

    def __init__(self, fn: Callable[[Any], _T]) -> None:
        self.fn = fn
        self.name = fn.__name__
        self.__doc__ = fn.__doc__

    def __get__(self, obj: Any, owner: Any = None) -> _T:
        value: _T = self.fn(obj)
        obj.__dict__[self.name] = value  # found there from now on: this is not called again
        return value


class PayloadSource(Protocol):
    """A block's payloads not yet made into bytes (a candump block's hex digits): rows made when read."""

    def rows(self, rows: Any) -> np.ndarray:
        """The payloads of ``rows`` (index array or slice), zero-padded to the longest of them."""

    def one(self, i: int) -> bytes:
        """Row ``i``'s payload."""


def frame_from_message(msg: can.Message, channel: str | None = None) -> Frame:
    """A ``can.Message`` as a :class:`Frame` (``channel`` overrides the message's; ``dlc`` as :class:`Frame` says)."""
    data = bytes(msg.data) if msg.data is not None else b""
    dlc, remote = msg.dlc, bool(msg.is_remote_frame)
    return _new(Frame, (float(msg.timestamp or 0.0), channel_name(msg.channel) if channel is None else channel,
                        int(msg.arbitration_id), data, bool(msg.is_extended_id), bool(msg.is_fd),
                        bool(msg.is_error_frame), remote, bool(msg.bitrate_switch), bool(msg.error_state_indicator),
                        -1 if dlc == len(data) or (dlc == 0 and remote) else dlc))


def channel_name(channel: Any) -> str:
    """A python-can channel as a string: ints (and digit strings) become ``canN``, None becomes ``""``."""
    if channel is None:
        return ""
    if isinstance(channel, int) or (isinstance(channel, str) and channel.isdigit()):
        return f"can{channel}"
    return str(channel)


@dataclass(frozen=True, eq=False)
class Block:
    """``n`` CAN frames as numpy columns (see the module docstring); also :meth:`of_frames`, :meth:`of_messages`."""

    time_s: np.ndarray
    can_id: np.ndarray
    extended: np.ndarray
    flags: np.ndarray
    dlc: np.ndarray
    length: np.ndarray
    payload_source: np.ndarray | PayloadSource
    """The payload matrix (:attr:`payload`), or where its rows are read from when asked for."""
    channel: np.ndarray
    channels: tuple[str, ...]

    def __post_init__(self) -> None:
        shape = self.time_s.shape
        for name, dtype in _COLUMNS:
            column = getattr(self, name)
            if column.dtype != dtype or column.shape != shape:
                raise ValueError(f"Block.{name}: expected {dtype.name} of shape {shape}, "
                                 f"got {column.dtype.name} of shape {column.shape}")
        payload = self.payload_source  # a PayloadSource: its reader's rows, checked by it
        if isinstance(payload, np.ndarray) and (payload.dtype != _U8 or payload.ndim != 2
                                                or payload.shape[:1] != shape):
            raise ValueError(f"Block.payload: expected uint8 of shape ({shape[0]}, width), got {payload.dtype.name} "
                             f"of shape {payload.shape}")
        if len(self.channels) > 1 and shape[0] and int(self.channel.max()) >= len(self.channels):
            raise ValueError(f"Block.channel: index {int(self.channel.max())} with {len(self.channels)} channels")

    # -- building ----------------------------------------------------------------------------
    @classmethod
    def of_frames(cls, frames: Iterable[Frame]) -> Block:
        """The frames as a block (the live drain, a simulator, tests)."""
        listed = frames if type(frames) is tuple else tuple(frames)
        return one_block(listed[0]) if len(listed) == 1 else _of_frames(listed)

    @classmethod
    def of_messages(cls, msgs: Sequence[can.Message], channel: str | Sequence[str] | None = None) -> Block:
        """python-can messages as a block (``channel``: one for all, or one per message; ints named ``canN``)."""
        if len(msgs) == 1:  # a live frame
            return one_block(frame_from_message(msgs[0], channel if channel is None or type(channel) is str
                                                else channel[0]))
        if channel is None:
            names: dict[Any, str] = {}  # each message's channel named once
            chans = [names.get(m.channel) or names.setdefault(m.channel, channel_name(m.channel)) for m in msgs]
        else:
            chans = [channel] * len(msgs) if type(channel) is str else list(channel)
        flags = [(FLAG_FD if m.is_fd else 0) | (FLAG_BRS if m.bitrate_switch else 0)
                 | (FLAG_ESI if m.error_state_indicator else 0) | (FLAG_REMOTE if m.is_remote_frame else 0)
                 | (FLAG_ERROR if m.is_error_frame else 0) for m in msgs]
        return _rows([float(m.timestamp or 0.0) for m in msgs], [int(m.arbitration_id) for m in msgs],
                     [bool(m.is_extended_id) for m in msgs], flags, [int(m.dlc) for m in msgs],
                     [bytes(m.data) if m.data is not None else b"" for m in msgs], chans)

    # -- what the engine reads ----------------------------------------------------------------
    @_cached
    def n(self) -> int:
        """How many frames."""
        return int(self.time_s.shape[0])

    def __len__(self) -> int:
        return self.n

    @_cached
    def payload(self) -> np.ndarray:
        """Each row's payload in its first ``length`` bytes, zeros after (see the module docstring)."""
        source = self.payload_source
        return source if isinstance(source, np.ndarray) else source.rows(slice(None))

    def payload_rows(self, rows: Any) -> np.ndarray:
        """:attr:`payload`'s ``rows`` (an index array), made for these rows alone while :attr:`payload` is not."""
        source = self._made_payload()
        return source[rows] if isinstance(source, np.ndarray) else source.rows(rows)

    @_cached
    def keys(self) -> np.ndarray:
        """Each row's id as one integer (int64): the id, plus :data:`EXT_KEY` when extended."""
        return self.can_id.astype(np.int64) + self.extended.astype(np.int64) * EXT_KEY

    @_cached
    def times(self) -> list[float]:
        """:attr:`time_s` as a list of floats (rows read one by one)."""
        return self.time_s.tolist()

    @_cached
    def ordered(self) -> bool:
        """No row's time is before the previous row's."""
        t = self.time_s
        return bool(t.size < 2 or not (t[1:] < t[:-1]).any())

    @_cached
    def order(self) -> tuple[int, int]:
        """(rows whose time goes back, rows whose time repeats the previous row's), within the block."""
        t = self.time_s
        if t.size < 2:
            return 0, 0
        step = t[1:] - t[:-1]
        return int(np.count_nonzero(step < 0)), int(np.count_nonzero(step == 0))

    @_cached
    def only_channel(self) -> int | None:
        """The index of the one channel every row is on, or None (rows of several channels)."""
        if not self.n:
            return None
        first = int(self.channel[0])
        return first if len(self.channels) == 1 or bool((self.channel == first).all()) else None

    @_cached
    def special(self) -> np.ndarray:
        """The rows of remote and error frames (no payload to decode), as an index array."""
        if not self.flags.any():
            return _NO_ROWS
        return np.flatnonzero(self.flags & (FLAG_REMOTE | FLAG_ERROR))

    def frame(self, i: int) -> Frame:
        """Row ``i`` as a :class:`Frame` (``dlc`` -1 when it is the payload's length, as :class:`Frame` says)."""
        length = int(self.length[i])
        flags = int(self.flags[i])
        dlc = int(self.dlc[i])
        remote = bool(flags & FLAG_REMOTE)
        source = self._made_payload()
        return _new(Frame, (
            float(self.time_s[i]), self.channels[int(self.channel[i])], int(self.can_id[i]),
            source[i, :length].tobytes() if isinstance(source, np.ndarray) else source.one(i),
            bool(self.extended[i]), bool(flags & FLAG_FD), bool(flags & FLAG_ERROR), remote, bool(flags & FLAG_BRS),
            bool(flags & FLAG_ESI),
            -1 if dlc == length or (remote and dlc == 0) else dlc,
        ))

    def _made_payload(self) -> np.ndarray | PayloadSource:
        """:attr:`payload` once made (or given), else :attr:`payload_source`."""
        made: np.ndarray | None = self.__dict__.get("payload")
        return self.payload_source if made is None else made

    def frames(self) -> Iterator[Frame]:
        """Every row as a :class:`Frame`, in order (each column converted once)."""
        n = self.n
        flags = self.flags
        length = self.length.astype(np.int64)
        dlc = self.dlc.astype(np.int64)
        remote = (flags & FLAG_REMOTE) != 0
        width = self.payload.shape[1]
        blob = self.payload.tobytes()
        starts = np.arange(n, dtype=np.int64) * width
        payloads = list(map(blob.__getitem__, map(slice, starts.tolist(), (starts + length).tolist())))
        channels = self.channels
        chans = [channels[0]] * n if len(channels) == 1 else list(map(channels.__getitem__, self.channel.tolist()))
        bits = [((flags & bit) != 0).tolist() for bit in (FLAG_FD, FLAG_ERROR, FLAG_REMOTE, FLAG_BRS, FLAG_ESI)]
        dlcs = np.where((dlc == length) | (remote & (dlc == 0)), -1, dlc).tolist()
        return map(_new, repeat(Frame), zip(self.time_s.tolist(), chans, self.can_id.tolist(), payloads,
                                            self.extended.tolist(), *bits, dlcs, strict=True))

    def select(self, rows: Any) -> Block:
        """The rows ``rows`` (an index array, a boolean mask or a slice) as a block of their own."""
        return Block(self.time_s[rows], self.can_id[rows], self.extended[rows], self.flags[rows], self.dlc[rows],
                     self.length[rows], self.payload[rows], self.channel[rows], self.channels)


_U8_ONE: tuple[np.ndarray, ...] = tuple(np.full(1, v, np.uint8) for v in range(256))
"""Each uint8 value as a column of one row (shared: a block never writes its arrays)."""
_ROW_0 = np.zeros(1, dtype=np.intp)
_IDS: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
"""Each id key seen in a block of one: its ``can_id``, ``extended`` and :attr:`Block.keys` columns (shared)."""
_MAX_IDS = 4096
for _shared in (*_U8_ONE, _ROW_0, _LANE_0, _NO_ROWS):
    _shared.flags.writeable = False


_TIME_ONE = np.zeros(1, dtype=np.float64)
"""A time column of one row, copied for each block of one (its own array: cheaper than ``np.array``)."""
_NO_PAYLOAD = np.zeros((1, 0), dtype=np.uint8)
_NO_PAYLOAD.flags.writeable = False
_ROW_TYPES: dict[int, np.dtype] = {}
"""Each payload width seen in a block of one: a dtype of that many bytes, which ``frombuffer`` reads as one row."""


def one_block(frame: Frame) -> Block:
    """One frame as a block (a live frame on a quiet bus): fields read at once, columns checked by construction, the
    id's and small integers' columns shared, what the engine reads (:attr:`Block.keys`, ...) known at once."""
    t, channel, cid, data, ext, fd, err, remote, brs, esi, dlc = frame
    width = len(data)
    if dlc < 0:
        dlc = width
    if not (0 <= cid <= 0xFFFFFFFF and width <= 255 and dlc <= 255):
        return _of_frames((frame,))  # no CAN frame: the rows' builder says why
    flags = ((FLAG_FD if fd else 0) | (FLAG_BRS if brs else 0) | (FLAG_ESI if esi else 0)
             | (FLAG_REMOTE if remote else 0) | (FLAG_ERROR if err else 0)) if fd or err or remote or brs or esi else 0
    key = cid + EXT_KEY if ext else cid
    ids = _IDS.get(key)
    if ids is None:
        if len(_IDS) >= _MAX_IDS:
            _IDS.clear()
        ids = _IDS[key] = (np.array((cid,), np.uint32), np.array((ext,), np.bool_), np.array((key,), np.int64))
        for column in ids:
            column.flags.writeable = False
    if width:
        row = _ROW_TYPES.get(width)
        if row is None:
            row = _ROW_TYPES[width] = np.dtype((np.uint8, (width,)))
        payload = np.frombuffer(data, row)  # (1, width)
    else:
        payload = _NO_PAYLOAD
    time_s = _TIME_ONE.copy()
    time_s[0] = t
    block = _new_object(Block)
    block.__dict__.update({
        "time_s": time_s, "can_id": ids[0], "extended": ids[1], "flags": _U8_ONE[flags], "dlc": _U8_ONE[dlc],
        "length": _U8_ONE[width], "payload_source": payload, "payload": payload, "channel": _LANE_0,
        "channels": (channel,), "n": 1, "keys": ids[2], "times": [float(t)], "ordered": True, "only_channel": 0,
        "special": _ROW_0 if flags & (FLAG_REMOTE | FLAG_ERROR) else _NO_ROWS,
    })
    return block


_new_object = object.__new__


def _of_frames(frames: Sequence[Frame]) -> Block:
    """Frames as a block: their fields transposed at once, the flags and data length codes made per column."""
    if not frames:
        return _rows([], [], [], [], [], [], [])
    t, chans, ids, datas, ext, fd, err, remote, brs, esi, dlcs = zip(*frames, strict=True)
    marks = (fd, brs, esi, remote, err)
    flags = ([FLAG_FD * a | FLAG_BRS * b | FLAG_ESI * c | FLAG_REMOTE * d | FLAG_ERROR * e
              for a, b, c, d, e in zip(*marks, strict=True)] if any(map(any, marks)) else [0] * len(frames))
    lengths = list(map(len, datas))
    codes = lengths if max(dlcs) < 0 else [n if d < 0 else d for n, d in zip(lengths, dlcs, strict=True)]
    return _rows(t, ids, ext, flags, codes, datas, chans, lengths)


def _rows(times: Sequence[float], ids: Sequence[int], ext: Sequence[bool], flags: Sequence[int],
          dlcs: Sequence[int], datas: Sequence[bytes], chans: Sequence[str],
          lengths: list[int] | None = None) -> Block:
    """Rows gathered one by one as a block; a row that is no CAN frame is a LogFormatError."""
    if lengths is None:
        lengths = list(map(len, datas))
    width = max(lengths, default=0)
    n = len(lengths)
    if n and min(lengths) == width:
        payload = np.frombuffer(b"".join(datas), dtype=np.uint8).reshape(n, width)
    else:
        payload = np.zeros((n, width), dtype=np.uint8)
        for i, data in enumerate(datas):
            payload[i, :len(data)] = np.frombuffer(data, dtype=np.uint8)
    names: dict[str, int] = {}
    lanes = [names.setdefault(c, len(names)) for c in chans]
    bad = [i for i, cid in enumerate(ids) if not 0 <= cid <= 0xFFFFFFFF or not 0 <= dlcs[i] <= 255]
    if bad or width > 255:
        i = bad[0] if bad else lengths.index(width)
        raise LogFormatError(f"frame {i}: id {ids[i]:#x}, dlc {dlcs[i]}, {lengths[i]} data bytes: "
                             "not a CAN frame")
    block = _new_object(Block)  # its columns of their types by construction: not checked again
    block.__dict__.update(
        time_s=np.array(times, dtype=np.float64), can_id=np.array(ids, dtype=np.uint32),
        extended=np.array(ext, dtype=np.bool_), flags=np.array(flags, dtype=np.uint8),
        dlc=np.array(dlcs, dtype=np.uint8), length=np.array(lengths, dtype=np.uint8), payload_source=payload,
        payload=payload, channel=np.array(lanes, dtype=np.uint16), channels=tuple(names) or ("",), n=n)
    return block
