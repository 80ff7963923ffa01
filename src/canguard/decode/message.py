"""One configured message's decoder: its strategy chosen once, one method for a block of payloads.

:class:`MessageDecoder` is built when the config is compiled, for one message on one
bus and the signals sources read from it (:class:`Output`). It picks how that message
is decoded, once, from the DBC:

``struct``
    Every configured signal is byte aligned, of a standard width (8/16/32/64-bit
    integer, float32/float64) and not multiplexed, and no two overlap. One
    :class:`struct.Struct` per byte order reads a payload (``unpack_from``); a block
    reads its joined payloads with ``iter_unpack`` (C); a numpy log's block of
    :data:`VECTOR_ROWS` rows or more is read by numpy from the hex of only the
    signals' bytes (:func:`canguard.decode.columns.field_rows`) when every signal is at
    most 32 bits wide and its scale keeps float64 exact.
``bits``
    What the bit maths of cantools takes and ``struct`` does not: any position and
    width up to 64 bits, Intel or Motorola, signed, IEEE float32/float64, classic and
    CAN FD (the padding cut, as cantools cuts it), simple and extended multiplexing.
    A frame, or a block of fewer than :data:`VECTOR_ROWS` rows, is read with Python
    integers (the payload as one int each way, shifts and masks); a larger block by
    numpy over the payload column (:func:`canguard.decode.columns.checked_rows`): the
    same maths, vectorised.
``cantools``
    Only what neither can take: container messages, a signal whose conversion is not
    cantools' identity or linear ``raw * scale + offset``, a float of another width
    than 32 or 64 bits, a multiplexer that is scaled (cantools picks the page by the
    scaled value, the bit maths by the raw one), a signal outside the payload.
    cantools' ``decode_simple``, one payload at a time.

The block size only picks between two kernels of the same maths (the scalar one and
its vectorised twin); ``tests/test_decode_message.py`` holds them equal on random
DBCs and payloads. :meth:`MessageDecoder.decode` gives each row's checked values
(:data:`~canguard.decode.rows.Row`: a tuple in output order; EMPTY when a multiplexed
payload carries none of the configured signals; None when the row is invalid), and
:meth:`MessageDecoder.explain` says why one payload's row is not a tuple and gives
each of its values as a :class:`~canguard.io.frame.Sample` carries it. A row is
invalid for one of these reasons, checked in one place (:func:`check_cell` per value;
its numpy twin :func:`canguard.decode.columns.check_column`): a payload of another
length (``bad_length``), one cantools refuses (``undecodable``: a multiplexer value
no signal is multiplexed on), a NaN or infinite value (``nan`` / ``inf``), one
outside the configured [min|max] (``out_of_range``), a presence flag at 0
(``absent``), a multiplexed payload with some configured signals but not all
(``other_page``).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

from canguard.decode.rows import EMPTY, Row
from canguard.io.frame import INVALID_INF, INVALID_LENGTH, INVALID_NAN, INVALID_PAYLOAD, INVALID_RANGE

if TYPE_CHECKING:
    import numpy as np

STRUCT, BITS, CANTOOLS = "struct", "bits", "cantools"
"""The strategies (:attr:`MessageDecoder.strategy`)."""

ABSENT = "absent"
"""A row's presence flag reads 0 (the source says its device is not there)."""
OTHER_PAGE = "other_page"
"""A multiplexed payload carries some of the configured signals, not all."""
NO_SIGNAL = "no_signal"
"""A multiplexed payload carries none of the configured signals (its row is EMPTY)."""

VECTOR_ROWS = 48
"""A block of fewer rows of one message takes the scalar kernel: below this numpy's fixed cost per call (a
dozen array operations per signal) outweighs what it saves; a frame never imports numpy. Where the two cross
was measured for byte-aligned fields against ``iter_unpack`` (48 rows), and on 2026-11-26 for bit fields
(a multiplexed Motorola message and a plain one of odd widths, in-process CPU time per block on a 2-core
machine): about 40 rows, within 10 % of this from 32 to 64."""

_BIG = 1.7976931348623157e308
"""The largest float: the default range bounds, so that +-inf fails the range check like NaN does."""
_NAN = math.nan
_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)

