"""Plain candump -L blocks parsed by numpy over the block's bytes: no Python object per field.

:func:`byte_columns` checks a block of ``(secs.usecs) channel ID#HEX`` lines (CAN FD
``ID##FHEX``, remote ``ID#R`` / ``ID#R4``, an optional T/R marker) with a handful of
passes over the bytes, and keeps what the replay engine asks for as arrays:

* the timestamps as floats, each equal to Python's ``float()`` of its text: the
  digits make an exact integer (below 2**53) divided by an exact power of ten, one
  correctly rounded division, hence the double nearest the written decimal;
* the ids as integer keys (:func:`canguard.io.logtypes.id_key`: the id, plus
  :data:`~canguard.io.logtypes.EXT_KEY` for an extended one), read 8 bytes at a time,
  which the engine looks up in its plans as it looks up id texts;
* each row's channel when the block mixes channels (names of one length: ``can0``/``can1``);
* where each row's data starts and ends: a message's payloads are read as one
  ``rows x length`` byte matrix (:meth:`ByteColumns.payload`), never as hex strings.

The block is accepted only when every line passes the checks the line parser makes
(``tests/test_candump_np.py`` tries damaged blocks); anything else gives None and the
caller falls back to the text parser, which reports bad lines with their file:line.
Frames are built only for rows the engine feeds one by one. candump -ta blocks come here
rewritten as -L (:mod:`canguard.io.candump_long`).
"""

from __future__ import annotations

import threading
from bisect import bisect_left
from collections.abc import Iterator
from typing import Any

import numpy as np

from canguard.io.frame import Frame
from canguard.io.logtypes import _F, CANFD_BRS, CANFD_ESI, CANFD_LENGTHS, EXT_KEY, _new, joined_hex

_HEXVAL = np.full(256, 255, dtype=np.uint8)
for _i, _c in enumerate(b"0123456789abcdef"):
    _HEXVAL[_c] = _i
for _i, _c in enumerate(b"ABCDEF", 10):
    _HEXVAL[_c] = _i
_FD_BYTES = np.zeros(66, dtype=bool)  # [65]: any length above 64 bytes
_FD_BYTES[sorted(CANFD_LENGTHS)] = True
_U = np.uint64
_LE64 = np.dtype("<u8")
_U16 = np.uint16
_LE16 = np.dtype("<u2")
_EXACT = 1 << 53
_MAX_STANDARD = 0x7FF
_MAX_EXTENDED = 0x1FFFFFFF
_MARKERS = frozenset(b"TRtr")
_CLASSIC = 255
"""A classic row's CAN FD flags (:attr:`ByteColumns._flags`): no hex digit's value."""
_FEW = 48
"""Below this many rows a message's payloads are cut from the text, not gathered by numpy."""


