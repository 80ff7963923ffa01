"""Quiet ticks: a grid tick proven to repeat the last one is counted, not run (live and in replay).

A grid tick is skipped only when it is *proven* an exact repetition of the last tick that ran, so that
no event, frame or summary field changes:

1. **The tree cannot tell two ticks apart.** Every node the tick reached declares ``QUIET_RETICK`` (no
   timer, counter, memory or output of its own), carries no pre/post condition, reads no ``{key}`` and
   writes none but what its quiet re-tick writes again (an I²t guard's ``level``); a guard's models change
   state only at samples (:mod:`canguard.protect.base`). No metrics, no tick hook.
2. **The last tick was a fixed point.** It left every node's status, feedback, position and SKIPPED flag
   as the tick before it did, wrote no event, and left the gate's state, inhibits and cause unchanged, in
   a state whose release rule does not wait on time (running, or held by a failing tree or an inhibit).
3. **No input changed since.** A sample that changes what a guard answers is an edge, which ticks the
   tree for real; no event was written since; and every time-driven change (a source's freshness
   deadline, the start windows, a guard's "left behind" deadline) lies after the tick, by a
   microsecond's margin. Samples taken since, and a block's rows still to come
   (:meth:`QuietTicks.reach`), move the freshness deadlines on.

A skipped tick is still counted, marks the guards it would have ticked (``judged_t``), writes an I²t
guard's ``level`` again and services the gate at its own time: the daemon and a replay count the same ticks.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Protocol

import py_trees

from canguard.bt.wakeup import tick_once
from canguard.engine.gate import TaskGate

if TYPE_CHECKING:
    from canguard.bt.context import Context
    from canguard.engine.stats import Journal

MARGIN_S = 1e-6
"""A time-driven change is taken to come this much earlier than computed (rounding)."""


class Watched(Protocol):
    """What :class:`QuietTicks` reads of the engine (:class:`canguard.engine.core.Engine` is one)."""

    guard_nodes: list[Any]
    started_at: float
    start_grace_s: float
    period_s: float


class QuietTicks:
    """The proof that a grid tick repeats the last one, kept tick by tick (see the module docstring)."""

    def __init__(self, root: py_trees.behaviour.Behaviour, ctx: Context, gate: TaskGate, journal: Journal,
                 engine: Watched) -> None:
        self.root = root
        self.ctx = ctx
        self.gate = gate
        self.journal = journal
        self.engine = engine
        self.nodes = list(root.iterate())
        # the nodes a tick may not reach to be a fixed point (part 1), and whether the last tick reached one
        self.loud = frozenset(node for node in self.nodes if not _quiet_node(node))
        self._heard = False
        self._state: tuple[Any, ...] | None = None  # what the last tick that ran left (nodes, gate)
        self.until = -math.inf  # grid ticks before this time may be skipped
        self._events = -1
        self._gate: tuple[Any, ...] = ()
        self.ticked: list[Any] = []  # the guards the fixed point ticked: a skipped tick marks them ticked
        self._fresh: list[tuple[Any, str]] | None = None  # (health, role) fresh at the fixed point (None: none)
        self._timers = math.inf  # :meth:`_timer_horizon`
        # the guards whose quiet re-tick writes an output (an I²t guard's wired ``level``)
        self._writers = frozenset(g for g in engine.guard_nodes
                                  if any(map(g.is_wired, getattr(type(g), "QUIET_OUTPUTS", ()))))
        # a skipped tick writes the blackboard: the samples between two ticks must be taken before each
        self.writes = False

    def tick_root(self, loaded: Any) -> py_trees.common.Status:
        """Tick the tree as BT.CPP's ``tickOnce()``, noting whether the tick reached a loud node; the root's status."""
        ticked = tick_once(loaded, collect=bool(self.loud))
        if ticked.reached is not None:
            self._heard = not self.loud.isdisjoint(ticked.reached)
        return ticked.status

    def after_tick(self, now: float, events_before: int, watched: bool) -> None:
        """After a tick that ran: note whether it was a fixed point, and until when nothing can change
        (``watched``: metrics or a tick hook look at every tick: none may be skipped)."""
        self.until = -math.inf
        self._fresh = None
        if self._heard or watched:
            self._state = None
            return
        gate = self.gate
        state = (
            tuple((n.status, n.feedback_message, getattr(n, "index", 0), getattr(n, "skipped", False))
                  for n in self.nodes),
            gate.state, tuple(gate.inhibits.items()), gate.cause,
        )
        # Belt and braces: a repeated state also covers a node whose QUIET_RETICK declaration were wrong.
        fixed = state == self._state and self.journal.written == events_before
        self._state = state
        if not fixed:
            return
        failed = self.root.status == py_trees.common.Status.FAILURE
        if gate.state != TaskGate.RUNNING and not (failed or gate.inhibits):
            return  # the release rule may wait on time (min_stop) or on a reset
        self._fresh = [(health, role) for health in self.ctx.health.values()
                       for role, t in health.latest_times().items() if not now - t > health.max_age_s]
        self._timers = self._timer_horizon(now)
        self.until = self._horizon()
        self._events = self.journal.written
        self._gate = (gate.state, dict(gate.inhibits))
        self.ticked = [g for g in self.engine.guard_nodes if g.judged_t == now]
        self.writes = not self._writers.isdisjoint(self.ticked)

    def _horizon(self) -> float:
        """The earliest time after the fixed point at which time alone may change what a tick sees (part 3): a
        fresh signal goes stale, a timer ends (a stale signal changes only with a sample, an edge)."""
        horizon = self._timers
        assert self._fresh is not None
        for health, role in self._fresh:
            t = health.latest_t(role)
            assert t is not None  # fresh at the fixed point: it has a sample
            if t + health.max_age_s < horizon:
                horizon = t + health.max_age_s
        return horizon - MARGIN_S

    def reach(self, coming: Mapping[tuple[int, str], Any]) -> float:
        """:meth:`_horizon` with the rows a block still holds (``coming``: their times by (``id`` of a health, role)):
        a fresh signal stays fresh through them up to the first gap over ``max_age``. -inf: no fixed point."""
        if self._fresh is None:
            return -math.inf
        horizon = self._timers
        gaps: dict[tuple[int, float], int] = {}  # by a times column (a message's rows) and max_age: its first gap
        for health, role in self._fresh:
            last = health.latest_t(role)
            assert last is not None  # fresh at the fixed point: it has a sample
            max_age = health.max_age_s
            times = coming.get((id(health), role))
            if times is not None and len(times) and not times[0] - last > max_age:
                k = gaps.get((id(times), max_age))
                if k is None:
                    k = gaps[id(times), max_age] = _first_gap(times, max_age)
                last = float(times[k - 1])
            if last + max_age < horizon:
                horizon = last + max_age
        return horizon - MARGIN_S

    def _timer_horizon(self, now: float) -> float:
        """When a start window ends or a guard the tick at ``now`` left behind reads as such."""
        horizon = math.inf
        start = self.engine.started_at
        windows = [source.max_age_s for source in self.ctx.sources.values()]  # each source's no_data grace
        windows.append(self.engine.start_grace_s)  # the start window (Engine.starting)
        for width in windows:
            if now - start < width and start + width < horizon:
                horizon = start + width
        period = self.engine.period_s
        for g in self.engine.guard_nodes:
            if g.source is not None and g.judged_t < now:  # not reached by this tick: "left behind" later
                limit = max(g.source.max_age_s, period)
                if not now - g.judged_t > limit and g.judged_t + limit < horizon:
                    horizon = g.judged_t + limit
        return horizon

    def unchanged(self) -> bool:
        """Nothing the last fixed point saw has changed: no event since, the gate as it left it."""
        if self.journal.written != self._events:
            return False
        state, inhibits = self._gate
        return self.gate.state == state and self.gate.inhibits == inhibits

    def may_skip(self, now: float) -> bool:
        """The grid tick at ``now`` is proven quiet: count it instead of running it (at the horizon, the samples
        taken since the fixed point may have moved it on: it is drawn again)."""
        if not now < self.until:
            if self._fresh is None:
                return False
            self.until = self._horizon()
        return now < self.until and self.unchanged()


def _quiet_node(node: Any) -> bool:
    """True when ``node`` may be re-ticked quietly: its type says so, no conditions, no ``{key}`` read, no
    output but those its quiet re-tick writes again."""
    if not getattr(type(node), "QUIET_RETICK", False):
        return False
    if "tick" in vars(node) or "stop" in vars(node):  # pre/post conditions wrap the node's tick
        return False
    wired = getattr(node, "is_wired", None)  # a canguard node: which ports the XML wired to the blackboard
    if wired is not None:
        if any(map(wired, node.input_ports())):
            return False
        quiet_outputs: frozenset[str] = getattr(type(node), "QUIET_OUTPUTS", frozenset())
        if not {port for port in node.output_ports() if wired(port)} <= quiet_outputs:
            return False
    return True


def _first_gap(times: Any, max_age: float) -> int:
    """The position after which the first step of ``times`` longer than ``max_age`` comes (their length: none)."""
    if not float(times[-1]) - float(times[0]) > max_age:  # no step is longer than all of them (rounding is monotone)
        return len(times)
    import numpy as np

    times = np.asarray(times)
    over = np.flatnonzero(times[1:] - times[:-1] > max_age)
    return int(over[0]) + 1 if over.size else len(times)
