"""The engine's watch over its inputs: stale sources, buses down, the start window, levels for metrics."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from canguard.engine.gate import TaskGate

if TYPE_CHECKING:
    from canguard.bt.context import Context
    from canguard.config.schema import Config
    from canguard.engine.stats import EngineStats
    from canguard.io.clock import PinnedClock


class SourceWatchMixin:
    """Source freshness and bus health as stops (inhibits), independent of what the tree says."""

    if TYPE_CHECKING:  # what the engine provides
        cfg: Config
        ctx: Context
        clock: PinnedClock
        gate: TaskGate
        stats: EngineStats
        metrics: Any
        _due: float
        _stale: dict[str, str]
        _started_at: float
        _start_grace_s: float

        def _event(self, event: dict[str, Any]) -> None: ...
        def _flush(self) -> None: ...

    def _starting(self, now: float) -> bool:
        """True while the task never ran and the sources still have their first max_age to speak.

        A tree that fails in that window only keeps the task from starting: the
        drives were never enabled, so no stop frames go out (they would latch an
        ESTOP error that needs clearing). After it, a failing tree stops, enabled or not.
        """
        return self.gate.state == TaskGate.IDLE and now - self._started_at < self._start_grace_s

    def _watch_sources(self, now: float) -> None:
        for name, health in self.ctx.health.items():
            reason = health.reason(now)
            if reason == "no_data" and now - self._started_at < self.ctx.sources[name].max_age_s:
                reason = ""  # not yet: every source gets max_age to send its first frame
            prev = self._stale.get(name, "")
            if name in self.ctx.read_sources:
                # Backstop, whatever the tree's shape: a source the tree reads that is stale or
                # invalid holds the task stopped until it is fine again.
                if reason:
                    self.gate.inhibit(f"source {name}", f"source {name}: {reason}", now)
                elif prev:
                    self.gate.release(f"source {name}")
            if reason != prev:
                self._stale[name] = reason
                if reason:
                    self._event({"event": "stale", "source": name, "reason": reason,
                                 "read_by_tree": name in self.ctx.read_sources})
                else:
                    self._event({"event": "fresh", "source": name, "reason": f"{prev} cleared"})
            if self.metrics is not None:
                age = health.age(now, None) if hasattr(health, "age") else math.nan
                self.metrics.set_sample_age(name, age)

    def _sample_levels(self) -> None:
        levels = self.stats.max_level_pct
        for node, model in self.ctx.heat_models.items():
            pct = model.snapshot().level_pct
            if pct > levels.get(node, -1.0):
                levels[node] = pct
            if self.metrics is not None:
                self.metrics.set_i2t_level(node, pct)

    def bus_down(self, bus: str, reason: str) -> None:
        """A bus went away: the task stops (frames out on the buses still up) until :meth:`bus_up`."""
        now = self.clock.now()
        self._event({"event": "bus_error", "source": bus, "reason": reason})
        self.gate.inhibit(f"bus {bus}", f"bus {bus} down: {reason}", now)
        self._due = min(self._due, self.gate.next_deadline())
        self._flush()

    def bus_up(self, bus: str) -> None:
        """The bus is open again: its inhibit is released (the tree decides whether the task resumes)."""
        self.gate.release(f"bus {bus}")

    def stale_unstopped(self, now: float) -> list[str]:
        """Sources the tree reads that are stale while the task is not stopped (a blind daemon)."""
        if self.gate.state == TaskGate.STOPPED:
            return []
        return [s for s in self.ctx.read_sources if self.ctx.health[s].reason(now)]