# struct codes of the standard widths: (is_float, signed, bits) -> code
_CODES = {
    (False, True, 8): "b", (False, False, 8): "B", (False, True, 16): "h", (False, False, 16): "H",
    (False, True, 32): "i", (False, False, 32): "I", (False, True, 64): "q", (False, False, 64): "Q",
    (True, True, 32): "f", (True, False, 32): "f", (True, True, 64): "d", (True, False, 64): "d",
}
_DTYPES = {"b": "i1", "B": "u1", "h": "i2", "H": "u2", "i": "i4", "I": "u4", "f": "f4", "d": "f8"}
"""struct codes numpy reads the same from a block's hex; 64-bit integers are left to struct."""
_INT_EXACT = 2**20
"""An integer scale and offset below this keep 32-bit raws' products and sums below 2**53."""


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


class Verdict(NamedTuple):
    """Why one payload's row is not a tuple of values, and what it carries.

    ``reason``: "" (the row is valid), or one of the module's reasons. ``cells``: per
    configured signal on the payload's multiplexer page, (its output index, its value as
    a sample carries it, its own reason); empty for ``bad_length`` and ``undecodable``.
    """

    reason: str
    cells: list[tuple[int, float, str]]


def check_cell(v: Any, present: bool, lo: float, hi: float) -> tuple[float, str]:
    """A decoded number as a row carries it (1.0/0.0 for a presence flag, NaN for NaN/inf) and why it is
    unusable ("" when it is usable)."""
    if v - v != 0.0:  # NaN or +-inf, with one comparison on the common path
        return _NAN, INVALID_NAN if v != v else INVALID_INF
    if present:
        if not v:
            return 0.0, ABSENT
        v = 1.0
    else:
        v = float(v)
    if not lo <= v <= hi:
        return v, INVALID_RANGE
    return v, ""


_BAD_LENGTH = Verdict(INVALID_LENGTH, [])
_UNDECODABLE = Verdict(INVALID_PAYLOAD, [])


# Reads one payload's configured values (None: a signal off this payload's multiplexer page); raises when refused.
_Scalar = Callable[[bytes], Sequence[Any]]
# Reads a block's joined payloads into checked rows, given each output's (present, lo, hi).
_Block = Callable[[bytes, tuple[tuple[bool, float, float], ...]], list[Row]]


