"""Frames -> samples: decode only the configured signals of the configured frames.

:class:`Decoder` is built once from a :class:`~canguard.config.schema.Config`. Its
:meth:`Decoder.decode` is the replay hot path (millions of frames), so:

- frames are filtered with one dict lookup on ``(bus, arbitration_id,
  is_extended_id)`` before anything is decoded; unconfigured frames cost only
  that lookup;
- messages are looked up once, at construction;
- messages whose configured signals are byte-aligned standard widths (8/16/32/64
  bit integers, float32/float64, little- or big-endian) are decoded with one
  precompiled :class:`struct.Struct` per byte order, then scaled exactly as
  cantools scales (``raw * scale + offset``); every other message (multiplexed,
  odd bit widths, containers) goes through cantools' own ``decode_simple``.

Nothing raises out of :meth:`Decoder.decode`: a frame of the wrong length or a
payload cantools cannot decode becomes one invalid sample (``bad_length`` /
``undecodable``, value NaN) per configured signal; a NaN or infinite value
becomes an invalid sample (``nan`` / ``inf``). Error and remote frames are
counted, never decoded. The DBC [min|max] range check is not done here but by
:class:`~canguard.protect.staleness.SourceHealth`.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from canguard.config.schema import Config, SignalRef
from canguard.io.frame import (
    INVALID_INF,
    INVALID_LENGTH,
    INVALID_NAN,
    INVALID_PAYLOAD,
    Frame,
    Sample,
)

_NAN = math.nan
_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)

# struct codes of the standard widths: (is_float, signed, bits) -> code
_CODES = {
    (False, True, 8): "b",
    (False, False, 8): "B",
    (False, True, 16): "h",
    (False, False, 16): "H",
    (False, True, 32): "i",
    (False, False, 32): "I",
    (False, True, 64): "q",
    (False, False, 64): "Q",
    (True, True, 32): "f",
    (True, False, 32): "f",
    (True, True, 64): "d",
    (True, False, 64): "d",
}


@dataclass
class DecodeCounters:
    """What one bus (or all buses together) fed the decoder.

    ``frames``: every frame given to :meth:`Decoder.decode`; ``decoded``: configured
    frames decoded; ``invalid``: configured frames that produced invalid samples
    (wrong length, undecodable payload, NaN/inf value); ``skipped``: frames of no
    configured message; ``error_frames`` / ``remote_frames``: counted, never decoded.
    ``reasons`` counts invalid samples by reason.
    """

    frames: int = 0
    decoded: int = 0
    invalid: int = 0
    skipped: int = 0
    error_frames: int = 0
    remote_frames: int = 0
    reasons: dict[str, int] = field(default_factory=dict)

    def add(self, other: DecodeCounters) -> None:
        """Add ``other``'s counts to these."""
        self.frames += other.frames
        self.decoded += other.decoded
        self.invalid += other.invalid
        self.skipped += other.skipped
        self.error_frames += other.error_frames
        self.remote_frames += other.remote_frames
        for k, v in other.reasons.items():
            self.reasons[k] = self.reasons.get(k, 0) + v


@dataclass(frozen=True)
class _Output:
    """One sample a message yields: which source/role, from which signal."""

    source: str
    role: str
    signal: str
    present: bool


_new = tuple.__new__  # builds a Sample without NamedTuple.__new__'s keyword handling (hot path)

# Runs one configured frame's payload: (data, t) -> (samples, any invalid); raises on an undecodable payload.
_Run = Callable[[bytes, float], tuple[list[Sample], bool]]


def _value_sample(source: str, role: str, v: float, t: float, present: bool) -> Sample:
    """The sample of one decoded number: invalid for NaN/inf, 1.0/0.0 for a present flag."""
    if v - v != 0.0:  # NaN or +-inf, with one comparison on the common path
        return _new(Sample, (source, role, _NAN, t, INVALID_NAN if v != v else INVALID_INF))
    if present:
        return _new(Sample, (source, role, 1.0 if v else 0.0, t, ""))
    return _new(Sample, (source, role, float(v), t, ""))


