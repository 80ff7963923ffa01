"""One configured message's decoder: compiled once from the DBC, one kernel over a block of payloads.

The kernel reads the payload as 64-bit words (an aligned IEEE float as ``f4``/``f8``): per signal a shift,
a mask, the sign, then ``raw * scale + offset`` in the number type that gives Python's result (float64,
int64 or Python integers). A block of one runs the same operators on that row's Python numbers
(:class:`_Numbers`), cheaper than numpy per call. The contract is equality with cantools'
``decode(..., decode_choices=False)`` to the bit. What the maths does not take (containers, a conversion
that is not linear, a float of another width than 32 or 64 bits, a scaled or signed multiplexer, a signal
outside the payload) goes through cantools' ``decode_simple`` per row, then the same row check.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from canguard.decode.rows import EMPTY, ColumnRows, OneRow, Row, Verdict
from canguard.io.frame import INVALID_INF, INVALID_LENGTH, INVALID_NAN, INVALID_PAYLOAD, INVALID_RANGE

BITS, CANTOOLS = "bits", "cantools"
"""The strategies (:attr:`MessageDecoder.strategy`)."""

ABSENT = "absent"
"""A row's presence flag reads 0 (the source says its device is not there)."""
OTHER_PAGE = "other_page"
"""A multiplexed payload carries some of the configured signals, not all."""
NO_SIGNAL = "no_signal"
"""A multiplexed payload carries none of the configured signals (its row is EMPTY)."""

_BIG = 1.7976931348623157e308
"""The largest float: the widest range bounds, so that +-inf fails the range check like NaN does."""
_NAN = math.nan
_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
_EXACT = 2**53
"""Integers up to this are exact in float64: a product and sum below it is what Python's integers give."""
_FEW_IDS = 8
"""Up to this many multiplexer values are matched by one comparison each, more by ``np.isin``."""

_F = np.float64
_I = np.int64
_LE, _BE = np.dtype("<u8"), np.dtype(">u8")
_FLOAT_LANES: dict[tuple[int, str], np.dtype] = {
    (32, "little_endian"): np.dtype("<f4"), (32, "big_endian"): np.dtype(">f4"),
    (64, "little_endian"): np.dtype("<f8"), (64, "big_endian"): np.dtype(">f8")}
_U1 = np.dtype(np.uint8)
_frombuffer = np.frombuffer  # positional arguments only: numpy's keyword parsing costs more than the call
_ONE_LENGTH = tuple(np.array([k], dtype=np.int64) for k in range(65))
"""The ``lengths`` of a block of one payload of each length (read only, shared)."""

Lanes = list[Any]
"""Per :func:`_slot` dtype, the block's words: ``lanes[s][k]`` is word ``k`` (a column, or one row's number)."""
Column = Any
"""A column of the block (an array) or, in a block of one, that row's Python number: the kernel treats both alike."""
_WRAP = 1 << 64
_U32, _F32, _U64, _F64 = struct.Struct("<I"), struct.Struct("<f"), struct.Struct("<Q"), struct.Struct("<d")
_ROW_FORMATS = {_LE: "<%dQ", _BE: ">%dQ", np.dtype("<f4"): "<%df", np.dtype(">f4"): ">%df", np.dtype("<f8"): "<%dd",
                np.dtype(">f8"): ">%dd"}
"""The :mod:`struct` format of each dtype the kernel reads (``%d``: the words of a row)."""


class _Columns:
    """The kernel's casts over a block's numpy columns."""

    f = _F
    i = _I  # a uint64 wraps: two's complement

    @staticmethod
    def f32(bits: Column) -> Column:
        """The low 32 bits as an IEEE float32, as float64."""
        return _F(np.uint32(bits).view(np.float32))

    @staticmethod
    def f64(bits: Column) -> Column:
        return bits.view(np.float64)


class _Numbers:
    """The kernel's casts over one row's Python numbers (the same values as :class:`_Columns` gives)."""

    f = float

    @staticmethod
    def i(raw: int) -> int:
        """As int64: an unsigned 64-bit value wraps (two's complement)."""
        return raw - _WRAP if raw >> 63 else raw

    @staticmethod
    def f32(bits: int) -> float:
        """The low 32 bits as an IEEE float32."""
        return _F32.unpack(_U32.pack(bits & 0xFFFFFFFF))[0]

    @staticmethod
    def f64(bits: int) -> float:
        return _F64.unpack(_U64.pack(bits))[0]