class ByteColumns:
    """A checked block of plain candump -L lines, as arrays over its bytes.

    The same attributes the engine reads on :class:`canguard.io.candump.Columns`: ``n``,
    ``ts`` (floats), ``chans``, ``ids`` (integer keys, :func:`id_key`), ``ordered``,
    ``channel``, ``fd`` and ``remote``; :meth:`frame`, :meth:`frames` and :meth:`payload`. A block of
    several channels (names of one length) has ``channel`` None, their names in ``channels`` and
    each row's index into them in ``lanes``.
    """

    __slots__ = ("_b", "_end", "_fd", "_flags", "_ids", "_raw", "_row_chans", "_start", "_ts", "channel",
                 "channels", "keys", "lanes", "n", "order", "ordered", "remote", "stamps")

    def __init__(self, n: int, stamps: np.ndarray, keys: np.ndarray, ordered: bool, channel: str | None,
                 flags: np.ndarray | None, remote: dict[int, int] | None, raw: bytes, b: np.ndarray,
                 start: np.ndarray, end: np.ndarray) -> None:
        self.n = n
        self.stamps = stamps
        """Each row's timestamp (float64, each equal to ``float()`` of its text); :attr:`ts` as a list."""
        self._ts: list[float] | None = None
        self.keys = keys
        """Each row's id key (:func:`~canguard.io.logtypes.id_key`), as an array: the engine looks rows up by it."""
        self._ids: list[int] | None = None
        self.ordered = ordered
        self.channel = channel
        self.channels: list[str] = [channel] if channel is not None else []
        self.lanes: np.ndarray | None = None
        """Each row's index into :attr:`channels` (None: one channel)."""
        self._row_chans: list[str] | None = None
        self._flags = flags
        """Each row's CAN FD flags digit (BRS, ESI), :data:`_CLASSIC` on a classic row; None: no CAN FD row."""
        self._fd: dict[int, int] | None = None
        self.remote = remote
        self._raw = raw
        self._b = b
        self._start = start
        self._end = end
        self.order = (0, 0)
        """Rows whose timestamp goes back, and rows whose timestamp repeats the previous row's (in the block)."""

    @property
    def ts(self) -> list[float]:
        """:attr:`stamps` as a list of floats, made when first asked for: a block taken whole never is (making
        and freeing a float object per row was ~15 % of a replay of a log where 10 % of the frames count)."""
        if self._ts is None:
            self._ts = self.stamps.tolist()
        return self._ts

    @property
    def fd(self) -> dict[int, int] | None:
        """The CAN FD rows' flags (BRS, ESI) by row, made when first asked for (a frame reads its own row's; a
        dict of every FD row, made per block, was ~4 % of a replay of an all-FD log); None: no CAN FD row."""
        if self._fd is None and self._flags is not None:
            rows = np.flatnonzero(self._flags != _CLASSIC)
            self._fd = dict(zip(rows.tolist(), self._flags[rows].tolist(), strict=True))
        return self._fd

    @property
    def ids(self) -> list[int]:
        """:attr:`keys` as a list, made when first asked for (most blocks never are: a list of every row's key
        cost ~3 % of a replay)."""
        if self._ids is None:
            self._ids = self.keys.tolist()
        return self._ids

    @property
    def chans(self) -> list[str]:
        """The channel of every row."""
        if self.channel is not None:
            return [self.channel] * self.n
        if self._row_chans is None:
            assert self.lanes is not None
            self._row_chans = list(map(self.channels.__getitem__, self.lanes.tolist()))
        return self._row_chans

    def frame(self, i: int) -> Frame:
        """The frame of row ``i`` (a few rows of a block are: the block's lists are not made for them)."""
        key = self._ids[i] if self._ids is not None else int(self.keys[i])
        t = self._ts[i] if self._ts is not None else float(self.stamps[i])
        ext = key >= EXT_KEY
        cid = key - EXT_KEY if ext else key
        channel = self.channel if self.channel is not None else self.chans[i]
        if self.remote is not None and i in self.remote:
            return _new(Frame, (t, channel, cid, b"", ext, _F, _F, True, _F, _F, self.remote[i]))
        data = bytes.fromhex(self._raw[int(self._start[i]):int(self._end[i])].decode("ascii"))
        flags = int(self._flags[i]) if self._flags is not None else _CLASSIC
        if flags != _CLASSIC:
            return _new(Frame, (t, channel, cid, data, ext, True, _F, _F,
                                bool(flags & CANFD_BRS), bool(flags & CANFD_ESI), -1))
        return _new(Frame, (t, channel, cid, data, ext, _F, _F, _F, _F, _F, -1))

    def frames(self) -> Iterator[Frame]:
        """The frames of every row, in order (the block's id and time lists made first: every row is read)."""
        _made = self.ids, self.ts
        return map(self.frame, range(self.n))

    def hex_lengths(self) -> np.ndarray:
        """Each row's payload length in hex digits (twice its bytes)."""
        return self._end - self._start

    def payload(self, rows: Any, size: int) -> tuple[list[int] | None, bytes]:
        """The payloads of ``rows`` that hold ``size`` hex digits, joined: (their positions in ``rows``, or None
        when all of them do; the bytes)."""
        if len(rows) < _FEW:  # a few rows: slicing the bytes costs less than numpy's calls
            idx = np.asarray(rows, dtype=np.intp)
            raw = self._raw
            # hex digits all (checked by byte_columns): unhexlify reads them as bytes.fromhex reads their text
            return joined_hex(list(map(raw.__getitem__, map(slice, self._start[idx].tolist(),
                                                              self._end[idx].tolist()))), size)
        good, start = self._fitting(rows, size)
        if not size or not start.size:
            return good, b""
        return good, _hex_bytes(_rows(self._b, start, size)).tobytes()

    def payloads(self, groups: list[Any], size: int) -> list[tuple[list[int] | None, bytes]]:
        """:meth:`payload` of each of ``groups`` (row lists or index arrays), cut in one pass over all their rows."""
        good, data = self.payload(np.concatenate(groups), size)
        width = size // 2
        out: list[tuple[list[int] | None, bytes]] = []
        pos = 0
        if good is None:
            for group in groups:
                out.append((None, data[pos * width:(pos + len(group)) * width]))
                pos += len(group)
            return out
        at = 0  # good positions before the group
        for group in groups:
            end = pos + len(group)
            upto = bisect_left(good, end, at)
            mine = [k - pos for k in good[at:upto]]
            out.append((None if len(mine) == len(group) else mine, data[at * width:upto * width]))
            pos, at = end, upto
        return out

    def _fitting(self, rows: Any, size: int) -> tuple[list[int] | None, np.ndarray]:
        """Which of ``rows`` hold ``size`` hex digits (their positions in ``rows``; None: all), and where
        their data starts."""
        idx = np.asarray(rows, dtype=np.intp)
        start = self._start[idx]
        fit = self._end[idx] - start == size
        if fit.all():
            return None, start
        keep = np.flatnonzero(fit)
        return keep.tolist(), start[keep]