class _Entry:
    """Everything needed to turn one configured (bus, id, extended) frame into samples."""

    __slots__ = ("fast", "fields", "float_raws", "length", "lengths", "message", "outputs", "plan", "run", "unpack")

    def __init__(self, message: Any, outputs: list[_Output]) -> None:
        self.message = message
        self.outputs = tuple(outputs)
        self.length = int(message.length)
        # Accepted payload lengths: the DBC length; a CAN FD frame may carry padding up to the next DLC size.
        padded = next((n for n in _FD_LENGTHS if n >= self.length), self.length)
        self.lengths = frozenset({self.length, padded} if message.is_fd else {self.length})
        compiled = _compile_fast(message, self.outputs)
        self.fast = compiled is not None
        self.plan: tuple[_Step, ...] | None = None
        """Struct path: (source, role, index in the raw tuple, scale, offset, identity, present) per output."""
        self.unpack: Callable[[bytes], tuple[Any, ...]] | None = None
        """Struct path with one byte order: the unpacker whose tuple ``plan`` indexes (else None)."""
        self.float_raws: tuple[bool, ...] = ()
        """Struct path: whether each raw value of the unpacked tuple is a float (else an int)."""
        self.fields: tuple[tuple[int, str, str], ...] = ()
        """Struct path with one byte order: (byte offset, struct code, byte order) of each raw value."""
        if compiled is not None:
            self.run, self.plan, self.unpack, self.float_raws, self.fields = compiled
        else:
            self.run = _fallback(message, self.outputs)


def _byte_aligned(signal: Any) -> tuple[int, str, str] | None:
    """(byte offset, struct code, byte order char) of a standard-width byte-aligned signal, else None."""
    if signal.multiplexer_ids or signal.is_multiplexer:
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


_Step = tuple[str, str, int, float, float, bool, bool]


def _structs(groups: dict[str, list[tuple[int, str, Any]]], index: dict[str, tuple[int, float, float, bool]],
             floats: list[bool], fields: list[tuple[int, str, str]]) -> list[struct.Struct] | None:
    """One Struct per byte order of ``groups``' (offset, code, signal) fields; every wanted value lands at a
    known index of the joined raw tuple (filled in ``index``, ``floats``, ``fields``). None: fields overlap."""
    structs: list[struct.Struct] = []
    n = 0
    for order, items in groups.items():
        items.sort(key=lambda item: item[0])
        fmt, pos = order, 0
        for offset, code, signal in items:
            if offset < pos:  # overlapping signals: one Struct cannot express it
                return None
            if offset > pos:
                fmt += f"{offset - pos}x"
            fmt += code
            pos = offset + struct.calcsize("<" + code)
            scale, off = signal.scale, signal.offset
            index[signal.name] = (n, scale, off, scale == 1 and off == 0)
            floats.append(code in "fd")
            fields.append((offset, code, order))
            n += 1
        structs.append(struct.Struct(fmt))
    return structs


def _compile_fast(
    message: Any, outputs: tuple[_Output, ...]
) -> tuple[_Run, tuple[_Step, ...], Callable[[bytes], tuple[Any, ...]] | None, tuple[bool, ...],
           tuple[tuple[int, str, str], ...]] | None:
    """A struct-based run of ``outputs`` of ``message`` with its plan, single unpacker, float flags and fields, or None.

    None when a signal is not eligible (then cantools decodes the message).
    """
    if message.is_multiplexed() or getattr(message, "is_container", False):
        return None
    wanted = {o.signal for o in outputs}
    groups: dict[str, list[tuple[int, str, Any]]] = {}
    index: dict[str, tuple[int, float, float, bool]] = {}
    floats: list[bool] = []
    fields: list[tuple[int, str, str]] = []
    bits: Callable[[bytes], tuple[Any, ...]] | None = None
    for signal in message.signals:
        if signal.name not in wanted:
            continue
        aligned = _byte_aligned(signal)
        if aligned is None or aligned[0] + struct.calcsize("<" + aligned[1]) > message.length:
            bits = _bit_fields(message, [s for s in message.signals if s.name in wanted], index, floats)
            if bits is None:
                return None
            break
        offset, code, order = aligned
        groups.setdefault(order, []).append((offset, code, signal))
    structs = _structs({} if bits is not None else groups, index, floats, fields)
    if structs is None:
        return None
    plan: tuple[_Step, ...] = tuple((o.source, o.role, *index[o.signal], o.present) for o in outputs)
    unpackers = (bits,) if bits is not None else tuple(st.unpack_from for st in structs)
    single = unpackers[0] if len(unpackers) == 1 else None

    def run(data: bytes, t: float) -> tuple[list[Sample], bool]:
        if single is not None:
            raws = single(data)
        else:
            raws = ()
            for unpack in unpackers:
                raws += unpack(data)
        out: list[Sample] = []
        bad = False
        for source, role, i, scale, off, identity, present in plan:
            v = raws[i] if identity else raws[i] * scale + off
            if v - v != 0.0 or present:
                sample = _value_sample(source, role, v, t, present)
                bad = bad or bool(sample.reason)
                out.append(sample)
            else:
                out.append(_new(Sample, (source, role, float(v), t, "")))
        return out, bad

    return run, plan, single, tuple(floats), tuple(fields) if bits is None and len(structs) == 1 else ()


