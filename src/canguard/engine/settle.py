"""Settled blocks: a block whose configured rows change nothing a tick can see is taken whole (replay; issue 16).

Row by row, each configured row of a block updates its source's health and its
models (:meth:`MessagePlan.step <canguard.engine.blocks.MessagePlan.step>`), a few
microseconds each: on a log where every frame is configured, most of a replay. Yet
on most blocks nothing happens: no value crosses a threshold, no source goes stale
or comes back. Such a block is *settled*: every message's rows are taken at once
and the state is set to that of its last row, before the block's ticks run.

A block is settled only when, for every configured message in it:

- its rows all passed the column checks (no row for ``feed``: no NaN, range, length
  or multiplexer problem, no presence flag, no alive counter) and the block has no
  remote frame nor a message without a plan;
- no two of its rows, nor its first row and the source's previous sample, lie more
  than the source's ``max_age`` apart, and the source was usable before it (so its
  reason is "" at every instant of the block, whichever of its samples a tick sees);
- every model the rows feed declares, on the run's lowest and highest |value|, that
  the run trips or recovers nothing (:meth:`~canguard.protect.base.LatchedModel.settle`:
  threshold and hysteresis without inrush; others decline); a presence flag feeds no
  model: its rows all read 1 (a 0 goes to ``feed``), the source's other signals are in
  the same message (so fresh and valid at each row by the checks above), and the
  source's reason was "" at its last full look (``SourceHealth.observe``);
- no metrics count per frame;
- when its source is the stop confirmation's (which reads the value between ticks, while a
  stop waits for it): no confirmation is pending, and the block ends before the quiet
  horizon of the last fixed point, counted with the block's rows taken
  (:meth:`QuietTicks.block_horizon <canguard.engine.quiet.QuietTicks.block_horizon>`):
  no tick in it can stop the task and start one.

And the tick before the block was a fixed point reaching no loud node (the quiet
ticks' test, :mod:`canguard.engine.quiet`): every guard it reached reported its
model's state, no reported trip is waiting in a latch to be followed by its
recovery, and no timer node may lead the tree to a guard it did not reach.

Then no edge happens in the block, so it has no edge tick, and every tick in it
(each at its own time, as before) finds each guard's status, reason and feedback
as row by row: a guard changes only at an edge, or when time makes another source
stale (that guard words it with its own, unsettled, values), and then the tree
reaches fewer guards, never more. Only the settled models' latest values differ
before the block's end, and they are read only to word a change of their guard.
The random-log test found the case that needs the fixed point: a guard behind a
failing one keeps its trip latched; when the first recovers, the next ticks
report the second's trip and then its recovery, without an edge, worded with its
value at the tick. The differential
tests (``tests/test_replay_columns.py``, ``tests/test_replay_random_logs.py``,
``tests/test_quiet_ticks.py``) hold the result to the frame-by-frame engine.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping, Sequence
from typing import TYPE_CHECKING

from canguard.decode.rows import abs_range, has_empty, has_fed, keep_valued, last_row, max_gap

if TYPE_CHECKING:
    from canguard.engine.blocks import MessagePlan

Prepared = tuple["MessagePlan", Sequence[tuple[float, ...]], float, float]
"""(plan, row values, first time, last time) of a message whose rows may be settled."""


def may_settle(plan: MessagePlan, metrics: bool, tree_reads: Collection[str]) -> bool:
    """True when ``plan``'s rows may ever be settled (the static conditions of the module docstring).

    Each signal feeds a model, is a presence flag, or is read by no tree node (only by the stop
    confirmation: ``plan.confirm_read``, checked block by block).
    """
    if metrics or plan.counter or plan.passive:
        return False
    own = {role for _source, role, *_rest in plan.outputs}
    # a presence flag: the source's other signals are in the same message (as sources: configures them)
    return all((present and own.issuperset(health.value_roles)) or models or source not in tree_reads
               for source, _role, _signal, present, health, _lo, _hi, models in plan.outputs)


def prepare(plan: MessagePlan, stamps: Sequence[str], rows: Sequence[tuple[float, ...] | None]) -> Prepared | None:
    """The rows of one message in a block, checked for settling (nothing changed); None: go row by row."""
    if has_fed(rows):
        return None
    if has_empty(rows):  # multiplexer pages without a configured signal: counted, no sample
        stamps, rows = keep_valued(stamps, rows)
        if not rows:
            return None
    first, last = float(stamps[0]), float(stamps[-1])
    if last - first > plan.min_age and max_gap(stamps) > plan.min_age:  # else no gap can exceed it (float
        return None  # subtraction is monotonic)
    for _source, role, _signal, _present, health, _lo, _hi, _models in plan.outputs:
        if not health.fresh_valid(role, first):
            return None
    for health in plan.present_healths:
        if health.last_reason:  # the source's reason as its last full look found it (step's own test)
            return None
    return plan, rows, first, last  # type: ignore[return-value]  # no None left in rows


def settle(prepared: list[Prepared], end: float = math.inf,
           horizon: Callable[[Mapping[int, Mapping[str, float]]], float] | None = None) -> bool:
    """Take every prepared message's rows whole if every model agrees; False: nothing changed, go row by row.

    ``end``: the block's last time; ``horizon``: :meth:`QuietTicks.block_horizon
    <canguard.engine.quiet.QuietTicks.block_horizon>`, which a block feeding the stop
    confirmation's source must end before.
    """
    if any(plan.confirm_read for plan, *_rest in prepared):
        fresh: dict[int, dict[str, float]] = {}
        for plan, _rows, _first, last in prepared:
            for _source, role, _signal, _present, health, *_rest in plan.outputs:
                fresh.setdefault(id(health), {})[role] = last
        if horizon is None or not end < horizon(fresh):
            return False
    runs: list[list[float]] = []
    for plan, rows, first, _last in prepared:
        highs = []
        for j, (*_head, models) in enumerate(plan.outputs):
            low, high = abs_range(rows, j)
            if not all(model.settles(low, high, first) for model in models):
                return False
            highs.append(high)
        runs.append(highs)
    for (plan, rows, _first, last_t), highs in zip(prepared, runs, strict=True):
        final = last_row(rows)
        tops = plan.tops
        for j, (_source, role, _signal, _present, health, _lo, _hi, models) in enumerate(plan.outputs):
            for model in models:
                model.take_run(final[j], last_t)
            health.take(role, last_t, final[j])
            health.samples += len(rows)
            if highs[j] > tops[j]:
                tops[j] = highs[j]
        plan.seen += len(rows)
    return True
