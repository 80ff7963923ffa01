"""A configured message on one bus: its rows decoded as columns, and its row step (live and replay).

A block of frames (:meth:`Engine.take <canguard.engine.core.Engine.take>`: a live bus's
queue drained, or a log's block) reaches the engine's block runner
(:class:`~canguard.engine.logrun.LogRun`). In a block (:class:`~canguard.io.block.Block`) the rows of each
configured message are
decoded together (:meth:`MessagePlan.decode`: the message's :class:`~canguard.decode.message.MessageDecoder`,
the same object that decodes a live frame; checked together: NaN, inf, the DBC range, the
multiplexer, presence flags).

Then each row, in time order, takes the message's **row step**, the one way a frame's
samples change anything: :meth:`MessagePlan.step` for a row the column decoder read whole,
:meth:`MessagePlan.take_samples` for a row the frame decoder
(:meth:`Decoder.decode <canguard.decode.decoder.Decoder.decode>`) read: a frame of a
frame-list block (live, a block of one on a quiet bus), or a row the column decoder leaves to
it (a wrong length, a payload cantools refuses, an invalid value with its reason, a presence
flag at 0, a multiplexer page with part of the signals, an alive counter or a drive's health
roles, a remote frame). Both hand each sample to its source role's
:class:`~canguard.bt.context.SampleRoute` (the source's health, then its protection models)
and count it; the counts reach the decoder's and the engine's counters at :meth:`MessagePlan.flush`.

A message nobody reads between ticks may take a block's rows whole (:meth:`MessagePlan.batch`),
and a block that changes nothing a tick sees is taken whole (:mod:`canguard.engine.settle`).
No code is generated.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from typing import TYPE_CHECKING, Any

from canguard.decode.decoder import row_samples
from canguard.decode.rows import Row, abs_range, clean, last_row, max_gap
from canguard.protect.staleness import ROW_ROLES

if TYPE_CHECKING:
    from canguard.bt.context import Context
    from canguard.decode.decoder import DecodeCounters
    from canguard.decode.message import MessageDecoder
    from canguard.engine.stats import EngineStats
    from canguard.io.block import Block
    from canguard.io.frame import Sample


_BIG = 1.7976931348623157e308
"""The largest float: the default range bounds, so that +-inf fails the range check like NaN does."""


class MessagePlan:
    """One configured message on one bus: its column decode, its per-row step, its whole-block batch."""

    def __init__(self, entry: MessageDecoder, counters: DecodeCounters, ctx: Context, stats: EngineStats,
                 readers: Collection[str] | None) -> None:
        self.entry = entry
        self.counters = counters
        self.stats = stats
        message = entry.message
        self.message = message
        self.length = int(message.length)
        self.frame_id = int(message.frame_id)
        self.outputs: list[tuple[str, str, str, bool, Any, float, float, tuple[Any, ...]]] = []
        """(source, role, signal, present, health, lo, hi, models) of each configured signal."""
        for out in entry.outputs:
            health = ctx.health[out.source]
            lo, hi = health.ranges.get(out.role, (None, None))
            self.outputs.append((out.source, out.role, out.signal, out.present, health,
                                 -_BIG if lo is None else float(lo), _BIG if hi is None else float(hi),
                                 tuple(ctx.subscribers(out.source, out.role))))
        self.names = [(o[0], o[1]) for o in self.outputs]
        """(source, role) of each output: the samples a decoded row gives, in order."""
        self.keys = tuple((source, (source, role)) for source, role in self.names)
        """(source, (source, role)) of each output: where :meth:`flush` counts it."""
        self.single = len(self.outputs) == 1
        self.counter = any(role in ROW_ROLES for _src, role, *_rest in self.outputs)
        """An alive counter or a drive's health role: every row goes to the frame decoder (its journal events)."""
        self.passive = not self.counter and readers is not None and all(
            not present and source not in readers and not models
            for source, _r, _s, present, _h, _lo, _hi, models in self.outputs
        )
        """Nobody looks at this message between ticks: a block's rows may be taken whole (:meth:`batch`)."""
        self.min_age = min(o[4].max_age_s for o in self.outputs)
        self.seen = 0
        self.empty = 0
        self.settle_ok = False
        """Its rows may be taken a block at a time (:func:`canguard.engine.settle.may_settle`, set by the engine)."""
        self.confirm_read = False
        """It feeds the stop confirmation's source (set by the engine): it settles only while no tick can stop."""
        self.present_healths = tuple(o[4] for o in self.outputs if o[3])
        """The health of each source whose presence flag it carries."""
        self.tops = [-1.0] * len(self.outputs)
        """The largest |value| of each output's valid samples since the last :meth:`flush`."""
        self.sampled = [0] * len(self.outputs)
        """Each output's samples taken through :meth:`take_samples` since the last :meth:`flush`."""
        self.routes = tuple(ctx.route(source, role) for source, role, *_rest in self.outputs)
        """Each output's sample step (the same objects :meth:`Context.dispatch` uses)."""
        self.index = {(source, role): j for j, (source, role, *_rest) in enumerate(self.outputs)}
        """Each output's index by (source, role): where a decoded sample goes."""
        if self.single:
            self.step = self._single_step()  # type: ignore[method-assign,assignment]

    # -- the columns -------------------------------------------------------------------
    def decode(self, block: Block, rows: Any) -> Sequence[Row]:
        """Each of ``rows``' configured values (in output order), ``EMPTY``, or None: the row goes to the frame decoder.

        The rows :meth:`MessageDecoder.decode <canguard.decode.message.MessageDecoder.decode>`
        gives over ``rows``' payloads and lengths (None: a wrong length, a payload cantools would
        refuse, a value NaN, infinite or outside the DBC range, a presence flag at 0, some
        configured signals of a multiplexed message but not all); every row when the message
        carries an alive counter or a drive's health role.
        """
        if self.counter:
            return [None] * len(rows)
        return self.entry.decode(block.payload[rows], block.length[rows])

    # -- one row: the row step (every frame of this message, live or replayed, takes it) -------
    def step(self, values: tuple[float, ...], t: float) -> bool:
        """Take one row the column decoder found whole and valid (one value per output) at ``t``; True on an edge.

        Each value takes its source role's step (:meth:`SampleRoute.take
        <canguard.bt.context.SampleRoute.take>`: the source's health, then its models), as
        :meth:`take_samples` does for a row the frame decoder decoded. Replaced per instance
        by a closure over the one output when the message has one (most messages).
        """
        self.seen += 1
        edge = False
        tops = self.tops
        for j, route in enumerate(self.routes):
            v = values[j]
            if route.take(v, t):
                edge = True
            a = -v if v < 0.0 else v
            if a > tops[j]:
                tops[j] = a
        return edge

    def _single_step(self) -> Callable[[tuple[float, ...], float], bool]:
        """:meth:`step` of a message with one configured signal, the lookups done once."""
        take = self.routes[0].take
        tops = self.tops
        plan = self

        def step(values: tuple[float, ...], t: float) -> bool:
            plan.seen += 1
            v = values[0]
            a = -v if v < 0.0 else v
            if a > tops[0]:
                tops[0] = a
            return take(v, t)

        return step

    def take_payload(self, data: bytes, t: float) -> bool | None:
        """One frame's payload at ``t`` (a block of one through the message's kernel); True on an edge.

        A whole and valid row takes :meth:`step`; any other row its samples with their reasons
        (:func:`~canguard.decode.decoder.row_samples`, counted here as the frame decoder counts them),
        :meth:`take_samples`. None: nothing taken, the frame decoder must take the frame (a message whose
        every row goes to it: :attr:`counter`).
        """
        if self.counter:
            return None
        entry = self.entry
        rows = entry.decode(*entry.one(data))
        row = rows[0]
        if row:
            return self.step(row, t)
        self.stats.frames += 1
        self.counters.frames += 1
        return self.take_samples(row_samples(entry, rows, 0, t, self.counters))

    def take_samples(self, samples: Sequence[Sample]) -> bool:
        """Take the samples the frame decoder made of one frame of this message (any reason, any subset of
        the outputs, in output order); True on an edge. Counted here; the frame itself by the decoder."""
        edge = False
        index = self.index
        for sample in samples:
            j = index[sample.source, sample.signal]
            reason = sample.reason
            v = sample.value
            if self.routes[j].take(v, sample.t, reason):
                edge = True
            self.sampled[j] += 1
            if not reason:
                a = -v if v < 0.0 else v
                if a > self.tops[j]:
                    self.tops[j] = a
        return edge

    def count_empty(self, rows: int) -> None:
        """``rows`` decoded rows that carried none of the configured signals (counted at :meth:`flush`)."""
        self.empty += rows

    def flush(self) -> None:
        """Add the rows and samples taken since the last flush to the decoder's and the engine's counters."""
        seen = self.seen
        rows = seen + self.empty
        if rows:
            counters = self.counters
            counters.frames += rows
            counters.decoded += rows
            self.stats.frames += rows
            self.seen = self.empty = 0
        elif not any(self.sampled):
            return  # nothing taken since the last flush (most plans, most blocks)
        sampled, tops = self.sampled, self.tops
        stats = self.stats
        max_abs, counts = stats.max_abs, stats.samples
        for j, (source, key) in enumerate(self.keys):
            n = seen + sampled[j]
            if n:
                counts[source] = counts.get(source, 0) + n
                top = tops[j]
                if top > max_abs.get(key, -1.0):
                    max_abs[key] = top
                tops[j] = -1.0
                sampled[j] = 0

    # -- a whole block -----------------------------------------------------------------
    def batch(self, stamps: Sequence[str], rows: Sequence[tuple[float, ...] | None]) -> bool:
        """Take a block's rows of a :attr:`passive` message whole; False (nothing changed): go row by row.

        Such a message feeds only sources no tree node reads, no protection model and no
        presence signal: what it changes is seen only through its sources' reasons at
        ticks (``stale`` / ``fresh`` events) and through counters. When every row passed
        the column checks and no two rows (nor the first row and the previous sample) lie
        more than ``max_age`` apart, every reason at every tick in the block is "" and
        the state at the end of the block is that of its last row: it is stored at once
        (before the block's ticks, which then read "fresh" as they would have).
        """
        if not self.passive or not clean(rows):  # a row for the frame decoder (None) or without a sample (EMPTY)
            return False
        first, last = float(stamps[0]), float(stamps[-1])
        gap = last - first
        if gap > self.min_age:  # else no gap can exceed it (float subtraction is monotonic)
            gap = max_gap(stamps)
        for _source, role, _signal, _present, health, _lo, _hi, _models in self.outputs:
            if not health.fresh_valid(role, first) or gap > health.max_age_s:
                return False
        count = len(rows)
        self.counters.frames += count
        self.counters.decoded += count
        self.stats.frames += count
        tops = [abs_range(rows, j)[1] for j in range(len(self.outputs))]
        final = last_row(rows)
        for j, (source, role, _signal, _present, health, _lo, _hi, _models) in enumerate(self.outputs):
            health.take(role, last, final[j])
            _count_samples(self.stats, health, source, role, count, tops[j])
        return True


def _count_samples(stats: EngineStats, health: Any, source: str, role: str, rows: int, top: float) -> None:
    """Count ``rows`` samples of one signal, with the largest |value| among them."""
    stats.samples[source] = stats.samples.get(source, 0) + rows
    health.samples += rows
    key = (source, role)
    if top > stats.max_abs.get(key, -1.0):
        stats.max_abs[key] = top


def compile_plan(entry: MessageDecoder, counters: DecodeCounters, ctx: Context, stats: EngineStats,
                 readers: Collection[str] | None) -> MessagePlan | None:
    """The :class:`MessagePlan` of ``entry``'s frames, or None when a source of it is not in the tree's context.

    ``readers``: the sources read between ticks (tree nodes, the stop confirmation);
    None keeps every message off the whole-block path (the metrics count per frame).
    """
    if any(out.source not in ctx.health for out in entry.outputs) or not entry.outputs:
        return None
    return MessagePlan(entry, counters, ctx, stats, readers)