class MessageDecoder:
    """Decodes the configured signals of one message, a block of payloads at a time (a frame is a block of one)."""

    __slots__ = ("_fast", "_iter", "_limits", "_scalar", "_spec", "_structs", "fields_key", "length", "lengths",
                 "message", "multiplexed", "names", "outputs", "signals", "spans", "strategy", "valid_row")

    def __init__(self, message: Any, outputs: Sequence[Output]) -> None:
        self.message = message
        self.outputs = tuple(outputs)
        self.length = int(message.length)
        # Accepted payload lengths: the DBC length; a CAN FD frame may carry padding up to the next DLC size.
        padded = next((n for n in _FD_LENGTHS if n >= self.length), self.length)
        self.lengths = frozenset({self.length, padded} if message.is_fd else {self.length})
        self.signals = frozenset(o.signal for o in self.outputs)
        self.names = tuple((o.source, o.role) for o in self.outputs)
        """(source, role) of each output: the samples a row gives, in order."""
        self.multiplexed = bool(message.is_multiplexed())
        self._limits = tuple((o.present, o.lo, o.hi) for o in self.outputs)
        self._structs: tuple[struct.Struct, ...] = ()
        self._iter: _Block | None = None
        self._fast: Callable[[bytes], tuple[float, ...] | None] | None = None
        self._spec: tuple[tuple[int, int, str, Any, Any, bool], ...] | None = None
        self.spans: list[tuple[int, int]] | None = None
        """(byte offset, width) of each configured signal when numpy reads a block from their bytes alone."""
        self.fields_key: tuple[Any, ...] | None = None
        """With :attr:`spans`: what decoding those bytes depends on (length, fields, checks). Messages with equal
        keys decode a block's fields in the same way: as one message over all their rows together."""
        by_name = {s.name: s for s in message.signals}
        wanted = [by_name[o.signal] for o in self.outputs]
        compiled = _struct_kernel(message, wanted)
        if compiled is not None:
            self.strategy = STRUCT
            self._structs, index, self._spec = compiled
            plan = [index[o.signal] for o in self.outputs]
            self._scalar = _struct_scalar(self._structs, plan)
            self._iter = _struct_iter(self._structs, plan)
            self._fast = _struct_fast(self._structs, plan, self._limits, self.lengths)
            if self._spec is not None:
                self.spans = [(at, width) for at, width, *_ in self._spec]
                self.fields_key = (self.length, self._spec, self._limits)
        elif (bits := _bits_kernel(message, wanted, self.length)) is not None:
            self.strategy = BITS
            self._scalar = bits
            self._fast = _bits_fast(message, wanted, self._limits, self.lengths)
        else:
            self.strategy = CANTOOLS
            self._scalar = _cantools_kernel(message, [o.signal for o in self.outputs])
        self.valid_row: Callable[[bytes], tuple[float, ...] | None] = (
            self._fast if self._fast is not None else self._valid_of_row)
        """One payload's row when it is whole and valid (the common live frame), else None (:meth:`decode` says
        why): the fused kernel of a plain message, decoded and checked in one step, where there is one."""

    # -- what a caller asks before decoding ------------------------------------------------
    def reads_fields(self, rows: int) -> bool:
        """A numpy block's ``rows`` rows are read from the bytes of :attr:`spans` alone (give
        :meth:`decode` those fields, not the payloads)."""
        return self.spans is not None and rows >= VECTOR_ROWS

    # -- decoding -----------------------------------------------------------------------
    def decode(self, data: bytes | list[np.ndarray], n: int) -> Sequence[Row]:
        """The checked rows of ``n`` payloads: per row its values in output order, EMPTY, or None (invalid).

        ``data``: the payloads joined, each of the DBC length (one payload may have any
        length: a wrong one gives None); or, when :meth:`reads_fields`, the ``n x width``
        uint8 matrices of :attr:`spans` in order. Rows of the scalar kernel that are not all
        tuples (a frame always takes it) come as :class:`Checked`, whose ``verdicts`` say why
        (:meth:`explain` says it of any payload).
        """
        if n == 1 and not isinstance(data, list):  # a frame: no Checked built for a valid row (the live path)
            fast = self._fast
            if fast is not None and (valid := fast(data)) is not None:
                return [valid]
            found = self._row(data)
            if not isinstance(found, Verdict):
                return [found]
            rows = Checked()
            rows.add(found)
            return rows
        if isinstance(data, list):
            from canguard.decode.columns import field_rows

            assert self._spec is not None
            return field_rows(data, n, self._spec, self._limits)
        if self._iter is not None:
            return self._iter(data, self._limits)
        if self.strategy == BITS and n >= VECTOR_ROWS:
            import numpy as np

            from canguard.decode.columns import checked_rows

            payload = np.frombuffer(data, dtype=np.uint8).reshape(n, self.length)
            return checked_rows(self.message, payload, [o.signal for o in self.outputs], self._limits,
                                self.multiplexed)
        size = self.length
        return self._checked(list(map(data.__getitem__, map(slice, range(0, n * size, size),
                                                            range(size, n * size + 1, size)))))

    def _checked(self, payloads: list[bytes]) -> Checked:
        """The scalar kernel's rows of ``payloads``, with the verdict of each row that is not a tuple."""
        rows = Checked()
        for data in payloads:
            rows.add(self._row(data))
        return rows

    def _valid_of_row(self, data: bytes) -> tuple[float, ...] | None:
        """:attr:`valid_row` of a message without a fused kernel: the scalar kernel's row, when valid."""
        found = self._row(data)
        return None if isinstance(found, Verdict) or not found else found

    def _row(self, data: bytes) -> tuple[float, ...] | Verdict:
        """One payload's checked values, or the verdict on it (the scalar kernel)."""
        if len(data) not in self.lengths:
            return _BAD_LENGTH
        try:
            values = self._scalar(data)
        except Exception:  # any payload cantools (or struct) cannot decode: the row is invalid, never raise
            return _UNDECODABLE
        row = []
        for v, (present, lo, hi) in zip(values, self._limits, strict=True):
            if v is None:  # off this payload's multiplexer page
                return self._verdict(values)
            if present or v - v != 0.0 or not lo <= v <= hi:  # check_cell's cases, screened in one test
                value, why = check_cell(v, present, lo, hi)
                if why:
                    return self._verdict(values)
                row.append(value)
            else:
                row.append(float(v))
        return tuple(row)

    def _verdict(self, values: Sequence[Any]) -> Verdict:
        """Why decoded ``values`` do not make a row, with each value on the payload's page as a sample carries it."""
        cells = []
        reason = ""
        for j, (v, (present, lo, hi)) in enumerate(zip(values, self._limits, strict=True)):
            if v is not None:
                value, why = check_cell(v, present, lo, hi)
                cells.append((j, value, why))
                reason = reason or why
        if not cells:
            return Verdict(NO_SIGNAL, cells)
        return Verdict(reason or (OTHER_PAGE if len(cells) < len(values) else ""), cells)

    def explain(self, data: bytes) -> Verdict:
        """Why ``data``'s row is what :meth:`decode` gives, with each value as a sample carries it."""
        found = self._row(data)
        if isinstance(found, Verdict):
            return found
        return Verdict("", [(j, v, "") for j, v in enumerate(found)])


