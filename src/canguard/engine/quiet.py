"""Quiet ticks: a grid tick proven to repeat the last one is counted, not run (replay; issue 16).

A replay of a long log spends most of its time ticking a tree that answers the same
thing 100 times a second: 20 guards at 100 Hz were half of a replay's process time.
BehaviorTree.CPP's answer would be "tick less"; ours must not change a single event,
frame or summary field. So a grid tick is skipped only when it is *proven* to be an
exact repetition of the last tick that ran, and the proof is made of three parts:

1. **The tree cannot tell two ticks apart.** Every node the tick reached is of a
   type that declares ``QUIET_RETICK`` (no timer, counter, memory or output of its
   own: the reactive and plain sequences and fallbacks, Inverter, ForceSuccess/Failure,
   AlwaysSuccess/Failure, ExecuteTask, the guards), carries no pre/post condition,
   reads no ``{key}`` and writes none but what its quiet re-tick writes again (an I²t
   guard's ``level``), and every guard's models are ``SAMPLE_DRIVEN`` (their
   state changes only at samples: threshold, hysteresis, and I²t, whose heat is
   integrated at samples). Nodes the tick did not reach may be anything (a
   PerformRecovery before ExecuteTask in a Sequence runs once, then is not reached
   while the task runs). No metrics, no tick hook.
2. **The last tick was a fixed point.** The tick that ran left every node with the
   status, feedback, position and SKIPPED flag the tick before it left, wrote no
   event, and left the task gate in the same state, with the same inhibits and the
   same cause, in a state whose release rule does not wait on time (running, or held
   by a failing tree or an inhibit). Ticking the same tree again on the same inputs
   then gives the same tick again.
3. **No input changed since.** Every sample that changes what a guard answers (a
   model's trip or recovery, a source's health reason) is an edge, and an edge ticks
   the tree at once for real (ending the quiet stretch); no event was written since
   (a bus error, a controller going error-passive...); and no time-driven change is
   due: each source's freshness deadline (its roles' latest sample + ``max_age``), the
   start windows (``no_data`` grace, the start grace), and the "guards left behind"
   deadline of a guard the fixed-point tick did not reach all lie after the tick (by
   a microsecond's margin against rounding).

A skipped tick still does what a tick does outside the tree: it is counted, it marks
the guards it would have ticked as ticked (``judged_t``), it samples the I²t levels
(their peak is taken at ticks), and it services the gate's periodic frames at its
own time. The live daemon ticks every tick (it has the time); ``tests/test_quiet_ticks.py``
replays random and example logs with and without quiet ticks and requires the same
summaries, events, frames out and engine state.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import py_trees

from canguard.engine.gate import LogSink, TaskGate
from canguard.engine.logrun import MAX_CATCH_UP_S

if TYPE_CHECKING:
    from canguard.bt.context import Context
    from canguard.engine.stats import EngineStats
    from canguard.io.clock import PinnedClock

MARGIN_S = 1e-6
"""A time-driven change is taken to come this much earlier than computed (rounding)."""


class QuietTickMixin:
    """The quiet-tick half of the engine (see the module docstring)."""

    if TYPE_CHECKING:  # what the engine provides
        ctx: Context
        clock: PinnedClock
        gate: TaskGate
        stats: EngineStats
        root: py_trees.behaviour.Behaviour
        metrics: Any
        tick_hook: Callable[[float], None] | None
        period_s: float
        _guard_nodes: list[Any]
        _started_at: float
        _start_grace_s: float
        _next_tick: float
        _due: float
        heat: Any
        save_heat: bool
        last_due_run: float

        def _flush(self) -> None: ...
        def _sample_levels(self) -> None: ...
        def _save_heat(self, now: float, periodic: bool) -> None: ...
        def _run_due(self, now: float) -> None: ...

    elide_ticks = False
    """On while a recorded log is fed (:meth:`~canguard.engine.logrun.LogRunMixin.run_log`).

    The live daemon ticks every tick: it has the time, and it is the reference the tests hold replay to.
    """
    replay_quiet_ticks = True
    """What :meth:`run_log` sets :attr:`elide_ticks` to (the differential tests turn it off for their reference)."""

    def _init_quiet(self) -> None:
        self.events_written = 0
        """Events written so far (a quiet stretch ends at any event)."""
        self._q_nodes: list[Any] = []
        """The tree's nodes (see :meth:`_quiet_tree`)."""
        self._q_loud: frozenset[Any] = frozenset()
        """The nodes that may not be re-ticked quietly: a tick that reaches one is no fixed point."""
        self._q_heard = False
        """The last tick reached one of :attr:`_q_loud`."""
        self._q_fixed = False
        """The last tick that ran was a fixed point reaching no loud node: until an edge, no tick changes a
        guard's status by itself (a settled block relies on it: :mod:`canguard.engine.settle`)."""
        self._q_state: tuple[Any, ...] | None = None
        """What the last tick that ran left (nodes, gate), to recognise a fixed point."""
        self._q_until = -math.inf
        """Grid ticks before this time may be skipped (set by a fixed-point tick)."""
        self._q_now = -math.inf
        """The time of the fixed-point tick that set :attr:`_q_until`."""
        self._q_timers = -math.inf
        """Its horizon but for the sources' staleness (start windows, guards left behind)."""
        self._q_events = -1
        self._q_gate: tuple[Any, ...] = ()
        self._q_ticked: list[Any] = []
        """The guards the fixed-point tick ticked: a skipped tick marks them ticked."""

    def _quiet_tree(self) -> tuple[list[Any], frozenset[Any]]:
        """Every node of the tree, and those that may not be re-ticked quietly (part 1 of the proof).

        A tick that reaches none of the latter may be a fixed point; one that reaches
        any is never one (a RunOnce, a Delay, an action sending frames at each tick).
        """
        nodes = list(self.root.iterate())
        return nodes, frozenset(node for node in nodes if not _quiet_node(node))

    def _quiet_check(self, now: float, events_before: int) -> None:
        """After a tick that ran: note whether it was a fixed point, and until when nothing can change."""
        self._q_until = -math.inf
        self._q_fixed = False
        nodes = self._q_nodes
        if self._q_heard or not self.elide_ticks or self.metrics is not None or self.tick_hook is not None:
            self._q_state = None
            return
        gate = self.gate
        state = (
            tuple((n.status, n.feedback_message, getattr(n, "index", 0), getattr(n, "skipped", False)) for n in nodes),
            gate.state, tuple(gate.inhibits.items()), gate._cause,
        )
        # Belt and braces: the quiet node types answer from their inputs alone, so one tick already
        # settles them; requiring a repeated state also covers a node whose declaration were wrong.
        fixed = state == self._q_state and self.events_written == events_before
        self._q_state = state
        if not fixed:
            return
        self._q_fixed = True
        failed = self.root.status == py_trees.common.Status.FAILURE
        if gate.state != TaskGate.RUNNING and not (failed or gate.inhibits):
            return  # the release rule may wait on time (min_stop) or on a reset
        self._q_until = self._quiet_horizon(now)
        self._q_events = self.events_written
        self._q_gate = (gate.state, dict(gate.inhibits))
        self._q_ticked = [g for g in self._guard_nodes if g.judged_t == now]

    def _quiet_horizon(self, now: float) -> float:
        """The earliest time after ``now`` at which time alone may change what a tick sees (part 3).

        Each deadline is taken when it is still ahead by the very test the engine makes
        (``now - t > max_age`` ...), and then as ``t + max_age``: when rounding puts that
        sum at or before ``now``, the horizon is in the past and the next tick runs.
        """
        self._q_now = now
        self._q_timers = self._timer_horizon(now)
        return min(self._health_horizon(now, None), self._q_timers) - MARGIN_S

    def _health_horizon(self, now: float, fresh: Mapping[int, Mapping[str, float]] | None) -> float:
        """When the first source signal not stale at ``now`` goes stale (``fresh``: later latest times, by
        ``id(health)`` and role)."""
        horizon = math.inf
        for health in self.ctx.health.values():
            max_age = health.max_age_s
            later = fresh.get(id(health)) if fresh else None
            for role, t in health._latest_t.items():
                if later is not None:
                    t = later.get(role, t)
                if not now - t > max_age and t + max_age < horizon:  # not stale yet: stale after t + max_age
                    horizon = t + max_age
        return horizon

    def _timer_horizon(self, now: float) -> float:
        """When a start window ends or a guard the tick at ``now`` left behind reads as such."""
        horizon = math.inf
        start = self._started_at
        windows = [source.max_age_s for source in self.ctx.sources.values()]  # each source's no_data grace
        windows.append(self._start_grace_s)  # the start window (Engine._starting)
        for width in windows:
            if now - start < width and start + width < horizon:
                horizon = start + width
        period = self.period_s
        for g in self._guard_nodes:
            if g.source is not None and g.judged_t < now:  # not reached by this tick: "left behind" later
                limit = max(g.source.max_age_s, period)
                if not now - g.judged_t > limit and g.judged_t + limit < horizon:
                    horizon = g.judged_t + limit
        return horizon

    def _block_horizon(self, fresh: Mapping[int, Mapping[str, float]]) -> float:
        """The quiet horizon of the last fixed point had the signals in ``fresh`` (by ``id(health)`` and role)
        been sampled last at those times, as a settled block's rows leave them (:mod:`canguard.engine.settle`);
        -inf when :meth:`_quiet_through` finds no horizon to extend."""
        if self._quiet_through() == -math.inf:
            return -math.inf
        return min(self._health_horizon(self._q_now, fresh), self._q_timers) - MARGIN_S

    def _quiet_tick(self, now: float) -> bool:
        """Count the grid tick at ``now`` instead of running it when it is proven quiet; False: run it."""
        if not (now < self._q_until and self.events_written == self._q_events):
            return False
        gate = self.gate
        state, inhibits = self._q_gate
        if gate.state != state or gate.inhibits != inhibits:
            return False
        self._count_quiet(now, 1)
        return True

    def _quiet_through(self) -> float:
        """Until when every tick is proven quiet, as a settled block of the stop confirmation's source needs
        (:mod:`canguard.engine.settle`): the last fixed point's horizon, while nothing it saw has changed (no
        event, the gate as it left it: :meth:`_quiet_tick`'s test) and no stop waits for its confirmation;
        -inf otherwise."""
        until = self._q_until
        gate = self.gate
        if until == -math.inf or self.events_written != self._q_events or gate._confirm_pending:
            return -math.inf
        state, inhibits = self._q_gate
        if gate.state != state or gate.inhibits != inhibits:
            return -math.inf
        return until

    def _quiet_advance(self, now: float) -> bool:
        """:meth:`advance` to ``now`` when all that is due up to it is one quiet grid tick; False: nothing done.

        The usual case between two rows of a replay whose tree sits at a fixed point: the
        tick at ``_next_tick`` is the only one due, the task runs and its next deadline is
        not before the tick nor between the tick and ``now`` (one at the tick is serviced
        by it). The steps are those of :meth:`advance`, :meth:`_run_due`, :meth:`_quiet_tick`
        and :meth:`_quiet_run` (which has nothing left to count), in their order, without
        their loop and tests: on a log of frames every millisecond, 25,000 ticks took 3.4 µs
        each that way.
        """
        nxt = self._next_tick
        gate = self.gate
        if not nxt <= now or self.events_written != self._q_events or gate.state != TaskGate.RUNNING:
            return False
        after = nxt + self.period_s
        task = gate._next_task
        if after <= now or task < nxt or nxt < task <= now or now - nxt > MAX_CATCH_UP_S:
            return False
        state, inhibits = self._q_gate
        if state != TaskGate.RUNNING or gate.inhibits != inhibits:
            return False
        self.clock.advance_to(nxt)
        self.last_due_run = nxt
        self._count_quiet(nxt, 1)
        self._next_tick = after
        if gate.next_deadline() <= now:  # the task serviced at the tick is due again already: the loop goes on
            self._run_due(now)
        self._due = min(self._next_tick, gate.next_deadline())
        self._flush()
        return True

    def _quiet_run(self, now: float, until: float) -> None:
        """After a quiet tick: the grid ticks due before ``until`` (and up to ``now``) counted in one go.

        Only while the task runs and no heat is saved: then between two ticks with no frame
        fed in between a quiet tick changes nothing but what the last of them leaves (the
        guards' tick times, the counts): ``gate.service`` has nothing due before ``until``
        (the gate's next deadline) and the heat levels move only with samples. Each tick
        time is still reached by the same additions as one by one.
        """
        gate = self.gate
        if gate.state != TaskGate.RUNNING or (self.heat is not None and self.save_heat):
            return
        sink = gate.sink
        counted = isinstance(sink, LogSink) and sink.out is None and not sink.keep
        nxt, period, last, count = self._next_tick, self.period_s, 0.0, 0
        # The task's periodic frames only counted (a replay without --emit): its deadlines among the
        # ticks change nothing a tick sees, and are sent in one go below; else they end the run.
        until = self._q_until if counted else min(until, self._q_until)
        while nxt <= now and nxt < until:
            last = nxt
            count += 1
            nxt += period
        if count:
            if counted:
                task, task_period, sends = gate._next_task, gate.task_cfg.period_s, 0
                while task <= last:  # as gate.service at each deadline (a tick at the same time goes first)
                    sends += 1
                    task += task_period
                if sends:
                    gate._next_task = task
                    assert isinstance(sink, LogSink)
                    sink.sent += sends * len(gate.task_cfg.frames)
            self.clock.advance_to(last)
            self.last_due_run = last
            self._next_tick = nxt
            self._count_quiet(last, count)

    def _count_quiet(self, now: float, count: int) -> None:
        """``count`` quiet grid ticks, the last at ``now``."""
        gate = self.gate
        self.clock.pin(now)
        try:
            self.stats.ticks += count
            self.stats.quiet_ticks += count
            self.last_tick_t = now
            for g in self._q_ticked:
                g.quiet_retick(now)
            self._sample_levels()  # I²t heat moved with the samples since: its peak is sampled at ticks
            gate.service(now)
            self._save_heat(now, periodic=True)
            self._flush()
            self._due = min(self._next_tick, gate.next_deadline())
        finally:
            self.clock.unpin()


def _quiet_node(node: Any) -> bool:
    """True when ``node`` may be re-ticked quietly: its type says so, no conditions, no ``{key}`` read, no
    output but those its quiet re-tick writes again, sample-driven models."""
    if not getattr(type(node), "QUIET_RETICK", False):
        return False
    if "tick" in vars(node) or "stop" in vars(node):  # pre/post conditions wrap the node's tick
        return False
    if getattr(node, "_dynamic", None) or not getattr(node, "_wired", frozenset()) <= getattr(
        type(node), "QUIET_OUTPUTS", frozenset()
    ):
        return False
    guarded = getattr(node, "guarded", None)
    return guarded is None or all(model.SAMPLE_DRIVEN for _, model, _ in guarded())