def byte_columns(text: str | bytes, n: int) -> ByteColumns | None:
    """The block ``text`` (its characters or, as the reader gives it, its bytes) of ``n`` lines (each ending in
    a newline) as :class:`ByteColumns`, or None.

    ``n`` < 0: count them. None when any line is not of the plain shape, when the block has channels
    of several name lengths, or when a timestamp does not convert exactly this way (its digits
    make 2**53 or more): the caller then uses the text parser.
    """
    if not n or not text.isascii():
        return None
    raw = text if isinstance(text, bytes) else text.encode("ascii")
    if b"\t" in raw:
        return None
    b = np.frombuffer(raw, dtype=np.uint8)
    size = b.size
    pad, mask, spare = _scratch(size)
    pad[:size] = b
    pad[size:size + 8] = 0
    words = np.ndarray((size + 1,), _LE64, pad, 0, (1,))  # words[k]: the 8 bytes from k, little-endian
    np.equal(b, 10, out=mask)
    nl = np.flatnonzero(mask)
    if n < 0:
        n = nl.size
    if not n or nl.size != n or nl[-1] != b.size - 1:
        return None
    layout = _layout(raw, b, nl, n)
    if layout is None:
        return None
    start, width, clen, sp1, sp2, end, spaces = layout
    markers = spaces == 3 * n
    ts = _stamps(b, start, width)
    if ts is None:
        return None
    chans = _channels(b, words, sp1, clen)
    if chans is None:
        return None
    names, lanes = chans
    if any(c in name for name in names for c in "()# \t"):
        return None  # a channel's letters are not counted as fields are: the text parser decides
    found = _id_fields(b, words, sp2, end, n)
    if found is None:
        return None
    h1, after, hashes, keys = found
    payloads = _payloads(raw, b, h1, end, after, hashes - n)
    if payloads is None:
        return None
    data_start, flags, remote = payloads
    # Every byte that is not a hex digit has been found at its place above: "(", ")", the dot,
    # the spaces, the "#"s, the newline, the marker, the channel's letters, a remote "R". One
    # more anywhere (in the data, say, or a second "(" or "#") and the count differs.
    others = [_others(name) for name in names]
    letters = n * others[0] if lanes is None else int(np.dot(np.bincount(lanes, minlength=len(names)), others))
    known = n * (4 + markers) + letters + spaces + hashes + len(remote or ())
    if size - _hex_digits(b, pad[:size], mask, spare) != known:
        return None
    step = ts[1:] - ts[:-1]
    backs = int(np.count_nonzero(step < 0))
    cols = ByteColumns(n, ts, keys, not backs, names[0] if lanes is None else None, flags, remote,
                       raw, b, data_start, end)
    if lanes is not None:
        cols.channels, cols.lanes = names, lanes
    cols.order = (backs, int(np.count_nonzero(step == 0)))
    return cols


