"""What the engine publishes once per tick: an immutable snapshot, built from public accessors.

:class:`Observer` (the engine's ``observer``) takes one when something changed (a node's status, the task's state,
an event), at most every :data:`PERIOD_S`, with the guards' values at most every :data:`GUARD_PERIOD_S`: the
monitors' cost to the loop is bounded however fast the tree ticks.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import py_trees

from canguard.bt.dryrun import root_blackboard

if TYPE_CHECKING:
    from canguard.bt.loaded import GuardView
    from canguard.engine.core import Engine
    from canguard.service.monitor.layout import LayoutRecord, TreeLayout

log = logging.getLogger(__name__)


class SnapshotSink(Protocol):
    """Where snapshots go (:class:`canguard.service.monitor.Monitor`): never blocks the engine's thread."""

    def blackboard_wanted(self) -> bool: ...

    def put(self, snapshot: TickSnapshot) -> None: ...

    def flush(self) -> None: ...

PERIOD_S = 0.02
"""Shortest time between two snapshots: a change is published in the first tick this long after the last one
(Groot2 polls STATUS at up to 50 Hz; the page draws at most 10 times a second)."""
GUARD_PERIOD_S = 0.08
"""Longest time between two snapshots of the guards' values while nothing else changes."""

IDLE, RUNNING, SUCCESS, FAILURE, SKIPPED = 0, 1, 2, 3, 4
"""BehaviorTree.CPP's ``NodeStatus`` values (Groot2's STATUS carries them; ``10 + s``: idle after ``s``)."""
STATUS_NAMES = ("IDLE", "RUNNING", "SUCCESS", "FAILURE", "SKIPPED")
_CODES = {py_trees.common.Status.RUNNING: RUNNING, py_trees.common.Status.SUCCESS: SUCCESS,
          py_trees.common.Status.FAILURE: FAILURE}


def status_name(code: int) -> str:
    """``SUCCESS``, ``IDLE``... for a status code (an idle-after code reads ``IDLE``)."""
    return STATUS_NAMES[code] if 0 <= code < len(STATUS_NAMES) else "IDLE"


class GuardState(NamedTuple):
    """One guarded signal at one tick: the fields of ``/api/status``'s ``guards`` (docs/monitor.md)."""

    name: str
    role: str
    kind: str
    source: str
    value: float
    unit: str
    threshold: float
    heat_pct: float
    status: str
    reason: str


class TaskState(NamedTuple):
    """The task gate at one tick (a plain tuple to the monitor process, as :class:`GuardState`)."""

    state: str
    since: float | None
    """When the running stop began (engine time), None when not stopped."""
    reason: str
    stops: int
    holding: tuple[tuple[str, str], ...]
    """What holds the task besides the tree (a stale source, a bus down, an overrun): (key, reason)."""
    failing: tuple[str, ...]
    """The guard nodes that failed in this tick."""
    stopped_by: tuple[str, ...]
    """The guard nodes that had failed in the tick the running stop began."""


@dataclass(frozen=True)
class TickSnapshot:
    """Everything the monitors show of one tick; never changed once published."""

    seq: int
    t: float
    layout: LayoutRecord
    codes: tuple[int, ...]
    """Per UID (``codes[uid - 1]``), BT.CPP's status code."""
    task: TaskState
    guards: tuple[GuardState, ...]
    confirm: bool
    """``stop.confirm`` is configured (a stop then waits for its confirmation)."""
    blackboard: dict[str, Any] | None
    """The root blackboard's entries, when a monitor asked for them lately."""


class Observer:
    """The engine's per-tick publication point for the monitors (one per engine: a reload attaches a new one)."""

    def __init__(self, engine: Engine, layout: TreeLayout, hub: SnapshotSink) -> None:
        self.layout = layout
        self.hub = hub
        self._guards = engine.guards()
        self._guard_nodes = engine.loaded.guard_nodes()
        self._last_active = [IDLE] * len(layout.behaviours)
        self._seq = 0
        self._key: tuple[Any, ...] = ()
        self._guard_states: tuple[GuardState, ...] = ()
        self._guards_at = -math.inf
        self._next_at = -math.inf
        self._stops = -1
        self._stopped_by: tuple[str, ...] = ()
        self._failed = False

    def publish(self, engine: Engine, now: float) -> None:
        """Called by the engine after each tick: publish this tick's snapshot (never raises, never waits)."""
        try:
            self._publish(engine, now)
        except Exception:  # a monitor must never take the loop down with it
            if not self._failed:
                log.exception("monitor snapshot failed; the monitors show the last good one")
            self._failed = True

    def _publish(self, engine: Engine, now: float) -> None:
        gate = engine.gate
        if gate.stops != self._stops:  # read in the tick the stop began, however soon the next snapshot is due
            self._stops = gate.stops
            self._stopped_by = self._failing()
        mono = time.monotonic()
        if mono < self._next_at:  # the one bound on what the monitors cost the loop, however fast it ticks
            return
        codes = self._codes()
        failing = self._failing()
        key = (codes, gate.state, gate.stops, engine.journal.written, gate.stop_reason)
        stale = mono - self._guards_at >= GUARD_PERIOD_S
        if key == self._key and not stale:
            self.hub.flush()  # what the monitor process could not take before goes now
            return
        if stale:  # a node's status or an event in between: published at once, with the guards as last read
            self._guard_states = tuple(self._guard_state(engine, g, now) for g in self._guards)
            self._guards_at = mono
        self._next_at = mono + PERIOD_S
        self._key = key
        self._seq += 1
        task = TaskState(gate.state, gate.stop_since, gate.stop_reason, gate.stops, tuple(gate.inhibits.items()),
                         failing, self._stopped_by)
        blackboard = root_blackboard() if self.hub.blackboard_wanted() else None
        self.hub.put(TickSnapshot(self._seq, now, self.layout.record, codes, task, self._guard_states,
                                  engine.cfg.stop.confirm is not None, blackboard))

    def _failing(self) -> tuple[str, ...]:
        """The guard nodes that failed in the tick just done."""
        return tuple(g.name for g in self._guard_nodes if g.status == py_trees.common.Status.FAILURE)

    def _codes(self) -> tuple[int, ...]:
        out = []
        last = self._last_active
        for i, node in enumerate(self.layout.behaviours):
            code = SKIPPED if getattr(node, "skipped", False) else _CODES.get(node.status, IDLE)
            if code != IDLE:
                last[i] = code
            elif last[i] != IDLE:
                code = 10 + last[i]  # BT.CPP: IDLE after SUCCESS is 12
            out.append(code)
        return tuple(out)

    @staticmethod
    def _guard_state(engine: Engine, g: GuardView, now: float) -> GuardState:
        snap = g.snapshot()
        health = engine.ctx.health.get(g.source)
        why = health.reason(now, g.role) if health is not None else "no_data"
        value = snap.threshold * snap.level_pct / 100.0 if g.kind == "i2t" else snap.value
        status = why or ("tripped" if snap.tripped else "ok")
        return GuardState(g.node, g.role, g.kind, g.source, value, g.threshold_unit, snap.threshold, snap.level_pct,
                          status, why or snap.reason)

