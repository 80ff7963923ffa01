"""Frames -> samples: decode only the configured signals of the configured frames.

Never raises: a wrong length or an undecodable payload gives one NaN sample per configured signal, a NaN
or infinite value an invalid sample; error and remote frames are counted, never decoded. The range and a
presence flag at 0 leave the sample valid: :class:`~canguard.protect.staleness.SourceHealth` reports those.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from canguard.config.schema import Config, SignalRef
from canguard.decode.message import MessageDecoder, Output
from canguard.decode.rows import EMPTY
from canguard.io.frame import INVALID_INF, INVALID_LENGTH, INVALID_NAN, INVALID_PAYLOAD, Frame, Sample

_NAN = math.nan
_SAMPLE_REASONS = frozenset({INVALID_NAN, INVALID_INF})
"""The reasons a sample carries itself (the others are the row's: SourceHealth reports range and presence)."""
_new = tuple.__new__  # builds a Sample without NamedTuple.__new__'s keyword handling (hot path)


@dataclass
class DecodeCounters:
    """What one bus fed the decoder (the summary's ``frames``); ``reasons`` counts invalid samples by reason."""

    frames: int = 0
    decoded: int = 0
    invalid: int = 0
    skipped: int = 0
    error_frames: int = 0
    remote_frames: int = 0
    reasons: dict[str, int] = field(default_factory=dict)


def _all_buses(name: str, doc: str) -> property:
    """A counter of :class:`DecodeCounters` summed over every bus."""
    return property(lambda self: sum(getattr(c, name) for c in self.per_bus.values()), doc=f"{doc}, all buses.")


def _output(ref: SignalRef, source: str) -> Output:
    """What a configured signal yields: its source and role, and the range its values must keep."""
    lo, hi = ref.minimum, ref.maximum
    return Output(source, ref.role, ref.signal, ref.role == "present",
                  *((float(lo),) if lo is not None else ()), *((float(hi),) if hi is not None else ()))


class Decoder:
    """Decodes the configured signals of the configured frames; counters summed over every bus, and :attr:`per_bus`."""

    def __init__(self, cfg: Config) -> None:
        self._table: dict[tuple[str, int, bool], MessageDecoder] = {}
        self.per_bus: dict[str, DecodeCounters] = {name: DecodeCounters() for name in cfg.buses}
        db = cfg.database
        grouped: dict[tuple[str, int, bool], list[tuple[SignalRef, str]]] = {}
        for source in cfg.sources.values():
            for ref in source.signals:
                grouped.setdefault((ref.bus, ref.frame_id, ref.is_extended_id), []).append((ref, source.name))
        for key, refs in grouped.items():
            message = db.get_message_by_name(refs[0][0].message)
            self._table[key] = MessageDecoder(message, [_output(ref, src) for ref, src in refs])

    # -- introspection -----------------------------------------------------
    def entries(self) -> Iterable[tuple[tuple[str, int, bool], MessageDecoder]]:
        """Every configured ``(bus, arbitration_id, is_extended_id)`` with its message's decoder."""
        return self._table.items()

    frames = _all_buses("frames", "Frames given to :meth:`decode`")
    decoded = _all_buses("decoded", "Configured frames decoded")
    invalid = _all_buses("invalid", "Configured frames that gave invalid samples")
    skipped = _all_buses("skipped", "Frames of no configured message")
    error_frames = _all_buses("error_frames", "Error frames seen (never decoded)")
    remote_frames = _all_buses("remote_frames", "Remote frames seen (never decoded)")

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
        t = frame.t
        rows = entry.decode(*entry.one(frame.data))  # a frame is a block of one
        row = rows[0]
        if not row:
            return row_samples(entry, rows, 0, t, counters)
        counters.decoded += 1
        if len(row) == 1:  # most messages: one configured signal
            (source, role), = entry.names
            return [_new(Sample, (source, role, row[0], t, ""))]
        out = []  # a loop, not a comprehension: no function object per frame (Python < 3.12)
        for (source, role), v in zip(entry.names, row, strict=True):
            out.append(_new(Sample, (source, role, v, t, "")))
        return out


def row_samples(entry: MessageDecoder, rows: Any, k: int, t: float, counters: DecodeCounters) -> list[Sample]:
    """The samples of row ``k`` of ``rows`` (EMPTY or None), each with its reason, counted (but for the frame)."""
    if rows[k] is EMPTY:  # a multiplexer page that carries none of the configured signals
        counters.decoded += 1
        return []
    reason, cells = rows.verdict(k)
    outputs = entry.outputs
    if reason in (INVALID_LENGTH, INVALID_PAYLOAD):
        counters.invalid += 1
        counters.reasons[reason] = counters.reasons.get(reason, 0) + len(outputs)
        return [Sample(o.source, o.role, _NAN, t, reason) for o in outputs]
    out: list[Sample] = []
    bad = False
    for j, value, why in cells:
        own = why if why in _SAMPLE_REASONS else ""
        if own:
            bad = True
            counters.reasons[own] = counters.reasons.get(own, 0) + 1
        out.append(_new(Sample, (outputs[j].source, outputs[j].role, value, t, own)))
    if bad:
        counters.invalid += 1
    else:
        counters.decoded += 1
    return out
