"""The candump text parser: a block of lines parsed by numpy into a :class:`~canguard.io.block.Block`.

:func:`parse_block` reads every shape candump writes (``-L`` / ``-l``, CAN FD, remote, raw DLC, error frames, T/R
markers, comments; ``-ta`` lines, first rewritten as ``-L``; ``-e``'s indented lines) with one pass per field over
the block's bytes: fields found where they are (any widths mix), timestamps equal to ``float()`` of their text (an
exact integer over an exact power of ten), ids read 8 bytes at a time, hex digits checked by one count over the
block, payloads left as text until a row is read (:class:`HexPayloads`). A line failing a check is a bad line,
by its index in the block (:attr:`Parsed.bad`).
"""

from __future__ import annotations

import binascii
import re
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from canguard.io.block import FLAG_BRS, FLAG_ERROR, FLAG_ESI, FLAG_FD, FLAG_REMOTE, Block
from canguard.io.logtypes import CANFD_LENGTHS

_HEX = np.zeros(256, dtype=bool)
_HEX[list(b"0123456789abcdefABCDEF")] = True
_FD_BYTES = np.zeros(66, dtype=bool)  # [65]: any length above 64 bytes
_FD_BYTES[sorted(CANFD_LENGTHS)] = True
_MARKERS = np.zeros(256, dtype=bool)
_MARKERS[list(b"TRtr")] = True
_U = np.uint64
_LE64 = np.dtype("<u8")
_LE16 = np.dtype("<u2")
_NIBBLES = np.array([int(chr(c), 16) if chr(c) in "0123456789abcdefABCDEF" else 0 for c in range(256)], dtype=np.uint8)
_PAIRS = ((_NIBBLES[None, :] << 4) | _NIBBLES[:, None]).ravel()
"""By the little-endian word of two hex digits' bytes, the byte they spell (:data:`_NIBBLES`: each byte's digit)."""
_EXACT = 1 << 53
_NO_ROWS = np.zeros(0, dtype=np.intp)
_ERR_FLAG = 0x20000000
_MAX_STANDARD = 0x7FF
_MAX_EXTENDED = 0x1FFFFFFF
_PAD = 160
"""Bytes after a block's last one that a gather may read (a CAN FD payload's 128 hex digits, an 8-byte word)."""
_INDENTED = 1
"""The first byte of an indented line once the block is rewritten (``-e``'s lines under an error frame)."""


@dataclass(frozen=True)
class Parsed:
    """What :func:`parse_block` made of a block of lines."""

    block: Block | None
    """The frames of the good lines, in order (None: no frame)."""
    rows_line: np.ndarray
    """Each frame's line index in the block."""
    lines: int
    """Lines in the block, blank and comment lines included."""
    bad: list[int]
    """The bad lines' indices, in order."""
    error_last: bool
    """The block's last frame is an error frame (an indented line after it, in the next block, is ``-e``'s)."""


# --------------------------------------------------------------------------- the text rewritten: one shape

_LONG_PLAIN = (rb"(?m)^\((\d{10,}\.\d+)\) ([^ \n]+) ([0-9A-Fa-f]{3}|[0-9A-Fa-f]{8}) \[[0-8]\]((?: [0-9A-Fa-f]{2})*)"
               rb"(?: '[^\n]*)?$")
_LONG_ANY = (rb"\((\d{10,}\.\d+)\) ([^ ]+) (?:([RT]X) ([B-]) ([E-]) )?([0-9A-Fa-f]{3}|[0-9A-Fa-f]{8}) \[(\d\d?)\]"
             rb"((?: [0-9A-Fa-f]{2})*)( remote request|(?: '.*)?| ERRORFRAME.*)")
"""candump -ta lines: classic ones (a block rewritten at once), and any (a line at a time)."""