def _bit_fields(
    message: Any, signals: list[Any], index: dict[str, tuple[int, float, float, bool]], floats: list[bool]
) -> Callable[[bytes], tuple[int, ...]] | None:
    """An unpacker of integer signals at any bit position (one int of the payload, shifts and masks), or None.

    Fills ``index`` and ``floats`` like the struct path. None for float signals
    off byte boundaries and CAN FD messages (whose payload may be padded: the
    big-endian positions would move), which cantools decodes instead.
    """
    if message.is_fd:
        return None
    size = int(message.length)
    specs: list[tuple[bool, int, int, int]] = []
    for n, signal in enumerate(signals):
        if signal.is_float or signal.multiplexer_ids or signal.is_multiplexer:
            return None
        length = int(signal.length)
        if signal.byte_order == "little_endian":
            shift = int(signal.start)  # cantools: the least significant bit, numbered from byte 0 bit 0
        else:
            # Motorola: the DBC start bit is the most significant bit, in sawtooth numbering (byte * 8 + bit)
            byte, bit = divmod(int(signal.start), 8)
            shift = (size - 1 - byte) * 8 + bit - (length - 1)
        if shift < 0 or shift + length > size * 8:
            return None
        specs.append((signal.byte_order == "little_endian", shift, (1 << length) - 1,
                      1 << (length - 1) if signal.is_signed else 0))
        scale, off = signal.scale, signal.offset
        index[signal.name] = (n, scale, off, scale == 1 and off == 0)
        floats.append(False)
    plan = tuple(specs)
    from_bytes = int.from_bytes

    def unpack(data: bytes) -> tuple[int, ...]:
        little = from_bytes(data, "little")
        big = from_bytes(data, "big")
        out = []
        for is_little, shift, mask, sign in plan:
            raw = ((little if is_little else big) >> shift) & mask
            if raw & sign:
                raw -= sign << 1
            out.append(raw)
        return tuple(out)

    return unpack


def _fallback(message: Any, outputs: tuple[_Output, ...]) -> _Run:
    """cantools' own decoding (raw numbers, scaled), for everything the fast path cannot do."""
    simple = getattr(message, "decode_simple", None)
    decode = simple if simple is not None else message.decode
    plan = tuple((o.source, o.role, o.signal, o.present) for o in outputs)

    def run(data: bytes, t: float) -> tuple[list[Sample], bool]:
        values = decode(data, decode_choices=False, scaling=True)
        out: list[Sample] = []
        bad = False
        for source, role, name, present in plan:
            v = values.get(name)
            if v is None:  # a multiplexed signal outside this frame's mux branch: no sample
                continue
            sample = _value_sample(source, role, float(v), t, present)
            bad = bad or bool(sample.reason)
            out.append(sample)
        return out, bad

    return run