class Checked(list[Row]):
    """Rows of the scalar kernel: a list, and ``verdicts``: the :class:`Verdict` of each row (by position) that
    is not a tuple."""

    __slots__ = ("verdicts",)

    def __init__(self) -> None:
        super().__init__()
        self.verdicts: dict[int, Verdict] = {}

    def add(self, found: tuple[float, ...] | Verdict) -> None:
        """Append a row: ``found``'s values, or EMPTY / None with its verdict kept."""
        if isinstance(found, Verdict):
            self.verdicts[len(self)] = found
            self.append(EMPTY if found.reason == NO_SIGNAL else None)
        else:
            self.append(found)


# -- struct ---------------------------------------------------------------------------------
def _byte_aligned(signal: Any) -> tuple[int, str, str] | None:
    """(byte offset, struct code, byte order char) of a standard-width byte-aligned signal, else None."""
    if signal.multiplexer_ids or signal.is_multiplexer or not _linear(signal):
        return None
    code = _CODES.get((bool(signal.is_float), bool(signal.is_signed), int(signal.length)))
    if code is None:
        return None
    if signal.byte_order == "little_endian":
        if signal.start % 8:
            return None
        return signal.start // 8, code, "<"
    # Motorola: cantools keeps the DBC start bit, i.e. the most significant bit in sawtooth numbering;
    # byte aligned means the MSB is bit 7 of its byte, and the value runs over the following bytes.
    if signal.start % 8 != 7:
        return None
    return signal.start // 8, code, ">"


_Index = tuple[int, Any, Any, bool]
"""(index in the joined raw tuple, scale, offset, identity) of one signal."""


def _struct_kernel(message: Any, wanted: list[Any]) -> tuple[
        tuple[struct.Struct, ...], dict[str, _Index], tuple[tuple[int, int, str, Any, Any, bool], ...] | None] | None:
    """The Structs (one per byte order, each covering the whole payload) reading ``wanted``, where each signal's raw
    value lands, and the numpy field spec (or None); None when a signal is not byte aligned or two overlap."""
    if message.is_multiplexed() or getattr(message, "is_container", False):
        return None
    groups: dict[str, list[tuple[int, str, Any]]] = {}
    for signal in {s.name: s for s in wanted}.values():
        aligned = _byte_aligned(signal)
        if aligned is None or aligned[0] + struct.calcsize("<" + aligned[1]) > message.length:
            return None
        offset, code, order = aligned
        groups.setdefault(order, []).append((offset, code, signal))
    structs: list[struct.Struct] = []
    index: dict[str, _Index] = {}
    spec: list[tuple[int, int, str, Any, Any, bool]] | None = []
    n = 0
    for order, items in groups.items():
        items.sort(key=lambda item: item[0])
        fmt, pos = order, 0
        for offset, code, signal in items:
            if offset < pos:  # overlapping signals: one Struct cannot express it
                return None
            fmt += f"{offset - pos}x" if offset > pos else ""
            fmt += code
            pos = offset + struct.calcsize("<" + code)
            scale, off = signal.scale, signal.offset
            identity = scale == 1 and off == 0
            index[signal.name] = (n, scale, off, identity)
            kind = _DTYPES.get(code)
            if spec is not None and kind is not None and (identity or _exact(scale, off, kind)):
                spec.append((offset, pos - offset, order + kind, scale, off, identity))
            else:
                spec = None
            n += 1
        structs.append(struct.Struct(fmt + (f"{message.length - pos}x" if pos < message.length else "")))
    by_output = tuple(spec) if spec is not None else None
    return tuple(structs), index, _spec_by_output(by_output, index, wanted)