def _rewritten(raw: bytes) -> tuple[bytes, np.ndarray | None]:
    """The block with one space between fields, none at a line's ends, an indented line led by :data:`_INDENTED`,
    -ta lines rewritten as -L (lines keep their places); each line's ``[len]`` (-1: none) when there are -ta lines."""
    if b"\t" in raw or _loose_spaces(raw):
        if b"\t" in raw:
            raw = re.sub(rb"(?m)^\t", bytes([_INDENTED]), raw)
        raw = re.sub(rb"(?m)^ | $", b"", re.sub(rb"[ \t]+", b" ", raw))
    if b"[" not in raw:
        return raw, None
    n = raw.count(b"\n")
    found = re.findall(_LONG_PLAIN, raw)
    if len(found) == n:  # every line a classic -ta line: rewritten in one pass
        lengths = np.array(re.findall(rb"\[(\d\d?)\]", raw), dtype=np.int64)
        if lengths.size == n:
            return b"".join(b"(%s) %s %s#%s\n" % (t, c, i, d.replace(b" ", b"")) for t, c, i, d in found), lengths
    lines = raw.split(b"\n")
    lines.pop()
    announced = np.full(n, -1, dtype=np.int64)
    fullmatch = re.compile(_LONG_ANY).fullmatch
    for k, line in enumerate(lines):
        if b"[" in line and (m := fullmatch(line)) is not None:
            lines[k], announced[k] = _compact(m)
    return b"\n".join(lines) + b"\n", announced


def _loose_spaces(raw: bytes) -> bool:
    """Two spaces in a row, or a space at a line's start or end, anywhere in ``raw``."""
    b = np.frombuffer(raw, dtype=np.uint8)
    space = b == 32
    if not space.any():
        return False
    edge = b == 10
    return bool(space[0] or space[-1] or (space[1:] & (space[:-1] | edge[:-1])).any() or (space[:-1] & edge[1:]).any())


def _compact(m: re.Match[bytes]) -> tuple[bytes, int]:
    """A -ta line's fields as a -L line, and its announced length (-1: left as it was, refused)."""
    stamp, chan, _direction, brs, esi, cid, size, data, tail = m.groups()
    length = int(size)
    body = data.replace(b" ", b"")
    if tail == b" remote request":
        if body or len(size) == 2 or length > 8:
            return m.group(0), -1
        return b"(%s) %s %s#R%s" % (stamp, chan, cid, size if length else b""), 0
    if tail.startswith(b" ERRORFRAME") and (len(cid) != 8 or not int(cid, 16) & _ERR_FLAG):
        return m.group(0), -1
    if len(size) == 2:  # candump prints [%02d] for CAN FD
        flags = (1 if brs == b"B" else 0) | (2 if esi == b"E" else 0)
        return b"(%s) %s %s##%X%s" % (stamp, chan, cid, flags, body), length
    return b"(%s) %s %s#%s" % (stamp, chan, cid, body), length


# --------------------------------------------------------------------------- the columns


def parse_block(raw: bytes, error_before: bool = False) -> Parsed:
    """The frames of ``raw``, whole lines each ending in a newline (``\\r\\n`` taken as one); ``error_before``: the
    last frame before the block is an error frame (an indented first line is ``-e``'s)."""
    if b"\r" in raw:
        raw = raw.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    spaced = b"\t" in raw or b"[" in raw  # rewritten first (-ta lines are spaced out): else only if lines fail
    parsed = _parsed(_rewritten(raw) if spaced else (raw, None), error_before)
    if parsed.bad and not spaced and _loose_spaces(raw):
        return _parsed(_rewritten(raw), error_before)
    return parsed


