"""Overcurrent with hysteresis: behind IsCurrentSafe (docs/protection.md)."""

from __future__ import annotations

import math
from typing import Any

from canguard.protect.base import REASON_OVERCURRENT, TIME_EPS_S, LatchedModel, ProtectionModel, check_gap, check_limit
from canguard.protect.inrush import InrushBlanking
from canguard.protect.threshold import level_pct


def check_thresholds(overcurrent_a: float, recovery_a: float) -> tuple[float, float]:
    """Validate a threshold pair; ValueError naming both values when they do not make a hysteresis."""
    over = check_limit("overcurrent_a", overcurrent_a)
    rec = check_limit("recovery_a", recovery_a)
    if rec > over:
        raise ValueError(f"recovery_a ({recovery_a!r} A) must not exceed overcurrent_a ({overcurrent_a!r} A): "
                         "the current must fall below the trip threshold to recover")
    return over, rec


class Hysteresis(LatchedModel):
    """Overcurrent guard with a trip and a lower recovery threshold; reason ``overcurrent``; ValueError out of range."""

    reason_tripped = REASON_OVERCURRENT

    def __init__(self, overcurrent_a: float = 35.0, recovery_a: float = 25.0, trip_after_s: float = 0.0,
                 recover_after_s: float = 0.0, inrush: InrushBlanking | None = None, *,
                 max_gap_s: float = math.inf) -> None:
        super().__init__()
        self.overcurrent_a, self.recovery_a = check_thresholds(overcurrent_a, recovery_a)
        self.trip_after_s = check_limit("trip_after_s", trip_after_s)
        self.recover_after_s = check_limit("recover_after_s", recover_after_s)
        self.max_gap_s = check_gap(max_gap_s)
        self.inrush = inrush
        self._over_since: float | None = None
        self._under_since: float | None = None

    def set_thresholds(self, overcurrent_a: float, recovery_a: float) -> None:
        """Change both thresholds at run time (validated like the constructor); used from the next sample."""
        self.overcurrent_a, self.recovery_a = check_thresholds(overcurrent_a, recovery_a)

    def carry_from(self, old: ProtectionModel) -> None:
        """The base state plus the persistence timers and the inrush window."""
        super().carry_from(old)
        if isinstance(old, Hysteresis):
            self._over_since, self._under_since = old.timers
            if self.inrush is not None and old.inrush is not None:
                self.inrush.resume(old.inrush.running())

    @property
    def timers(self) -> tuple[float | None, float | None]:
        """Since when the overcurrent, and the recovery, held (None: not running)."""
        return self._over_since, self._under_since

    def _step(self, t: float, a: float) -> bool:
        thr = self.overcurrent_a
        if self.inrush is not None:
            self.inrush.observe(a, t)
            in_force = self.inrush.threshold(thr, t)
            thr = math.inf if in_force is None else in_force
        if self.last_t is not None and t - self.last_t > self.max_gap_s:
            self._over_since = self._under_since = None
        if not self._tripped:
            if a < thr:
                self._over_since = None
                return False
            if self._over_since is None:
                self._over_since = t
            if t - self._over_since >= self.trip_after_s - TIME_EPS_S:
                self._over_since = None
                return True
            return False
        if a > self.recovery_a:
            self._under_since = None
            return True
        if self._under_since is None:
            self._under_since = t
        if t - self._under_since >= self.recover_after_s - TIME_EPS_S:
            self._under_since = None
            return False
        return True

    def mark(self) -> Any:
        """The running state, the inrush helper's too."""
        return super().mark(), None if self.inrush is None else self.inrush.running()

    def rewind(self, mark: Any) -> None:
        """Back to :meth:`mark`'s state."""
        own, inrush = mark
        super().rewind(own)
        if self.inrush is not None and inrush is not None:
            self.inrush.resume(inrush)

    def _quiet(self, t: Any, low_a: float, high_a: float, final_a: float) -> bool:
        """No timer, no inrush helper, every sample on the side the state is on."""
        if self.inrush is not None or self._over_since is not None or self._under_since is not None:
            return False
        return low_a > self.recovery_a if self._tripped else high_a < self.overcurrent_a

    def _levels(self) -> tuple[float, float]:
        """The overcurrent threshold in force at the latest sample (inf: blanked)."""
        thr: float | None = self.overcurrent_a
        if self.inrush is not None and self.last_t is not None:
            thr = self.inrush.threshold(self.overcurrent_a, self.last_t)
        return (math.inf if thr is None else thr), level_pct(self._value, thr)