def _spec_by_output(spec: tuple[tuple[int, int, str, Any, Any, bool], ...] | None, index: dict[str, _Index],
                    wanted: list[Any]) -> tuple[tuple[int, int, str, Any, Any, bool], ...] | None:
    """The numpy field spec in output order (``spec`` is in raw-tuple order), or None."""
    if spec is None:
        return None
    return tuple(spec[index[signal.name][0]] for signal in wanted)


def _exact(scale: Any, offset: Any, kind: str) -> bool:
    """float64 arithmetic gives what Python's gives for ``raw * scale + offset``."""
    if kind[0] == "f" or (type(scale) is float and type(offset) is float):
        return True  # float arithmetic both ways, operation for operation
    return all(type(x) is float or (type(x) is int and abs(x) < _INT_EXACT) for x in (scale, offset))


def _struct_scalar(structs: tuple[struct.Struct, ...], plan: list[_Index]) -> _Scalar:
    """Reads one payload's values with ``unpack_from`` (a longer, CAN FD padded payload too)."""
    unpackers = tuple(st.unpack_from for st in structs)
    single = unpackers[0] if len(unpackers) == 1 else None
    steps = tuple(plan)

    def read(data: bytes) -> list[Any]:
        if single is not None:
            raws = single(data)
        else:
            raws = ()
            for unpack in unpackers:
                raws += unpack(data)
        return [raws[i] if identity else raws[i] * scale + off for i, scale, off, identity in steps]

    return read


def _struct_iter(structs: tuple[struct.Struct, ...], plan: list[_Index]) -> _Block:
    """Reads a block's joined payloads with ``iter_unpack`` (C), then checks each row as :func:`check_cell` does."""
    steps = tuple(plan)

    def rows(data: bytes, limits: tuple[tuple[bool, float, float], ...]) -> list[Row]:
        if len(structs) == 1:
            raws: Any = structs[0].iter_unpack(data)
        else:
            raws = map(_joined, *(st.iter_unpack(data) for st in structs))
        if len(steps) == 1 and not limits[0][0]:  # one plain signal: the common message, in C but for the check
            (i, scale, off, identity), (_present, lo, hi) = steps[0], limits[0]
            col = [raw[i] for raw in raws]
            values = list(map(float, col)) if identity else [float(x * scale + off) for x in col]
            if all(map(lo.__le__, values)) and all(map(hi.__ge__, values)):  # the common block: all in range
                return list(zip(values))
            return [(v,) if lo <= v <= hi else None for v in values]  # NaN and +-inf fail the range
        out: list[Row] = []
        for raw in raws:
            row = []
            for (i, scale, off, identity), (present, lo, hi) in zip(steps, limits, strict=True):
                value, why = check_cell(raw[i] if identity else raw[i] * scale + off, present, lo, hi)
                if why:
                    break
                row.append(value)
            out.append(tuple(row) if len(row) == len(steps) else None)
        return out

    return rows


def _struct_fast(structs: tuple[struct.Struct, ...], plan: list[_Index], limits: tuple[tuple[bool, float, float], ...],
                 lengths: frozenset[int]) -> Callable[[bytes], tuple[float, ...] | None] | None:
    """The struct kernel's valid row of one payload of one plain signal (the common live frame) in one step, or
    None when the payload's row is anything else (the caller then takes the general path); None: not one signal."""
    if len(structs) != 1 or len(plan) != 1 or limits[0][0]:
        return None
    unpack = structs[0].unpack_from
    (i, scale, off, identity), (_present, lo, hi) = plan[0], limits[0]

    def row(data: bytes) -> tuple[float, ...] | None:
        if len(data) not in lengths:
            return None
        v = float(unpack(data)[i] if identity else unpack(data)[i] * scale + off)
        return (v,) if lo <= v <= hi else None  # NaN and +-inf fail the range: check_cell then names them

    return row


def _joined(*parts: tuple[Any, ...]) -> tuple[Any, ...]:
    """The raw tuples of one payload read by several Structs, one after the other."""
    return sum(parts, ())