def _parsed(rewritten: tuple[bytes, np.ndarray | None], error_before: bool) -> Parsed:
    """:func:`parse_block` of a block (rewritten, with its -ta lines' announced lengths)."""
    text, announced = rewritten
    b = np.frombuffer(text, dtype=np.uint8)
    size = b.size
    pad = _buffer("pad", size + _PAD, np.uint8)
    pad[:size] = b
    pad[size:] = 10
    nl = np.flatnonzero(b == 10)
    n = nl.size
    start = np.empty(n, dtype=np.intp)
    start[:1] = 0
    start[1:] = nl[:-1] + 1
    first = pad[start]
    data = (first != 10) & (first != 35)  # blank lines and # comments are no frames
    indented = first == _INDENTED
    data &= ~indented
    whole = bool(data.all())  # every line a frame's (else the columns are those of the frames' lines)
    lines = np.arange(n) if whole else np.flatnonzero(data)
    cols = _Columns(b, pad, start if whole else start[lines], nl if whole else nl[lines], whole, b"_" in text,
                    first if whole else first[lines])
    ok = cols.ok
    if announced is not None:  # a -ta line's [len] is its payload's length
        known = announced[lines]
        ok &= (known < 0) | (cols.length == known)
    every = bool(ok.all())
    good = np.arange(lines.size) if every else np.flatnonzero(ok)
    bad_lines = _NO_ROWS if every else lines[~ok]
    rows_line = lines if every else lines[good]
    errors = cols.err if every else cols.err[good]
    error_last = bool(errors[-1]) if errors.size else error_before
    if indented.any():
        bad_lines, error_last = _indented(np.flatnonzero(indented), rows_line, errors, bad_lines, error_before)
    block = cols.block(text, good) if good.size else None
    return Parsed(block, rows_line, n, sorted(bad_lines.tolist()), error_last)


def _indented(at: np.ndarray, rows_line: np.ndarray, errors: np.ndarray, bad: np.ndarray,
              error_before: bool) -> tuple[np.ndarray, bool]:
    """The bad lines with the indented lines (``at``) added that do not follow an error frame (``errors``: each
    frame is one); whether the block's last frame is an error frame. An indented line under an error frame is
    ``candump -e``'s explanation of it: skipped."""
    before = np.searchsorted(rows_line, at) - 1  # the frame before each
    follows = np.where(before >= 0, errors[np.maximum(before, 0)] if errors.size else False, error_before)
    last = bool(errors[-1]) if errors.size else error_before
    return np.concatenate([bad, at[~follows]]), last