class Decoder:
    """Decodes the configured signals of the configured frames of a :class:`Config`.

    ``decode(frame, bus)`` never raises. Counters: :attr:`frames`, :attr:`decoded`,
    :attr:`invalid`, :attr:`skipped`, :attr:`error_frames`, :attr:`remote_frames`
    (all buses), :attr:`per_bus` (by bus name), :meth:`totals` (with reasons).
    """

    def __init__(self, cfg: Config) -> None:
        self._table: dict[tuple[str, int, bool], _Entry] = {}
        self.per_bus: dict[str, DecodeCounters] = {name: DecodeCounters() for name in cfg.buses}
        db = cfg.database
        grouped: dict[tuple[str, int, bool], list[tuple[SignalRef, str]]] = {}
        for source in cfg.sources.values():
            for ref in source.signals:
                grouped.setdefault((ref.bus, ref.frame_id, ref.is_extended_id), []).append((ref, source.name))
        for key, refs in grouped.items():
            message = db.get_message_by_name(refs[0][0].message)
            outputs = [_Output(src, ref.role, ref.signal, ref.role == "present") for ref, src in refs]
            self._table[key] = _Entry(message, outputs)

    # -- introspection -----------------------------------------------------
    def keys(self) -> Iterable[tuple[str, int, bool]]:
        """The configured ``(bus, arbitration_id, is_extended_id)`` triples."""
        return self._table.keys()

    def entries(self) -> Iterable[tuple[tuple[str, int, bool], _Entry]]:
        """Every configured ``(bus, arbitration_id, is_extended_id)`` with its decoding entry."""
        return self._table.items()

    def is_fast(self, bus: str, arbitration_id: int, is_extended_id: bool) -> bool:
        """True when that configured frame is decoded by the precompiled struct path."""
        entry = self._table.get((bus, arbitration_id, is_extended_id))
        return entry is not None and entry.fast

    def totals(self) -> DecodeCounters:
        """The counters of every bus added together."""
        total = DecodeCounters()
        for c in self.per_bus.values():
            total.add(c)
        return total

    @property
    def frames(self) -> int:
        """Frames given to :meth:`decode`, all buses."""
        return sum(c.frames for c in self.per_bus.values())

    @property
    def decoded(self) -> int:
        """Configured frames decoded, all buses."""
        return sum(c.decoded for c in self.per_bus.values())

    @property
    def invalid(self) -> int:
        """Configured frames that gave invalid samples, all buses."""
        return sum(c.invalid for c in self.per_bus.values())

    @property
    def skipped(self) -> int:
        """Frames of no configured message, all buses."""
        return sum(c.skipped for c in self.per_bus.values())

    @property
    def error_frames(self) -> int:
        """Error frames seen (never decoded), all buses."""
        return sum(c.error_frames for c in self.per_bus.values())

    @property
    def remote_frames(self) -> int:
        """Remote frames seen (never decoded), all buses."""
        return sum(c.remote_frames for c in self.per_bus.values())

    # -- the hot path ------------------------------------------------------
    def decode(self, frame: Frame, bus: str) -> list[Sample]:
        """The samples of ``frame`` received on ``bus``: empty for frames nobody configured."""
        counters = self.per_bus.get(bus)
        if counters is None:
            counters = self.per_bus[bus] = DecodeCounters()
        counters.frames += 1
        if frame.is_error_frame:
            counters.error_frames += 1
            return []
        if frame.is_remote_frame:
            counters.remote_frames += 1
            return []
        entry = self._table.get((bus, frame.arbitration_id, frame.is_extended_id))
        if entry is None:
            counters.skipped += 1
            return []
        data = frame.data
        t = frame.t
        if len(data) not in entry.lengths:
            return self._invalid(entry, t, INVALID_LENGTH, counters)
        try:
            out, bad = entry.run(data, t)
        except Exception:  # any payload cantools (or struct) cannot decode: never raise out
            return self._invalid(entry, t, INVALID_PAYLOAD, counters)
        if bad:
            counters.invalid += 1
            for sample in out:
                if sample.reason:
                    counters.reasons[sample.reason] = counters.reasons.get(sample.reason, 0) + 1
        else:
            counters.decoded += 1
        return out

    @staticmethod
    def _invalid(entry: _Entry, t: float, reason: str, counters: DecodeCounters) -> list[Sample]:
        counters.invalid += 1
        counters.reasons[reason] = counters.reasons.get(reason, 0) + len(entry.outputs)
        return [Sample(o.source, o.role, _NAN, t, reason) for o in entry.outputs]