def _layout(raw: bytes, b: np.ndarray, nl: np.ndarray, n: int) -> tuple[Any, ...] | None:
    """Where each line's fields are: (line starts, timestamp width, channel length, the space before the
    channel, the space before the id, where each line's data ends, the block's spaces); None: not plain.

    Each field's place follows from the first line's widths (timestamp, channel) and each id's
    length (3 or 8); each place is checked. That "(", ")", " " and "#" are nowhere else is the caller's count
    of the bytes that are not hex digits (no count of each: four passes over the block's bytes fewer).
    """
    start = np.empty(n, dtype=np.intp)
    start[0] = 0
    start[1:] = nl[:-1] + 1
    first = raw[:int(nl[0])]
    width = first.find(b")") - 1
    clen = first.find(b" ", width + 3) - width - 3
    if width < 3 or clen < 1 or nl[0] < 2:
        return None
    close = start + (width + 1)
    sp1 = close + 1
    sp2 = sp1 + (clen + 1)
    if not ((b[start] == 40) & (sp2 < nl)).all() or not ((b[close] == 41) & (b[sp1] == 32) & (b[sp2] == 32)).all():
        return None
    markers = bool(b[nl[0] - 2] == 32)  # as the first line ends (" T"), or its data does: every line is checked
    spaces = (3 if markers else 2) * n
    end = nl - 2 if markers else nl  # the space before a T/R marker, or the newline
    if markers and (not ((b[end] == 32) & (end > sp2)).all() or not set(b[nl - 1].tobytes()) <= _MARKERS):
        return None
    return start, width, clen, sp1, sp2, end, spaces


def _id_fields(b: np.ndarray, words: np.ndarray, sp2: np.ndarray, end: np.ndarray, n: int
               ) -> tuple[np.ndarray, np.ndarray, int, np.ndarray] | None:
    """(where each line's "#" after the id is, the byte after it, the block's "#"s at their places, the id keys);
    None: not plain."""
    short = b[np.minimum(sp2 + 4, b.size - 1)] == 35  # a 3-digit id, else 8
    h1 = np.where(short, sp2 + 4, sp2 + 9)
    if not ((h1 < end) & (b[np.minimum(h1, b.size - 1)] == 35)).all():
        return None
    after = b[h1 + 1]  # "#" for CAN FD, "R" / "r" for a remote frame: h1 + 1 <= end (a newline at worst)
    hashes = n + int(np.count_nonzero(after == 35))  # one "#" per line, two on a CAN FD line; none elsewhere:
    # the caller's count of the bytes that are not hex digits
    keys = _ids(words, sp2, h1)
    if keys is None:
        return None
    return h1, after, hashes, keys