@dataclass(frozen=True)
class Output:
    """One value a message yields: for which source and role, from which signal, within which range."""

    source: str
    role: str
    signal: str
    present: bool
    """The source's presence flag: the row carries 1.0 when the signal is non-zero."""
    lo: float = -_BIG
    hi: float = _BIG


def check(value: Column, present: bool, lo: float, hi: float) -> tuple[Column, Column]:
    """The row check of one output's values (a column or one float): (what a valid row carries, which are usable).
    Usable: finite and in [lo, hi] (finite bounds: NaN and +-inf fail); a presence flag: non-zero, carrying 1.0."""
    if present:
        nonzero = value != 0.0
        good = (value >= -_BIG) & (value <= _BIG) & nonzero
        return nonzero * 1.0, good if lo <= 1.0 <= hi else good & False
    return value, (value >= lo) & (value <= hi)


def _reason(value: float, present: bool, lo: float, hi: float) -> tuple[float, str]:
    """One value as a sample carries it (NaN for NaN/inf, 1.0/0.0 for a presence flag) and why :func:`check`
    finds it unusable ("" when it does not)."""
    carried, good = check(float(value), present, lo, hi)
    if good:
        return float(carried), ""
    if value != value:
        return _NAN, INVALID_NAN
    if not -_BIG <= value <= _BIG:
        return _NAN, INVALID_INF
    if present:
        return (0.0, ABSENT) if value == 0.0 else (1.0, INVALID_RANGE)
    return value, INVALID_RANGE


class _Read(NamedTuple):
    """What the kernel read from a block, before the row check: per output its values and its page."""

    length_ok: Column
    decodable: Column | None  # rows cantools would decode (None: all of them)
    values: list[Column]  # each output's physical value, float64
    pages: list[Column | None]  # each output's rows on its multiplexer page (None: every row)


def _slot(dtypes: list[np.dtype], dtype: np.dtype) -> int:
    """The slot in :data:`Lanes` of ``dtype``'s view of the payload (``dtypes``: the views, given out as compiled)."""
    if dtype not in dtypes:
        dtypes.append(dtype)
    return dtypes.index(dtype)