class _Columns:
    """The fields of the lines from ``start`` to ``end`` (their newline), found and checked: :attr:`ok`.
    ``whole`` (every line a frame's): one count of the block's non-hex bytes against what the fields account for
    checks every id and payload at once. ``has_under``: the block has an "_". ``opening``: each line's first byte."""

    def __init__(self, b: np.ndarray, pad: np.ndarray, start: np.ndarray, end: np.ndarray, whole: bool,
                 has_under: bool, opening: np.ndarray) -> None:
        self.b = b
        self.pad = pad
        self.start = start
        self.has_under = has_under  # a raw DLC somewhere
        self.every: tuple[np.ndarray, list[bytes]] | None = None
        """Every line's channel index and the names' bytes, once found."""
        fixed = self._fixed(start, end)
        if fixed is not None:  # the ")", the spaces and the channel's end where :meth:`_fixed` saw them on every line
            close, sp2 = fixed
            ok = opening == 40
        else:
            close, sp2 = self._searched(start, end)
            ok = (opening == 40) & (close < end) & (pad[close + 1] == 32) & (sp2 < end) & (sp2 > close + 2)
        fe = self._field_end(sp2, end)
        tail = fe < end
        if tail.any():
            ok &= ~tail | ((fe == end - 2) & _MARKERS[pad[end - 1]])
        h1 = self._hash(sp2, fe)
        ok &= h1 < fe
        self.close, self.sp2 = close, sp2
        ok &= self._ids(h1, sp2)
        ok &= self._data(h1, fe)
        ok &= self._stamps(start, close, fixed is not None)
        hexes = [(sp2 + 1, h1), (self.ds, self.de)]  # where only hex digits may be
        if not (whole and ok.all() and self._counted(b, tail, close, sp2)):
            for lo, hi in hexes:
                ok &= self._between(lo, hi) == 0
        self.ok = ok

    def _fixed(self, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """")" and the space after the channel where the first line has them, when every line does."""
        if not start.size:
            return None
        pad = self.pad
        first = pad[int(start[0]):int(end[0])].tobytes()
        width = first.find(b")") - 1
        clen = first.find(b" ", width + 3) - width - 3
        if width < 1 or clen < 1:
            return None
        close = start + (width + 1)
        sp2 = close + clen + 2
        if not ((pad[close] == 41) & (pad[close + 1] == 32) & (pad[sp2] == 32) & (sp2 < end)).all():
            return None
        return close, sp2

    def _searched(self, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """")" and the space after the channel of each line, wherever they are."""
        close = _next(self.b, 41, start, end)
        return close, _after(np.flatnonzero(self.b == 32), close + 2, end)

    def _field_end(self, sp2: np.ndarray, end: np.ndarray) -> np.ndarray:
        """Where each line's ID#DATA ends: its end, or the space before a T/R marker."""
        pad = self.pad
        spaced = pad[end - 2] == 32
        if not spaced.any():
            return end
        return np.where(spaced & (end - 2 > sp2), end - 2, _after(np.flatnonzero(self.b == 32), sp2 + 1, end))

    def _hash(self, sp2: np.ndarray, fe: np.ndarray) -> np.ndarray:
        """The "#" after each line's id: 3 or 8 characters after the space (else searched)."""
        pad = self.pad
        h1 = np.where(pad[sp2 + 4] == 35, sp2 + 4, sp2 + 9)
        found = (pad[h1] == 35) & (h1 < fe)
        if found.all():
            return h1
        return np.where(found, h1, _next(self.b, 35, sp2 + 1, fe))

    def _counted(self, b: np.ndarray, tail: np.ndarray, close: np.ndarray, sp2: np.ndarray) -> bool:
        """The block's bytes that are not hex digits are exactly those its lines' fields account for."""
        n = tail.size
        marks = 2 * n + 2 * n + n + int(np.count_nonzero(tail)) * 2  # ( ) two spaces, newline; " T"
        marks += int(np.count_nonzero(self.dot_at)) + n + int(np.count_nonzero(self.fd))  # the dots, "#", "##"
        marks += int(np.count_nonzero(self.remote)) + int(np.count_nonzero(self.raw_dlc))  # "R", "_"
        lanes, names = self.every = self._named(slice(None))  # the channels: each name's bytes, times its rows
        counts = np.bincount(lanes, minlength=len(names)).tolist() if len(names) > 1 else [n]
        marks += sum(count * sum(not _HEX[c] for c in name) for count, name in zip(counts, names, strict=True))
        return b.size - _hex_digits(b) == marks

    def _between(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """How many bytes in each ``[lo, hi)`` are not hex digits."""
        nonhex = getattr(self, "nonhex", None)
        if nonhex is None:
            size = self.b.size
            nonhex = self.nonhex = _buffer("nonhex", size + 1, np.int32)
            nonhex[0] = 0
            np.cumsum(~_HEX[self.b], out=nonhex[1:])
        top = nonhex.size - 1
        return nonhex[np.clip(hi, 0, top)] - nonhex[np.clip(lo, 0, top)]

    def _ids(self, h1: np.ndarray, sp2: np.ndarray) -> np.ndarray:
        """The ids (3 or 8 hex digits before the "#"): :attr:`can_id`, :attr:`extended`, error frames."""
        size = h1 - sp2 - 1
        ext = size == 8
        words = np.ndarray((self.pad.size - 7,), _LE64, self.pad, 0, (1,))  # words[k]: 8 bytes from k
        # one read of the 8 bytes before each "#": a long id's digits, or a short one's three after five bytes
        # read and dropped (each byte lands in its own nibble: a short id is the low 12 bits)
        value = _extended_values(words[np.maximum(h1 - 8, 0)])
        low = value & _U(0xFFF)
        self.extended = ext
        if not ext.any():  # standard ids alone
            self.can_id = low.astype(np.uint32)
            self.err = ext
            return (size == 3) & (low <= _U(_MAX_STANDARD))
        err = ext & ((value & _U(_ERR_FLAG)) != 0)
        self.can_id = np.where(ext, value & _U(_MAX_EXTENDED), low).astype(np.uint32)
        self.err = err
        return (ext | (size == 3)) & np.where(ext, (value <= _U(_MAX_EXTENDED)) | err, low <= _U(_MAX_STANDARD))

    def _data(self, h1: np.ndarray, fe: np.ndarray) -> np.ndarray:
        """The payloads after the "#" (classic, FD, remote, raw DLC), each kind checked only where present."""
        pad = self.pad
        after = pad[h1 + 1]
        fd = after == 35
        remote = (after == 82) | (after == 114)
        has_fd, has_remote, has_under = bool(fd.any()), bool(remote.any()), self.has_under
        digit = pad[h1 + 2] if has_fd or has_remote else after  # CAN FD flags, a remote DLC (else unread)
        checks = []
        ds = h1 + 1
        if has_fd:
            checks.append(~fd | ((h1 + 2 < fe) & _HEX[digit]))
            self.fd_digit = np.where(fd, _NIBBLES[digit], 0)
            ds = np.where(fd, h1 + 3, ds)
        else:
            self.fd_digit = np.zeros(fe.size, dtype=np.int64)
        de = fe
        raw_dlc = under = dlc_digit = None
        if has_under:
            under = _next(self.b, 95, ds, fe)  # "_": a raw DLC
            raw_dlc = under < fe
            de = np.where(raw_dlc, under, fe)
            dlc_digit = _NIBBLES[pad[under + 1]]
            checks.append(~raw_dlc | (~fd & ~remote & (fe == under + 2) & (de - ds == 16) & _HEX[pad[under + 1]]
                                      & (dlc_digit >= 9)))
        rl = fe - h1 - 2
        if has_remote:
            de = np.where(remote, ds, de)
            checks.append(~remote | (rl == 0) | ((rl == 1) & (digit >= 48) & (digit <= 56)))
        hex_len = de - ds
        ok = (hex_len >= 0) & ((hex_len & 1) == 0)
        length = np.maximum(hex_len, 0) >> 1
        ok &= np.where(fd, _FD_BYTES[np.minimum(length, 65)], length <= 8) if has_fd else length <= 8
        for check in checks:
            ok &= check
        self.ds, self.de, self.length = ds, de, length
        self.fd, self.remote = fd, remote
        self.raw_dlc = raw_dlc if raw_dlc is not None else np.zeros(fe.size, dtype=bool)
        dlc = length if raw_dlc is None else np.where(raw_dlc, dlc_digit, length)
        self.dlc = np.where(remote, np.where(rl == 1, digit.astype(np.int64) - 48, 0), dlc) if has_remote else dlc
        return ok

    @property
    def flags(self) -> np.ndarray:
        """Each line's :class:`Block` flags."""
        flags = np.zeros(self.fd.size, dtype=np.uint8)
        if self.fd.any():
            digit = self.fd_digit.astype(np.uint8)
            flags |= np.where(self.fd, FLAG_FD | ((digit & 1) * FLAG_BRS) | ((digit & 2) // 2 * FLAG_ESI), 0
                              ).astype(np.uint8)
        for column, flag in ((self.remote, FLAG_REMOTE), (self.err, FLAG_ERROR)):
            if column.any():
                flags[column] |= flag
        return flags

    def _stamps(self, start: np.ndarray, close: np.ndarray, fixed: bool) -> np.ndarray:
        """The timestamps (digits, a dot and digits, or digits alone, between "(" and ")") as :attr:`time_s`;
        ``fixed``: every line's ")" is where the first line's is (every stamp as wide)."""
        n = start.size
        self.time_s = np.zeros(n, dtype=np.float64)
        ok = np.ones(n, dtype=bool)
        at = self._dot_place(start, close)
        kinds: list[tuple[int, slice | np.ndarray]]
        if fixed and at:  # one kind of stamp: the first line's
            self.dot_at = np.ones(n, dtype=bool)
            kinds = [(min(int(close[0] - start[0]) - 1, 48) * 64 + at - 1, slice(None))]
        else:
            width = close - start - 1
            dot = start + at if at else _next(self.b, 46, start + 1, close)
            self.dot_at = dot < close
            place = np.where(self.dot_at, dot - start - 1, 63)
            key = np.minimum(width, 48) * 64 + place
            if n and (key == key[0]).all():
                kinds = [(int(key[0]), slice(None))]
            else:
                kinds = [(int(k), np.flatnonzero(key == k)) for k in np.unique(key).tolist()]
        for k, pick in kinds:
            w, place_at = divmod(k, 64)
            self._stamp_kind(w, place_at, start[pick] + 1, ok, pick)
        return ok

    def _dot_place(self, start: np.ndarray, close: np.ndarray) -> int:
        """Where every line's timestamp has its dot, when it is where the first line's is; else 0."""
        if start.size:
            at = self.pad[int(start[0]):int(close[0])].tobytes().find(b".")
            if at > 0 and ((self.pad[start + at] == 46) & (start + at < close)).all():
                return at
        return 0

    def _stamp_kind(self, width: int, dot: int, first: np.ndarray, ok: np.ndarray, pick: slice | np.ndarray) -> None:
        """The timestamps of ``width`` characters with the dot at ``dot`` (63: none) from ``first``."""
        if width < 1 or width >= 48 or (dot != 63 and not 0 < dot < width - 1):
            ok[pick] = False  # empty, too long, or no digit before or after the dot
            return
        cells = _rows(self.pad, first, width)
        np.subtract(cells, np.uint8(48), out=cells)  # a digit is 0..9, anything else wraps above 9
        if dot != 63:
            cells[:, dot] = 0
        good: np.ndarray | None = None  # None: every row's are digits
        if cells.size and cells.max() > 9:
            good = np.asarray((cells <= 9).all(axis=1))
        if width <= 23:  # 10**22: the last exact power of ten
            weights = np.array([0.0 if k == dot else 10.0 ** (width - 1 - k - (dot != 63 and k < dot))
                                for k in range(width)])
            digits = _buffer("digits", cells.size, np.float64).reshape(cells.shape)
            np.copyto(digits, cells)
            whole = digits @ weights  # BLAS: every partial sum an integer below 2**53, exact in any order
            scale = 10.0 ** (width - 1 - dot) if dot != 63 else 1.0
            values = whole / scale  # an exact integer / an exact power of ten: one rounding, as float()
            slow = _NO_ROWS if not whole.size or whole.max() < _EXACT else np.flatnonzero(whole >= _EXACT)
        else:
            values = np.zeros(first.size)
            slow = np.arange(first.size)
        if good is not None:
            slow = slow[good[slow]]
            ok[pick] = good
        for r in slow.tolist():  # too many digits for one exact division: float() of the text
            at = int(first[r])
            values[r] = float(bytes(self.pad[at:at + width]))
        self.time_s[pick] = values

    def channels(self, rows: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
        """Each of ``rows``' channel index, and the names (in the order they first come)."""
        every = self.every
        lanes, names = every if every is not None and rows.size == self.start.size else self._named(rows)
        return lanes, tuple(name.decode("utf-8", "replace") for name in names)

    def _named(self, rows: np.ndarray | slice) -> tuple[np.ndarray, list[bytes]]:
        """Each of ``rows``' channel index, and the names' bytes (in the order they first come)."""
        begin = self.close[rows] + 2
        size = self.sp2[rows] - begin
        if not begin.size:
            return np.zeros(0, dtype=np.uint16), [b""]
        first = int(size[0])
        if first <= 8 and (size == first).all():  # names of up to 8 bytes are 64-bit words: compared as integers
            words = np.ndarray((self.pad.size - 7,), _LE64, self.pad, 0, (1,))
            found = _few(words[begin] & _U((1 << 8 * first) - 1))
            if found is not None:
                lanes, firsts = found
                return lanes, [self.pad[k:k + first].tobytes() for k in begin[firsts].tolist()]
        lanes = np.zeros(begin.size, dtype=np.uint16)
        if (size == first).all():
            cells = _rows(self.pad, begin, first)
            if (cells == cells[0]).all():
                return lanes, [cells[0].tobytes()]
        names: dict[bytes, int] = {}
        for length in np.unique(size).tolist():
            at = np.flatnonzero(size == length)
            cells = _rows(self.pad, begin[at], length)
            found_names, inverse = np.unique(cells.view(np.dtype((np.void, length))).reshape(-1), return_inverse=True)
            index = np.array([names.setdefault(k.tobytes(), len(names)) for k in found_names], dtype=np.uint16)
            lanes[at] = index[inverse.reshape(-1)]
        _seen, firsts = np.unique(lanes, return_index=True)
        order = np.argsort(firsts)  # the names in the order they first come
        rank = np.empty(order.size, dtype=np.uint16)
        rank[order] = np.arange(order.size, dtype=np.uint16)
        listed = list(names)
        return rank[lanes], [listed[k] for k in order.tolist()]

    def block(self, text: bytes, rows: np.ndarray) -> Block:
        """The frames of ``rows`` (good lines of ``text``) as a block (payloads: :class:`HexPayloads`)."""
        lanes, names = self.channels(rows)
        pick: Any = slice(None) if rows.size == self.start.size else rows  # every line: the columns as they are
        length = self.length[pick]
        return Block(self.time_s[pick], self.can_id[pick], self.extended[pick], self.flags[pick],
                     self.dlc[pick].astype(np.uint8), length.astype(np.uint8),
                     HexPayloads(text, self.b, self.ds[pick], length), lanes, names)


class HexPayloads:
    """A block's payloads as its lines' hex digits (``start``: each row's first in ``text``), rows made when read."""

    __slots__ = ("digits", "length", "start", "text")

    def __init__(self, text: bytes, digits: np.ndarray, start: np.ndarray, length: np.ndarray) -> None:
        self.text, self.digits, self.start, self.length = text, digits, start, length

    def rows(self, rows: Any) -> np.ndarray:
        """The bytes of ``rows``' digits as a ``len(rows) x longest`` matrix, zeros past each one's length."""
        start = self.start[rows]
        length = self.length[rows]
        width = int(length.max()) * 2 if start.size else 0
        if not width:
            return np.zeros((start.size, 0), dtype=np.uint8)
        digits = self.digits
        last = digits.size - width  # a row starting after it is near the text's end: its cells read from a copy
        if int(start.max()) <= last:
            cells = _rows(digits, start, width)
        else:
            cells = _rows(digits, np.minimum(start, last), width)
            for r in np.flatnonzero(start > last).tolist():
                at = int(start[r])
                cells[r, :digits.size - at] = digits[at:]  # its digits, then anything: past its length, zeroed
        payload = _PAIRS.take(cells.view(_LE16))  # two digits at a time
        if not (length == width >> 1).all():
            payload[np.arange(width >> 1) >= length[:, None]] = 0  # past a shorter row's data: the next bytes
        return payload

    def one(self, i: int) -> bytes:
        """Row ``i``'s payload."""
        at = int(self.start[i])
        return binascii.unhexlify(self.text[at:at + 2 * int(self.length[i])])


# --------------------------------------------------------------------------- numpy helpers

_LOCAL = threading.local()
_VOIDS: dict[int, np.dtype] = {}
"""The dtype of ``width`` bytes as one item, by width."""


def _buffer(name: str, count: int, dtype: type) -> np.ndarray:
    """This thread's scratch array ``name``, ``count`` items, kept from block to block (a process that gives freed
    memory back at once would fault a new block-sized array in page by page, every block)."""
    have: np.ndarray | None = getattr(_LOCAL, name, None)
    if have is None or have.size < count:
        have = np.empty(count + count // 4 + 64, dtype=dtype)
        setattr(_LOCAL, name, have)
    return have[:count]


def _hex_digits(b: np.ndarray) -> int:
    """How many bytes of ``b`` are hex digits (0-9, a-f, A-F): arithmetic in scratch, no table lookup."""
    work, mask, spare = _buffer("work", b.size, np.uint8), _buffer("mask", b.size, bool), _buffer("spare", b.size, bool)
    np.subtract(b, np.uint8(48), out=work)
    np.less(work, np.uint8(10), out=mask)  # a digit; anything else wraps above 9
    np.bitwise_or(b, np.uint8(32), out=work)
    np.subtract(work, np.uint8(97), out=work)
    np.less(work, np.uint8(6), out=spare)  # a-f or A-F
    np.logical_or(mask, spare, out=mask)
    return int(np.count_nonzero(mask))


def _next(b: np.ndarray, byte: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Per line, the first position of ``byte`` in ``b`` from ``lo`` on and before ``hi``, else ``hi``."""
    return _after(np.flatnonzero(b == byte), lo, hi)


def _after(positions: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Per line, the first of ``positions`` (sorted) at or after ``lo`` and before ``hi``, else ``hi``."""
    if not positions.size:
        return hi.copy()
    k = np.searchsorted(positions, lo)
    at = positions[np.minimum(k, positions.size - 1)]
    return np.where((k < positions.size) & (at < hi), at, hi)


def _few(codes: np.ndarray, most: int = 8) -> tuple[np.ndarray, np.ndarray] | None:
    """Each code's index among the distinct codes (first-come order) and their first rows; None: over ``most``."""
    lanes = np.zeros(codes.size, dtype=np.uint16)
    firsts = [0]
    rest = codes != codes[0]
    while rest.any():
        if len(firsts) == most:
            return None
        k = int(rest.argmax())
        same = codes == codes[k]
        lanes[same] = len(firsts)
        firsts.append(k)
        rest &= ~same
    return lanes, np.array(firsts, dtype=np.intp)


def _extended_values(x: np.ndarray) -> np.ndarray:
    """The values of 8 hex digits (``x``: their bytes, little-endian words), unchecked."""
    nib = (x & _U(0x0F0F0F0F0F0F0F0F)) + ((x >> _U(6)) & _U(0x0101010101010101)) * _U(9)  # byte k: digit k
    x = ((nib & _U(0x000F000F000F000F)) << _U(4)) | ((nib >> _U(8)) & _U(0x000F000F000F000F))
    x = ((x & _U(0x000000FF000000FF)) << _U(8)) | ((x >> _U(16)) & _U(0x000000FF000000FF))
    return ((x & _U(0xFFFF)) << _U(16)) | ((x >> _U(32)) & _U(0xFFFF))


def _rows(b: np.ndarray, pos: np.ndarray, width: int) -> np.ndarray:
    """The ``width`` bytes at each of ``pos``, as a ``len(pos) x width`` matrix (one copy per row, not per byte)."""
    void = _VOIDS.get(width)
    if void is None:
        void = _VOIDS[width] = np.dtype((np.void, width))
    cells: np.ndarray = np.ndarray((b.size - width + 1,), void, b, 0, (1,))[pos]  # a row one item: one copy, not width
    return cells.view(np.uint8).reshape(cells.size, width)