def _payloads(raw: bytes, b: np.ndarray, h1: np.ndarray, end: np.ndarray, after: np.ndarray, nfd: int
              ) -> tuple[np.ndarray, np.ndarray | None, dict[int, int] | None] | None:
    """(where each row's data starts, each row's CAN FD flags (None: no CAN FD row), the remote rows' DLCs);
    None: not plain."""
    data_start = h1 + 1
    is_fd = after == 35
    flags: np.ndarray | None = None
    remote: dict[int, int] | None = None
    if nfd:
        data_start = np.where(is_fd, h1 + 3, data_start)
        flags = _fd_flags(b, h1, end, is_fd)
        if flags is None:
            return None
    is_remote = (after == 82) | (after == 114)
    if is_remote.any():
        remote = _remote_dlcs(raw, h1, end, is_remote)
        if remote is None:
            return None
        data_start = np.where(is_remote, end, data_start)
    if not _lengths_ok(end - data_start, is_fd, nfd):
        return None
    return data_start, flags, remote


def _fd_flags(b: np.ndarray, h1: np.ndarray, end: np.ndarray, is_fd: np.ndarray) -> np.ndarray | None:
    """Each row's flags digit (BRS, ESI) when it is CAN FD (``ID##F...``), else :data:`_CLASSIC`; None: the
    digit of a CAN FD row is missing or not a hex digit.

    Over every row (a classic row's byte there is read and dropped): no index array of the FD rows."""
    at = h1 + 2
    if ((at >= end) & is_fd).any():
        return None
    flags = _HEXVAL.take(b.take(np.minimum(at, b.size - 1)))  # _HEXVAL gives _CLASSIC (255) to a non-hex byte
    if ((flags == _CLASSIC) & is_fd).any():
        return None
    flags[~is_fd] = _CLASSIC
    return flags


def _remote_dlcs(raw: bytes, h1: np.ndarray, end: np.ndarray, is_remote: np.ndarray) -> dict[int, int] | None:
    """The DLC of each remote row (``ID#R``, ``ID#R4``; -1: none written); None: a DLC that is no digit 0-8."""
    remote = {}
    for i in np.flatnonzero(is_remote).tolist():
        dlc = raw[int(h1[i]) + 2:int(end[i])].decode("ascii")
        if len(dlc) > 1 or (dlc and dlc not in "012345678"):
            return None
        remote[i] = (int(dlc) or -1) if dlc else -1
    return remote


def _lengths_ok(lengths: np.ndarray, is_fd: np.ndarray, nfd: int) -> bool:
    """Each row's data (hex digits) is whole bytes of a CAN length: up to 8 classic, a CAN FD length for FD
    (``nfd``: how many rows are CAN FD). Over every row: no selection of each kind's rows."""
    if (lengths & 1).any():
        return False
    if not nfd:
        return not (lengths > 16).any()
    fd_ok = _FD_BYTES.take(np.minimum(lengths >> 1, 65))
    return not (((lengths > 16) & ~is_fd) | (~fd_ok & is_fd)).any()


_LOCAL = threading.local()