# -- bits -----------------------------------------------------------------------------------
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


_Field = tuple[bool, int, int, int, str]
"""(little endian, shift, mask, sign bit (0: unsigned), struct code of an IEEE float or "") of one signal."""


def _field(signal: Any, size: int) -> _Field | None:
    """Where ``signal`` sits in a payload of ``size`` bytes read as one int, or None (not for the bit maths)."""
    length = int(signal.length)
    if not _linear(signal) or (signal.is_float and length not in (32, 64)) or not 0 < length <= 64:
        return None
    if signal.byte_order == "little_endian":
        shift = int(signal.start)  # cantools: the least significant bit, numbered from byte 0 bit 0
    else:
        # Motorola: the DBC start bit is the most significant bit, in sawtooth numbering (byte * 8 + bit)
        byte, bit = divmod(int(signal.start), 8)
        shift = (size - 1 - byte) * 8 + bit - (length - 1)
    if shift < 0 or shift + length > size * 8:
        return None
    sign = 1 << (length - 1) if signal.is_signed and not signal.is_float else 0
    code = ("<f" if length == 32 else "<d") if signal.is_float else ""
    return signal.byte_order == "little_endian", shift, (1 << length) - 1, sign, code


_Pages = tuple[tuple[str, frozenset[int]], ...]
"""The (multiplexer, values) conditions that select a signal."""


def _pages(message: Any, signal: Any) -> _Pages:
    """The (multiplexer, values) conditions that select ``signal``, outermost last."""
    by_name = {s.name: s for s in message.signals}
    out = []
    while signal.multiplexer_ids:
        out.append((signal.multiplexer_signal, frozenset(signal.multiplexer_ids)))
        signal = by_name[signal.multiplexer_signal]
    return tuple(out)


def _refusals(message: Any, muxes: list[Any]) -> tuple[tuple[str, _Pages, frozenset[int]], ...]:
    """Per multiplexer: its name, the pages that select it, and the values some signal is multiplexed on
    (cantools refuses a payload whose selected multiplexer holds another)."""
    out = []
    for mux in muxes:
        ids = frozenset(i for s in message.signals if s.multiplexer_signal == mux.name for i in s.multiplexer_ids or ())
        if ids:
            out.append((mux.name, _pages(message, mux), ids))
    return tuple(out)


def _bits_kernel(message: Any, wanted: list[Any], size: int) -> _Scalar | None:
    """Reads one payload's values with Python integers (the payload as one int each way), or None."""
    if getattr(message, "is_container", False):
        return None
    muxes = [s for s in message.signals if s.is_multiplexer]
    if any(s.scale != 1 or s.offset != 0 or s.is_signed or s.is_float for s in muxes):
        return None  # cantools selects by the scaled, signed value; the numpy twin by the raw bits
    needed = {s.name: s for s in (*wanted, *muxes)}
    fields: dict[str, _Field] = {}
    for name, signal in needed.items():
        spec = _field(signal, size)
        if spec is None:
            return None
        fields[name] = spec
    reads = tuple((fields[s.name], s.scale, s.offset, s.scale == 1 and s.offset == 0, _pages(message, s))
                  for s in wanted)
    if not muxes:
        return _plain_reader(tuple(read[:4] for read in reads), size)
    return _mux_reader(reads, _refusals(message, muxes), tuple((m.name, fields[m.name]) for m in muxes), size)


_from_bytes = int.from_bytes
_unpack = struct.unpack


def _convert(value: int, sign: int, code: str) -> Any:
    """A field's bits as cantools reads them: the IEEE float they hold, or a negative two's complement."""
    if code:
        return _unpack(code, value.to_bytes(8 if code == "<d" else 4, "little"))[0]
    return value - (sign << 1)


def _raw(little: int, big: int, spec: _Field) -> Any:
    """One signal's raw value (signed, or the IEEE float its bits hold) from the payload read as ints both ways."""
    is_little, shift, mask, sign, code = spec
    value = ((little if is_little else big) >> shift) & mask
    return _convert(value, sign, code) if code or value & sign else value


