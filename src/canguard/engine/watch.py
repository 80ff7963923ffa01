"""The engine's watch over its inputs: stale sources, buses down, the start window, I²t levels for metrics."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from canguard.engine.gate import TaskGate

if TYPE_CHECKING:
    from canguard.bt.context import Context
    from canguard.config.schema import Config
    from canguard.engine.events import Journal
    from canguard.io.clock import PinnedClock


CAN_ERR_CRTL = 0x004
"""linux/can/error.h: the error class of controller problems (the state is in data[1])."""
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40
"""The controller is back to error-active."""


class SourceWatch:
    """Source freshness and bus health as stops (inhibits), independent of what the tree says.

    Owned by the engine; it holds the task through the gate (:meth:`TaskGate.inhibit`) and
    says why in the journal. Whatever moves the gate's deadlines, the engine reads them
    again after each call (:meth:`TaskGate.next_deadline`).
    """

    def __init__(self, cfg: Config, ctx: Context, gate: TaskGate, journal: Journal, metrics: Any,
                 clock: PinnedClock, guard_nodes: list[Any], period_s: float) -> None:
        self.ctx = ctx
        self.gate = gate
        self.journal = journal
        self.metrics = metrics
        self.clock = clock
        self.guard_nodes = guard_nodes
        self.period_s = period_s
        read = [cfg.sources[s].max_age_s for s in ctx.read_sources if s in cfg.sources]
        self.start_grace_s = max(read, default=0.0)
        """How long after the start a failing tree only keeps the task from starting (:meth:`starting`)."""
        self.started_at = math.nan
        """When the engine started (set by :meth:`Engine.start <canguard.engine.core.Engine.start>`)."""
        self.stale: dict[str, str] = {}
        """Each source's reason as the last tick saw it ("" fresh)."""
        self.cover: list[Any] = []
        """The guards ticked when the task last started: they must keep being ticked (see :meth:`guards`)."""

    def adopt(self, old: SourceWatch) -> None:
        """Continue ``old``'s watch (config reload): the sources' reasons and the start time."""
        self.stale = dict(old.stale)
        self.started_at = old.started_at

    def starting(self, now: float) -> bool:
        """True while the task never ran and the sources still have their first max_age to speak.

        A tree that fails in that window only keeps the task from starting: the
        drives were never enabled, so no stop frames go out (they would latch an
        ESTOP error that needs clearing). After it, a failing tree stops, enabled or not.
        """
        return self.gate.state == TaskGate.IDLE and now - self.started_at < self.start_grace_s

    def sources(self, now: float) -> None:
        """At a tick: each source's reason; a source the tree reads holds the task while it is stale."""
        for name, health in self.ctx.health.items():
            reason = health.reason(now)
            if reason == "no_data" and now - self.started_at < self.ctx.sources[name].max_age_s:
                reason = ""  # not yet: every source gets max_age to send its first frame
            prev = self.stale.get(name, "")
            if name in self.ctx.read_sources:
                # Backstop, whatever the tree's shape: a source the tree reads that is stale or
                # invalid holds the task stopped until it is fine again.
                if reason:
                    self.gate.inhibit(f"source {name}", f"source {name}: {reason}", now)
                elif prev:
                    self.gate.release(f"source {name}")
            if reason != prev:
                self.stale[name] = reason
                if reason:
                    self.journal.write({"event": "stale", "source": name, "reason": reason,
                                 "read_by_tree": name in self.ctx.read_sources})
                else:
                    self.journal.write({"event": "fresh", "source": name, "reason": f"{prev} cleared"})
            if self.metrics is not None:
                age = health.age(now, None) if hasattr(health, "age") else math.nan
                self.metrics.set_sample_age(name, age)

    def guards(self, now: float, was_running: bool) -> None:
        """Every guard of the tree must keep being ticked while the task runs (safety table row T4).

        A tree can leave its guards behind while the task runs (a RunOnce around a guard, a
        branch the tree stopped visiting): the models still see every sample, but no failure
        can reach the tree. When a guard has not been ticked for longer than its source's
        ``max_age`` (a tick period at least) while the task runs, the task is held stopped
        (an inhibit, ``guards``, the stop event naming the guards) until every guard is
        ticked again. Conservative on purpose: a guard in a branch the running tree does not
        visit stops the task too — guards belong where every tick reaches them (design note 004).
        """
        gate = self.gate
        if gate.state == TaskGate.RUNNING and not was_running:
            self.cover = list(self.guard_nodes)
        left = [
            g for g in self.cover
            if g.source is not None and now - g.judged_t > max(g.source.max_age_s, self.period_s)
        ]
        if left and gate.state == TaskGate.RUNNING:
            names = ", ".join(g.name for g in left)
            gate.inhibit("guards", f"guards not ticked while the task runs: {names}", now, node=left[0].name)
        elif "guards" in gate.inhibits and all(g.judged_t == now for g in self.cover):
            gate.release("guards")

    def levels(self) -> None:
        """The I²t levels at a tick, to metrics (the summaries' peaks are the models' own, over every sample)."""
        metrics = self.metrics
        for node, model in self.ctx.heat_models.items():
            metrics.set_i2t_level(node, model.snapshot().level_pct)

    def bus_down(self, bus: str, reason: str) -> None:
        """A bus went away: the task stops (frames out on the buses still up) until :meth:`bus_up`."""
        now = self.clock.now()
        self.journal.write({"event": "bus_error", "source": bus, "reason": reason})
        self.gate.inhibit(f"bus {bus}", f"bus {bus} down: {reason}", now)
        self.journal.flush()

    def controller_state(self, bus: str, frame: Any) -> None:
        """An error frame's controller report (SocketCAN's ``CAN_ERR_CRTL`` class): error-passive holds the task.

        A controller in error-passive has seen so many errors that its frames, our stop frames
        among them, may no longer get through: journalled (``bus_error``) and the task is held
        stopped (inhibit ``bus NAME passive``) until the controller reports it is error-active
        again (``CAN_ERR_CRTL_ACTIVE``, sent by Linux since 5.x) or the bus is reopened.
        """
        if not frame.arbitration_id & CAN_ERR_CRTL or len(frame.data) < 2:
            return
        state = frame.data[1]
        key = f"bus {bus} passive"
        now = self.clock.now()
        if state & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
            if key not in self.gate.inhibits:
                side = "/".join(s for s, bit in (("rx", CAN_ERR_CRTL_RX_PASSIVE), ("tx", CAN_ERR_CRTL_TX_PASSIVE))
                                if state & bit)
                reason = f"bus {bus}: controller error-passive ({side}): frames may not get through"
                self.journal.write({"event": "bus_error", "source": bus, "reason": reason})
                self.gate.inhibit(key, reason, now)
                self.journal.flush()  # after the stop frames the inhibit sent
        elif state & CAN_ERR_CRTL_ACTIVE and key in self.gate.inhibits:
            again = f"bus {bus}: controller error-active again"
            self.journal.write({"event": "bus_error", "source": bus, "reason": again})
            self.gate.release(key)

    def overrun(self, waited_s: float, limit_s: float) -> None:
        """Frames waited ``waited_s`` in the daemon's receive queue: it is behind its buses, the task stops.

        The models would judge data older than the sources' ``max_age`` as fresh (safety row
        H2b): held stopped (inhibit ``overrun``, an ``overrun`` event) until :meth:`caught_up`.
        """
        if "overrun" in self.gate.inhibits:
            return
        now = self.clock.now()
        reason = (f"frames waited {waited_s:.3f} s in canguard's receive queue (limit {limit_s:.3f} s): "
                  "the daemon is behind its buses")
        self.journal.write({"event": "overrun", "reason": reason})
        self.gate.inhibit("overrun", reason, now)
        self.journal.flush()

    def caught_up(self, waited_s: float) -> None:
        """Frames wait no more than ``waited_s`` again: the ``overrun`` inhibit is released."""
        if "overrun" not in self.gate.inhibits:
            return
        self.journal.write({"event": "overrun", "reason": f"caught up: frames wait {waited_s:.3f} s"})
        self.gate.release("overrun")
        self.journal.flush()

    def bus_up(self, bus: str) -> None:
        """The bus is open again: its inhibits are released (the tree decides whether the task resumes)."""
        self.gate.release(f"bus {bus}")
        self.gate.release(f"bus {bus} passive")  # a reopened controller starts error-active

    def stale_unstopped(self, now: float) -> list[str]:
        """Sources the tree reads that are stale while the task is not stopped (a blind daemon)."""
        if self.gate.state == TaskGate.STOPPED:
            return []
        return [s for s in self.ctx.read_sources if self.ctx.health[s].reason(now)]