def _buffer(name: str, count: int, dtype: type) -> np.ndarray:
    """This thread's scratch array ``name``, ``count`` items, kept from block to block.

    A block's passes over its bytes then make no new block-sized array, which a process that
    gives freed memory back to the kernel at once (Dask starts its workers with
    ``MALLOC_TRIM_THRESHOLD_`` set) would fault in again page by page, every block.
    """
    have: np.ndarray | None = getattr(_LOCAL, name, None)
    if have is None or have.size < count:
        have = np.empty(count + count // 4 + 64, dtype=dtype)
        setattr(_LOCAL, name, have)
    return have[:count]


def _scratch(size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scratch for a block of ``size`` bytes (:func:`_buffer`): ``size + 8`` bytes, and two masks of ``size``."""
    return _buffer("pad", size + 8, np.uint8), _buffer("mask", size, bool), _buffer("spare", size, bool)


def _hex_digits(b: np.ndarray, work: np.ndarray, mask: np.ndarray, spare: np.ndarray) -> int:
    """How many bytes of ``b`` are hex digits (0-9, a-f, A-F), counted in ``work``/``mask``/``spare`` (overwritten)."""
    np.subtract(b, np.uint8(48), out=work)
    np.less(work, np.uint8(10), out=mask)  # a digit; anything else wraps above 9
    np.bitwise_or(b, np.uint8(32), out=work)
    np.subtract(work, np.uint8(97), out=work)
    np.less(work, np.uint8(6), out=spare)  # a-f or A-F
    np.logical_or(mask, spare, out=mask)
    return int(np.count_nonzero(mask))


def _stamps(b: np.ndarray, start: np.ndarray, width: int) -> np.ndarray | None:
    """The timestamps (``width`` characters after each line's "("), exactly as ``float()`` reads them, or None."""
    n = start.size
    cells = _rows(b, start + 1, width)
    dots = np.flatnonzero(cells[0] == 46)
    if dots.size != 1 or not 0 < int(dots[0]) < width - 1 or width - 1 > 22:  # 10**22: the last exact power
        return None
    dot = int(dots[0])
    if not (cells[:, dot] == 46).all():
        return None
    np.subtract(cells, np.uint8(48), out=cells)  # a digit is 0..9, anything else wraps above 9
    cells[:, dot] = 0
    if int(cells.max()) > 9:
        return None
    # BLAS in float64: every partial sum is an integer below 2**53, so exact in any order
    weights = np.array([0.0 if k == dot else 10.0 ** (width - 1 - k - (k < dot)) for k in range(width)])
    digits = _buffer("digits", n * width, np.float64).reshape(n, width)
    np.copyto(digits, cells)
    whole = digits @ weights
    if float(whole.max()) >= _EXACT:
        return None
    return whole / 10.0 ** (width - 1 - dot)  # exact integer / exact power of ten: one rounding, as float()


def _channels(b: np.ndarray, words: np.ndarray, sp1: np.ndarray, size: int
              ) -> tuple[list[str], np.ndarray | None] | None:
    """The block's channel names and each row's index into them (None: one channel); None: names of more
    than 8 characters that differ (their lengths are one: the caller placed every field by it)."""
    if size > 8:
        cells = _rows(b, sp1 + 1, size)
        if (cells == cells[0]).all():
            return [bytes(cells[0]).decode("ascii")], None
        return None
    codes = words[sp1 + 1] & np.uint64((1 << 8 * size) - 1)  # the name's bytes, little-endian
    first = int(sp1[0]) + 1
    same = codes == codes[0]
    if same.all():
        return [bytes(b[first:first + size]).decode("ascii")], None
    lanes = _two_lanes(codes, same)
    if lanes is None:
        _codes, firsts, lanes = np.unique(codes, return_index=True, return_inverse=True)
        lanes = lanes.reshape(-1).astype(np.intp)
    else:
        firsts = np.array([int(np.argmax(lanes == 0)), int(np.argmax(lanes))])
    names = [bytes(b[int(sp1[k]) + 1:int(sp1[k]) + 1 + size]).decode("ascii") for k in firsts.tolist()]
    return names, lanes


def _two_lanes(codes: np.ndarray, same: np.ndarray) -> np.ndarray | None:
    """Each row's lane when the block has exactly two channels (``same``: the rows of the first row's), as
    ``np.unique`` numbers them (the lower code first), without its sort; None: more than two."""
    other = codes[int(np.argmin(same))]
    second = codes == other
    if not (same | second).all():
        return None
    return (second if other > codes[0] else same).astype(np.intp)


def _ids(words: np.ndarray, sp2: np.ndarray, h1: np.ndarray) -> np.ndarray | None:
    """Each row's id key: 3 hex digits up to 7FF (standard) or 8 up to 1FFFFFFF (extended); None otherwise.

    The digits are read 8 bytes at a time (SWAR on little-endian words); that they are hex digits
    at all is the caller's non-hex count.
    """
    size = h1 - sp2 - 1
    ext = size == 8
    if not (ext | (size == 3)).all():
        return None
    if ext.all():
        return _extended(words[h1 - 8])
    if not ext.any():
        return _standard(words[h1 - 3])
    # One read of the 8 bytes before each "#", over every row: a long id's digits, or a short id's
    # three after five bytes that are read and dropped. Each byte lands in its own nibble of the
    # value, so a short id is its low 12 bits whatever the bytes before it (numpy's boolean
    # selections of each kind's rows cost more than the arithmetic they save).
    value = _extended_values(words[h1 - 8])
    low = value & _U(0xFFF)
    if ((value > _U(_MAX_EXTENDED)) & ext).any() or ((low > _U(_MAX_STANDARD)) & ~ext).any():
        return None
    return np.where(ext, value.astype(np.int64) + EXT_KEY, low.astype(np.int64))


def _extended(x: np.ndarray) -> np.ndarray | None:
    """The keys of 8-digit ids (``x``: their digits' bytes), or None when one is above 1FFFFFFF (error frames)."""
    value = _extended_values(x)
    if (value > _U(_MAX_EXTENDED)).any():
        return None
    return value.astype(np.int64) + EXT_KEY


def _standard(x: np.ndarray) -> np.ndarray | None:
    """The keys of 3-digit ids (``x``: their digits' bytes, then others), or None when one is above 7FF."""
    value = _standard_values(x)
    if (value > _U(_MAX_STANDARD)).any():
        return None
    return value.astype(np.int64)


def _extended_values(x: np.ndarray) -> np.ndarray:
    """The values of 8 hex digits (``x``: their bytes, little-endian words), unchecked."""
    nib = _nibbles(x)  # byte k: the k-th digit
    x = ((nib & _U(0x000F000F000F000F)) << _U(4)) | ((nib >> _U(8)) & _U(0x000F000F000F000F))
    x = ((x & _U(0x000000FF000000FF)) << _U(8)) | ((x >> _U(16)) & _U(0x000000FF000000FF))
    return ((x & _U(0xFFFF)) << _U(16)) | ((x >> _U(32)) & _U(0xFFFF))


def _standard_values(x: np.ndarray) -> np.ndarray:
    """The values of 3 hex digits (``x``: their bytes, then others, little-endian words), unchecked."""
    nib = _nibbles(x)
    return ((nib & _U(0xF)) << _U(8)) | (((nib >> _U(8)) & _U(0xF)) << _U(4)) | ((nib >> _U(16)) & _U(0xF))


def _nibbles(x: np.ndarray) -> np.ndarray:
    """Each byte of ``x``, an ASCII hex digit, as its value (0-9, a-f and A-F alike)."""
    return (x & _U(0x0F0F0F0F0F0F0F0F)) + ((x >> _U(6)) & _U(0x0101010101010101)) * _U(9)


def _hex_bytes(cells: np.ndarray) -> np.ndarray:
    """The bytes that the rows of ``cells`` spell (hex digits, checked by :func:`byte_columns`, an even number
    a row, C-contiguous): a ``rows x half as many`` matrix.

    Two digits at a time, as little-endian 16-bit words (the first digit in the low byte), in
    arithmetic: a table lookup (``take``) first widens every digit to an index."""
    pairs = cells.view(_LE16)
    nib = (pairs & _U16(0x0F0F)) + ((pairs >> _U16(6)) & _U16(0x0101)) * _U16(9)  # each byte: its digit's value
    return ((nib << _U16(4)) | (nib >> _U16(8))).astype(np.uint8)  # the low byte: first digit * 16 + second


def _rows(b: np.ndarray, pos: np.ndarray, width: int) -> np.ndarray:
    """The ``width`` bytes at each of ``pos``, as a ``len(pos) x width`` matrix (one copy per row, not per byte)."""
    return np.ndarray((b.size - width + 1, width), np.uint8, b, 0, (1, 1))[pos]  # as_strided, without its overhead


def _others(channel: str) -> int:
    """How many characters of ``channel`` are not hex digits."""
    return sum(c not in "0123456789abcdefABCDEF" for c in channel)