def _plain_reader(reads: tuple[tuple[_Field, Any, Any, bool], ...], size: int) -> _Scalar:
    """The bit maths of a message without multiplexing: each signal's raw value, scaled."""

    def read(data: bytes) -> list[Any]:
        if len(data) != size:
            data = data[:size]  # CAN FD padding: cantools reads the DBC length
        little, big = _from_bytes(data, "little"), _from_bytes(data, "big")
        out: list[Any] = []
        for (is_little, shift, mask, sign, code), scale, off, identity in reads:
            value = ((little if is_little else big) >> shift) & mask  # _raw, inline: the live path's common message
            if code or value & sign:
                value = _convert(value, sign, code)
            out.append(value if identity else value * scale + off)
        return out

    return read


def _bits_fast(message: Any, wanted: list[Any], limits: tuple[tuple[bool, float, float], ...],
               lengths: frozenset[int]) -> Callable[[bytes], tuple[float, ...] | None] | None:
    """The bit maths' valid row of one payload of a message without multiplexing, read and checked in one step
    (what :func:`_plain_reader` reads, then :meth:`MessageDecoder._row`'s checks), or None when the payload's
    row is anything else (the caller then takes the general path); None: a multiplexed or container message."""
    if message.is_multiplexed() or getattr(message, "is_container", False):
        return None
    size = int(message.length)
    steps = []
    for signal, (present, lo, hi) in zip(wanted, limits, strict=True):
        spec = _field(signal, size)
        if spec is None:
            return None
        scale, off = signal.scale, signal.offset
        steps.append((*spec, scale, off, scale == 1 and off == 0, present, lo, hi))
    reads = tuple(steps)
    want_little = any(step[0] for step in reads)
    want_big = not all(step[0] for step in reads)

    def row(data: bytes) -> tuple[float, ...] | None:
        n = len(data)
        if n != size:
            if n not in lengths:
                return None
            data = data[:size]  # CAN FD padding: cantools reads the DBC length
        little = _from_bytes(data, "little") if want_little else 0
        big = _from_bytes(data, "big") if want_big else 0
        out = []
        for is_little, shift, mask, sign, code, scale, off, identity, present, lo, hi in reads:
            value: Any = ((little if is_little else big) >> shift) & mask
            if code or value & sign:
                value = _convert(value, sign, code)
            if not identity:
                value = value * scale + off
            if present:
                if value - value != 0.0 or not value:
                    return None  # NaN, +-inf or 0: check_cell names it
                value = 1.0
            if not lo <= value <= hi:  # NaN and +-inf fail the range (compared before float(), as _row does)
                return None
            out.append(float(value))
        return tuple(out)

    return row


def _mux_reader(reads: tuple[tuple[_Field, Any, Any, bool, _Pages], ...],
                checks: tuple[tuple[str, _Pages, frozenset[int]], ...], mux_fields: tuple[tuple[str, _Field], ...],
                size: int) -> _Scalar:
    """The bit maths of a multiplexed message: refused pages raise; a signal off the payload's page is None."""

    def selected(pages: _Pages, mux: dict[str, Any]) -> bool:
        return all(mux[name] in ids for name, ids in pages)

    def read(data: bytes) -> list[Any]:
        if len(data) != size:
            data = data[:size]  # CAN FD padding: cantools reads the DBC length
        little, big = _from_bytes(data, "little"), _from_bytes(data, "big")
        mux = {name: _raw(little, big, spec) for name, spec in mux_fields}
        for name, pages, ids in checks:
            if selected(pages, mux) and mux[name] not in ids:
                raise ValueError(f"multiplexer {name} = {mux[name]}: no signal is multiplexed on it")
        out: list[Any] = []
        for spec, scale, off, identity, pages in reads:
            if pages and not selected(pages, mux):
                out.append(None)
                continue
            value = _raw(little, big, spec)
            out.append(value if identity else value * scale + off)
        return out

    return read


# -- cantools -------------------------------------------------------------------------------
def _cantools_kernel(message: Any, names: list[str]) -> _Scalar:
    """cantools' own decoding (raw numbers, scaled), for everything the bit maths cannot do."""
    simple = getattr(message, "decode_simple", None)
    decode = simple if simple is not None else message.decode
    getters = tuple(names)

    def read(data: bytes) -> list[Any]:
        values = decode(data, decode_choices=False, scaling=True)
        return [values.get(name) for name in getters]  # None: off this payload's multiplexer page

    return read