class MessageDecoder:
    """Decodes the configured signals of one message, a block of payloads at a time (a frame is a block of one)."""

    __slots__ = ("_cantools", "_checks", "_dtypes", "_guard", "_muxes", "_pages", "_refusals",
                 "_row_words", "_unpaged", "_values", "length", "lengths", "message", "multiplexed", "names", "outputs",
                 "strategy", "width")

    def __init__(self, message: Any, outputs: Sequence[Output]) -> None:
        self.message = message
        self.outputs = tuple(outputs)
        self.length = int(message.length)
        # Accepted payload lengths: the DBC length; a CAN FD frame may carry padding up to the next DLC size.
        padded = next((n for n in _FD_LENGTHS if n >= self.length), self.length)
        self.lengths = (self.length, padded if message.is_fd else self.length)
        self.names = tuple((o.source, o.role) for o in self.outputs)
        """(source, role) of each output: the samples a row gives, in order."""
        self.multiplexed = bool(message.is_multiplexed())
        self._checks = tuple((j, o.present, max(o.lo, -_BIG), min(o.hi, _BIG)) for j, o in enumerate(self.outputs))
        self.width = max(8, -(-self.length // 8) * 8)
        """The payload bytes the kernel reads a row as (the DBC length rounded up to 64-bit words)."""
        by_name = {s.name: s for s in message.signals}
        wanted = [by_name[o.signal] for o in self.outputs]
        self._pages = tuple(_pages(message, s) for s in wanted)
        self._unpaged: list[Column | None] = [None] * len(self.outputs)
        compiled = _compile(message, wanted, self.length)
        self._cantools: Callable[[bytes], list[Any]] | None = None
        self._muxes: tuple[tuple[str, Callable[[Lanes, Any], Column]], ...] = ()
        self._refusals: tuple[tuple[str, tuple[tuple[str, frozenset[int]], ...], frozenset[int]], ...] = ()
        self._dtypes: tuple[np.dtype, ...] = ()
        self._guard = True
        if compiled is None:
            self.strategy = CANTOOLS
            self._cantools = _cantools_kernel(message, [o.signal for o in self.outputs])
            self._values: tuple[Callable[[Lanes, Any], Column], ...] = ()
        else:
            self.strategy = BITS
            self._values, self._muxes, self._dtypes, self._guard = compiled
            self._refusals = _refusals(message)
        self._row_words = tuple(struct.Struct(_ROW_FORMATS[d] % (self.width // d.itemsize)).unpack
                                for d in self._dtypes)
        """Each :data:`Lanes` slot of one row's payload (``width`` bytes): its words as Python numbers."""

    def one(self, data: bytes) -> tuple[np.ndarray, np.ndarray]:
        """``data``, one frame's payload, as a block of one: (``payload``, ``lengths``) for :meth:`decode`."""
        size = len(data)
        if size < self.width:
            data = data.ljust(self.width, b"\0")
        return _frombuffer(data, _U1)[None], _ONE_LENGTH[size] if size <= 64 else np.array([size])

    # -- the kernel ---------------------------------------------------------------------
    def decode(self, payload: np.ndarray, lengths: np.ndarray) -> Sequence[Row]:
        """The checked rows of a block: per row its values in output order, EMPTY, or None (invalid); ``verdict(k)``
        says why. ``payload``: ``n x width`` uint8, row ``k`` starting with its ``lengths[k]`` bytes. Several rows
        give a ColumnRows, one a list (a OneRow when it is not valid). Never raises on a payload."""
        n = len(lengths)
        if not n:
            return []
        one = n == 1  # a block of one: the row's Python numbers, not one-row columns
        length: Any = int(lengths[0]) if one else lengths
        first, padded = self.lengths
        length_ok = length == first if first == padded else (length == first) | (length == padded)
        decodable: Column | None = None
        pages = self._unpaged
        if self._cantools is not None:
            decodable, values, pages = self._read_cantools(payload, lengths, n)
        else:
            ops = _Numbers if one else _Columns
            lanes = []  # loops, not comprehensions: no function object per block (Python < 3.12)
            if one:  # the row's words as Python numbers
                data = payload.tobytes()
                if len(data) != self.width:
                    data = data[:self.width].ljust(self.width, b"\0")
                for words in self._row_words:
                    lanes.append(words(data))
            else:  # the block's word columns
                view = (payload if payload.shape[1] == self.width else _fit(payload, self.width)).view
                for dtype in self._dtypes:
                    lanes.append(view(dtype).T)
            values = []
            if self._guard and not one:
                with np.errstate(all="ignore"):  # a float scaled past the largest float: inf, as in Python
                    for value in self._values:
                        values.append(value(lanes, ops))
            else:  # Python's floats overflow to inf without a word
                for value in self._values:
                    values.append(value(lanes, ops))
            if self._muxes:
                decodable, pages = self._multiplexers(lanes, ops)
        # the row check
        ok = length_ok if decodable is None else length_ok & decodable
        carried = []
        for j, present, lo, hi in self._checks:
            kept, good = check(values[j], present, lo, hi)
            carried.append(kept)
            ok = ok & good
        empty = None
        if self.multiplexed:
            ok, empty = _on_pages(ok, length_ok if decodable is None else length_ok & decodable, pages)
        if one and ok:
            return [tuple(carried)]  # the live frame's common row: nobody asks it why
        read = _Read(length_ok, decodable, values, pages)
        if one:
            return OneRow(EMPTY if empty is not None and empty else None, lambda k: self._verdict(read, k, True))
        return ColumnRows(n, carried, ok ^ True, empty, lambda k: self._verdict(read, k, False))

    def _multiplexers(self, lanes: Lanes, ops: Any) -> tuple[Column | None, list[Column | None]]:
        """The rows cantools would decode (their selected multiplexers hold values some signal is multiplexed
        on; None: all) and each output's rows on its page (None: every row)."""
        raws = {}
        for name, raw in self._muxes:
            raws[name] = raw(lanes, ops)
        refused = None
        for name, pages, ids in self._refusals:
            selected = _selected(pages, raws)
            bad = _member(raws[name], ids) ^ True
            if selected is not None:
                bad = selected & bad
            refused = bad if refused is None else refused | bad
        return None if refused is None else refused ^ True, [_selected(pages, raws) for pages in self._pages]

    def _read_cantools(self, payload: np.ndarray, lengths: np.ndarray, n: int
                       ) -> tuple[Column | None, list[Column], list[Column | None]]:
        """cantools over each row of a block whose length is right: the rows it decodes, the values, the pages."""
        width = len(self.outputs)
        values = [[_NAN] * n for _ in range(width)]
        pages = [[True] * n for _ in range(width)]
        decodable = [True] * n
        sizes = lengths.tolist()
        accepted = set(self.lengths)
        read = self._cantools
        assert read is not None
        for k in range(n):
            if sizes[k] not in accepted:
                continue
            try:
                found = read(payload[k, :sizes[k]].tobytes())
            except Exception:  # any payload cantools cannot decode: the row is invalid, never raise
                decodable[k] = False
                continue
            for j, v in enumerate(found):
                if v is None:  # off this payload's multiplexer page
                    pages[j][k] = False
                else:
                    values[j][k] = float(v)
        if n == 1:
            return decodable[0], [v[0] for v in values], [p[0] if self._pages[j] else None for j, p in enumerate(pages)]
        return (np.array(decodable), [np.array(v, dtype=np.float64) for v in values],
                [np.array(p) if self._pages[j] else None for j, p in enumerate(pages)])

    def _verdict(self, read: _Read, k: int, one: bool) -> Verdict:
        """Why row ``k`` of ``read`` is what :meth:`decode` made of it, each value on its page as a sample has it."""

        def cell(column: Column) -> Any:
            return column if one else column[k]

        if not cell(read.length_ok):
            return Verdict(INVALID_LENGTH, [])
        if read.decodable is not None and not cell(read.decodable):
            return Verdict(INVALID_PAYLOAD, [])
        cells = []
        reason = ""
        for (j, present, lo, hi), value, page in zip(self._checks, read.values, read.pages, strict=True):
            if page is None or cell(page):
                carried, why = _reason(float(cell(value)), present, lo, hi)
                cells.append((j, carried, why))
                reason = reason or why
        if not cells:
            return Verdict(NO_SIGNAL, cells)
        return Verdict(reason or (OTHER_PAGE if len(cells) < len(self.outputs) else ""), cells)


def _on_pages(ok: Column, whole: Column, pages: list[Column | None]) -> tuple[Column, Column | None]:
    """The rows of a multiplexed message still valid once every output must be on its page, and those whole rows
    on which none is (EMPTY; None: no such row can be)."""
    off_all: Column | None = None
    for page in pages:
        if page is None:  # an output on every page: no row is without one
            off_all = False
            continue
        ok = ok & page
        off = page ^ True
        off_all = off if off_all is None else off_all & off
    if off_all is None or off_all is False:
        return ok, None
    return ok, whole & off_all


def _fit(payload: np.ndarray, width: int) -> np.ndarray:
    """``payload`` cut or padded with zeros to ``width`` bytes a row (the bytes past the DBC length are never read)."""
    if payload.shape[1] > width:
        return payload[:, :width]
    out = np.zeros((payload.shape[0], width), dtype=np.uint8)
    out[:, :payload.shape[1]] = payload
    return out


def _member(raw: Column, ids: frozenset[int]) -> Column:
    """Which of the raw multiplexer values ``raw`` are one of ``ids``."""
    if len(ids) > _FEW_IDS:
        return np.isin(raw, np.fromiter(ids, dtype=np.uint64))
    found = None
    for page in sorted(ids):
        hit = raw == page
        found = hit if found is None else found | hit
    return found


_Pages = tuple[tuple[str, frozenset[int]], ...]
"""The (multiplexer, values) conditions that select a signal, outermost last."""


def _selected(pages: _Pages, raws: dict[str, Column]) -> Column | None:
    """The rows whose multiplexers select a signal of ``pages`` (None: every row)."""
    selected = None
    for name, ids in pages:
        hit = _member(raws[name], ids)
        selected = hit if selected is None else selected & hit
    return selected


def _pages(message: Any, signal: Any) -> _Pages:
    """The (multiplexer, values) conditions that select ``signal``, outermost last."""
    by_name = {s.name: s for s in message.signals}
    out = []
    while signal.multiplexer_ids:
        out.append((signal.multiplexer_signal, frozenset(signal.multiplexer_ids)))
        signal = by_name[signal.multiplexer_signal]
    return tuple(out)


def _refusals(message: Any) -> tuple[tuple[str, _Pages, frozenset[int]], ...]:
    """Per multiplexer: its name, the pages that select it, and the values some signal is multiplexed on
    (cantools refuses a payload whose selected multiplexer holds another)."""
    out = []
    for mux in (s for s in message.signals if s.is_multiplexer):
        ids = frozenset(i for s in message.signals if s.multiplexer_signal == mux.name for i in s.multiplexer_ids or ())
        if ids:
            out.append((mux.name, _pages(message, mux), ids))
    return tuple(out)


# -- compiling a message into the bit maths ---------------------------------------------------
def _linear(signal: Any) -> bool:
    """cantools converts ``signal`` as ``raw * scale + offset`` (or leaves the raw value): the bit maths can."""
    from cantools.database.conversion import (
        IdentityConversion,
        LinearConversion,
        LinearIntegerConversion,
        NamedSignalConversion,
    )

    return isinstance(signal.conversion, IdentityConversion | LinearConversion | LinearIntegerConversion
                      | NamedSignalConversion)


_Getter = Callable[[Lanes, Any], Column]


def _compile(message: Any, wanted: list[Any], size: int) -> tuple[
        tuple[_Getter, ...], tuple[tuple[str, _Getter], ...], tuple[np.dtype, ...], bool] | None:
    """Each wanted signal's value getter, each multiplexer's raw getter, the dtypes they read, and whether a
    value may overflow float64 (or flag a signalling NaN); None when the bit maths does not take the message."""
    if getattr(message, "is_container", False):
        return None
    muxes = [s for s in message.signals if s.is_multiplexer]
    if any(s.scale != 1 or s.offset != 0 or s.is_signed or s.is_float for s in muxes):
        return None  # cantools selects by the scaled, signed value; the bit maths by the raw one
    dtypes: list[np.dtype] = []
    values = []
    guard = False
    for signal in wanted:
        compiled = _value(signal, size, dtypes)
        if compiled is None:
            return None
        values.append(compiled[0])
        guard = guard or compiled[1]
    raws = []
    for mux in muxes:
        raw = _bits(mux, size, dtypes)
        if raw is None:
            return None
        raws.append((mux.name, raw))
    return tuple(values), tuple(raws), tuple(dtypes), guard


def _first_bit(signal: Any) -> int:
    """Intel: the least significant bit, numbered from byte 0 bit 0. Motorola: the DBC start bit is the most
    significant bit in sawtooth numbering (byte * 8 + bit); here counted from byte 0's most significant bit."""
    start = int(signal.start)
    return start if signal.byte_order == "little_endian" else (start // 8) * 8 + 7 - start % 8


def _bits(signal: Any, size: int, dtypes: list[np.dtype]) -> _Getter | None:
    """The raw unsigned bits of ``signal`` (uint64) from the payload's 64-bit words, or None (outside the payload)."""
    length = int(signal.length)
    first = _first_bit(signal)
    if not 0 < length <= 64 or first + length > size * 8:
        return None
    mask = (1 << length) - 1
    if signal.byte_order == "little_endian":
        le = _slot(dtypes, _LE)
        k, shift = divmod(first, 64)
        if shift + length <= 64:
            def get(lanes: Lanes, ops: Any) -> Column:
                return (lanes[le][k] >> shift) & mask
        else:  # across two words: the high bits from the next one
            def get(lanes: Lanes, ops: Any) -> Column:
                words = lanes[le]
                return ((words[k] >> shift) | (words[k + 1] << (64 - shift))) & mask
        return get
    be = _slot(dtypes, _BE)
    k, at_bit = divmod(first, 64)
    end = at_bit + length
    if end <= 64:
        def get(lanes: Lanes, ops: Any) -> Column:
            return (lanes[be][k] >> (64 - end)) & mask
    else:  # across two words: the low bits from the next one
        def get(lanes: Lanes, ops: Any) -> Column:
            words = lanes[be]
            return ((words[k] << (end - 64)) | (words[k + 1] >> (128 - end))) & mask
    return get


def _float_lane(signal: Any, size: int, dtypes: list[np.dtype]) -> _Getter | None:
    """An IEEE float at a boundary of its own size read as such (no bits to move), else None."""
    length = int(signal.length)
    start = _first_bit(signal)
    if start % length or start + length > size * 8:
        return None
    slot = _slot(dtypes, _FLOAT_LANES[length, signal.byte_order])
    k = start // length

    def get(lanes: Lanes, ops: Any) -> Column:
        return ops.f(lanes[slot][k])

    return get


def _value(signal: Any, size: int, dtypes: list[np.dtype]) -> tuple[_Getter, bool] | None:
    """``signal``'s physical value as float64, and whether numpy may flag it (overflow, a float32 signalling NaN)."""
    length = int(signal.length)
    if not _linear(signal) or (signal.is_float and length not in (32, 64)):
        return None
    lane = _float_lane(signal, size, dtypes) if signal.is_float else None
    bits = _bits(signal, size, dtypes) if lane is None else None
    if lane is None and bits is None:
        return None
    scale, offset = signal.scale, signal.offset
    identity = scale == 1 and offset == 0
    if signal.is_float:
        raw = lane if lane is not None else _float_bits(bits, length)  # type: ignore[arg-type]
        if identity:
            return raw, length == 32  # a float32 signalling NaN flags "invalid" as it becomes a float64 NaN
        return (lambda lanes, ops: raw(lanes, ops) * scale + offset), True
    assert bits is not None
    return _integer(bits, length, bool(signal.is_signed), scale, offset), abs(scale) > 1e250


def _float_bits(bits: _Getter, length: int) -> _Getter:
    """An IEEE float not at a boundary of its size: its bits reinterpreted."""
    if length == 32:
        return lambda lanes, ops: ops.f32(bits(lanes, ops))
    return lambda lanes, ops: ops.f64(bits(lanes, ops))


def _integer(bits: _Getter, length: int, signed: bool, scale: Any, offset: Any) -> _Getter:
    """An integer signal's ``raw * scale + offset`` as float64, equal to Python's result ``float()``-ed. Python
    computes in floats when the scale or the offset is a float, in exact integers when both are integers: float64
    then where every product and sum stays below 2**53, int64 where it fits, Python integers beyond."""
    sign = 1 << (length - 1) if signed else 0
    integers = type(scale) is int and type(offset) is int
    bound = (1 << length) * abs(scale) + abs(offset)
    if length <= 53 and (not integers or bound <= _EXACT) and (type(scale) is not int or bound <= _EXACT):
        # the signed raw value is exact in float64 (raw ^ sign) - sign, and so is every step Python makes exactly
        as_float = _signed_float(bits, sign)
        if scale == 1 and offset == 0:
            return as_float
        return lambda lanes, ops: as_float(lanes, ops) * scale + offset
    if integers or type(scale) is int:
        if bound < 2**63:  # exact in int64, then one rounding to float64 as Python's float() of the integer
            as_int = _signed_int(bits, length, sign)
            if type(offset) is int:
                return lambda lanes, ops: ops.f(as_int(lanes, ops) * scale + offset)
            return lambda lanes, ops: ops.f(as_int(lanes, ops) * scale) + offset
        exact = np.frompyfunc(lambda r: float(((int(r) ^ sign) - sign) * scale + offset), 1, 1)
        return lambda lanes, ops: ops.f(exact(bits(lanes, ops)))
    as_int = _signed_int(bits, length, sign)  # a float scale: float(raw), correctly rounded, then float maths
    return lambda lanes, ops: ops.f(as_int(lanes, ops)) * scale + offset


def _signed_float(bits: _Getter, sign: int) -> _Getter:
    """The signed raw value of a field of at most 53 bits, as float64 (exact)."""
    if not sign:
        return lambda lanes, ops: ops.f(bits(lanes, ops))
    half = float(sign)
    return lambda lanes, ops: ops.f(bits(lanes, ops) ^ sign) - half


def _signed_int(bits: _Getter, length: int, sign: int) -> _Getter:
    """The signed raw value of a field, as int64 (an unsigned 64-bit one stays uint64)."""
    if not sign:
        return bits if length == 64 else lambda lanes, ops: ops.i(bits(lanes, ops))
    if length == 64:
        return lambda lanes, ops: ops.i(bits(lanes, ops))  # two's complement: the cast wraps
    return lambda lanes, ops: ops.i(bits(lanes, ops) ^ sign) - sign


# -- cantools -------------------------------------------------------------------------------
def _cantools_kernel(message: Any, names: list[str]) -> Callable[[bytes], list[Any]]:
    """cantools' own decoding (raw numbers, scaled), for everything the bit maths cannot do."""
    simple = getattr(message, "decode_simple", None)
    decode = simple if simple is not None else message.decode
    getters = tuple(names)

    def read(data: bytes) -> list[Any]:
        values = decode(data, decode_choices=False, scaling=True)
        return [values.get(name) for name in getters]  # None: off this payload's multiplexer page

    return read
