"""The configured rows of a replayed candump block, decoded as columns (the replay hot path).

:meth:`Engine.run_log <canguard.engine.core.Engine.run_log>` works on plain candump
blocks (:class:`~canguard.io.logs.Columns`). The rows of each configured message in
a block are decoded and checked together (NaN, inf, the DBC range, the presence
flag, the multiplexer page) by the message's
:class:`~canguard.decode.message.MessageDecoder`, the same object that decodes a
live frame. What is left per row is what only the order of samples can decide:
:meth:`MessagePlan.step` does, for a row whose values all passed, exactly what
:meth:`Engine.feed <canguard.engine.core.Engine.feed>` does after its tick check —
:meth:`SourceHealth.observe <canguard.protect.staleness.SourceHealth.observe>`'s
fast path, the subscribed protection models, the per-source sample counts and
largest values — with the counters kept in the plan and added to the engine's at
:meth:`MessagePlan.flush`.

A row the columns cannot take (a wrong length, a payload cantools refuses, an
invalid value, a source coming back after a stale spell, a presence flag that may
change the source's reason) goes to ``feed`` as a frame *before anything was
changed*: the two paths leave the same state, which ``tests/test_replay_columns.py``
checks byte for byte on every block size. No code is generated.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from typing import TYPE_CHECKING, Any

from canguard.decode.rows import Row, abs_range, clean, last_row, max_gap, placed
from canguard.io.logtypes import joined_hex
from canguard.protect.staleness import ROW_ROLES

if TYPE_CHECKING:
    from canguard.bt.context import Context
    from canguard.decode.decoder import DecodeCounters
    from canguard.decode.message import MessageDecoder
    from canguard.engine.stats import EngineStats
    from canguard.io.candump import Columns
    from canguard.io.candump_np import ByteColumns


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
        self.hex_size = 2 * self.length
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
        self.single = len(self.outputs) == 1 and not self.outputs[0][3]
        self.counter = any(role in ROW_ROLES for _src, role, *_rest in self.outputs)
        """An alive counter or a drive's health role: every row goes to feed (SourceHealth.observe's full check)."""
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
        if self.single:
            self.step = self._single_step()  # type: ignore[method-assign,assignment]

    # -- the columns -------------------------------------------------------------------
    def cuts_payloads(self, rows: Any) -> bool:
        """A numpy block's ``rows`` of this message are decoded from their payloads joined (:meth:`decode` asks
        ``ByteColumns.payload`` for them, which :func:`canguard.engine.blockrows.decode_rows` may do for several
        messages at once); False: from the bytes of its signals alone (or not at all)."""
        return not self.counter and not self.entry.reads_fields(len(rows))

    def decode(self, cols: Columns | ByteColumns, rows: Any,
               payload: tuple[list[int] | None, bytes] | None = None) -> Sequence[Row]:
        """Each of ``rows``' configured values (in output order), ``EMPTY``, or None: the row goes to ``feed``.

        The rows :meth:`MessageDecoder.decode <canguard.decode.message.MessageDecoder.decode>`
        gives (None: a wrong length, a payload cantools would refuse, a value NaN, infinite
        or outside the DBC range, a presence flag at 0, some configured signals of a
        multiplexed message but not all); every row when the message carries an alive counter
        or a drive's health role. ``payload``: what ``cols.payload(rows, size)`` gives, when
        already cut (:meth:`cuts_payloads`).
        """
        n = len(rows)
        if self.counter:
            return [None] * n
        size = self.hex_size
        good: list[int] | None
        data: Any
        if payload is not None:
            good, data = payload
        elif not isinstance(cols, tuple):  # ByteColumns (numpy, imported only with it): straight from the bytes
            if self.cuts_payloads(rows):
                good, data = cols.payload(rows, size)
            else:
                assert self.entry.spans is not None
                good, data = cols.byte_fields(rows, size, self.entry.spans)
        else:
            good, data = joined_hex(list(map(cols.data.__getitem__, rows)), size)
        count = n if good is None else len(good)
        if not count:
            return [None] * n
        return placed(n, good, self.entry.decode(data, count))

    # -- one row -----------------------------------------------------------------------
    def step(self, values: tuple[float, ...], t: float) -> bool | None:
        """Take one row's checked values at ``t``: True on an edge, False, or None (changed nothing: feed it).

        Replaced per instance by a closure over the one output when the message has one
        (most messages): the same steps with the lookups done once.
        """
        outputs = self.outputs
        for _source, role, _signal, present, health, _lo, _hi, _models in outputs:
            if not health.fresh_valid(role, t) or (present and not health.settled(t)):
                return None
        self.seen += 1
        edge = False
        tops = self.tops
        for j, (_source, role, _signal, _present, health, _lo, _hi, models) in enumerate(outputs):
            v = values[j]
            health.take(role, t, v)
            a = -v if v < 0.0 else v
            if a > tops[j]:
                tops[j] = a
            for model in models:
                if model.update(v, t):
                    edge = True
        return edge

    def _single_step(self) -> Callable[[tuple[float, ...], float], bool | None]:
        """:meth:`step` of a message with one configured (non-presence) signal."""
        _source, role, _signal, _present, health, _lo, _hi, models = self.outputs[0]
        fresh, take = health.fresh_valid, health.take
        tops = self.tops
        plan = self

        def step(values: tuple[float, ...], t: float) -> bool | None:
            if not fresh(role, t):
                return None
            v = values[0]
            take(role, t, v)
            plan.seen += 1
            a = -v if v < 0.0 else v
            if a > tops[0]:
                tops[0] = a
            edge = False
            for model in models:
                if model.update(v, t):
                    edge = True
            return edge

        return step

    def count_empty(self, rows: int) -> None:
        """``rows`` decoded rows that carried none of the configured signals (counted at :meth:`flush`)."""
        self.empty += rows

    def flush(self) -> None:
        """Add the rows taken since the last flush to the decoder's and the engine's counters."""
        rows = self.seen + self.empty
        if rows:
            self.counters.frames += rows
            self.counters.decoded += rows
            self.stats.frames += rows
        if self.seen:
            for j, (source, role, _signal, _present, health, _lo, _hi, _models) in enumerate(self.outputs):
                _count_samples(self.stats, health, source, role, self.seen, self.tops[j])
                self.tops[j] = -1.0
        self.seen = self.empty = 0

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
        if not self.passive or not clean(rows):  # a row to feed (None) or without a sample (EMPTY)
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
