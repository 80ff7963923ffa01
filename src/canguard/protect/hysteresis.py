"""Overcurrent with hysteresis: behind IsCurrentSafe (design note 004, section 3.3).

Trips when |I| >= ``overcurrent_a`` and recovers only when |I| <= ``recovery_a``;
in between the state holds. Both edges are inclusive: a sample exactly at the
overcurrent threshold trips, one exactly at the recovery threshold recovers.

Optional persistence: with ``trip_after_s`` > 0 the overcurrent must hold (every
sample at or above the threshold) for that long, measured from the first such
sample to the current one, before the model trips; ``recover_after_s`` does the
same for recovery. A sample that breaks the condition restarts the timer. A gap
between samples longer than ``max_gap_s`` (stale data) also restarts both timers,
so an overcurrent is never "held" across a time nobody saw.

With ``inrush`` (an :class:`~canguard.protect.inrush.InrushBlanking`), every
sample is first fed to it, and the overcurrent threshold in force is the one it
returns (the inrush threshold inside a blanking window, or no overcurrent check
when it has none). Recovery is never blanked.
"""

from __future__ import annotations

import math

from canguard.protect.base import REASON_OVERCURRENT, TIME_EPS_S, LatchedModel, ProtectionModel
from canguard.protect.inrush import InrushBlanking
from canguard.protect.threshold import check_limit, level_pct


def check_thresholds(overcurrent_a: float, recovery_a: float) -> tuple[float, float]:
    """Validate a threshold pair; ValueError naming both values when they do not make a hysteresis."""
    over = check_limit("overcurrent_a", overcurrent_a)
    rec = check_limit("recovery_a", recovery_a)
    if rec > over:
        raise ValueError(
            f"recovery_a ({recovery_a!r} A) must not exceed overcurrent_a ({overcurrent_a!r} A): "
            "the current must fall below the trip threshold to recover"
        )
    return over, rec


class Hysteresis(LatchedModel):
    """Overcurrent guard with a trip and a lower recovery threshold; reason ``overcurrent``.

    ``overcurrent_a`` (A, default 35), ``recovery_a`` (A, default 25, must be <=
    ``overcurrent_a``), ``trip_after_s`` / ``recover_after_s`` (s, default 0:
    immediate), ``inrush`` (optional blanking helper), ``max_gap_s`` (s, default
    inf: a longer gap between samples restarts the persistence timers).
    ValueError on negative values or ``recovery_a`` > ``overcurrent_a``.
    """

    reason_tripped = REASON_OVERCURRENT
    SAMPLE_DRIVEN = True
    """Trips and recovers only at samples (the persistence timers and inrush windows are measured at samples)."""

    def __init__(
        self,
        overcurrent_a: float = 35.0,
        recovery_a: float = 25.0,
        trip_after_s: float = 0.0,
        recover_after_s: float = 0.0,
        inrush: InrushBlanking | None = None,
        *,
        max_gap_s: float = math.inf,
    ) -> None:
        super().__init__()
        self.overcurrent_a, self.recovery_a = check_thresholds(overcurrent_a, recovery_a)
        self.trip_after_s = check_limit("trip_after_s", trip_after_s)
        self.recover_after_s = check_limit("recover_after_s", recover_after_s)
        if math.isnan(max_gap_s) or max_gap_s <= 0:
            raise ValueError(f"max_gap_s must be > 0, got {max_gap_s!r}")
        self.max_gap_s = float(max_gap_s)
        self.inrush = inrush
        self._over_since: float | None = None
        self._under_since: float | None = None

    def set_thresholds(self, overcurrent_a: float, recovery_a: float) -> None:
        """Change both thresholds at run time (validated like the constructor); used from the next sample."""
        self.overcurrent_a, self.recovery_a = check_thresholds(overcurrent_a, recovery_a)

    def carry_from(self, old: ProtectionModel) -> None:
        """The base state plus the running persistence timers and the inrush window (see base)."""
        super().carry_from(old)
        if isinstance(old, Hysteresis):
            self._over_since, self._under_since = old._over_since, old._under_since
            if self.inrush is not None and old.inrush is not None:
                self.inrush.carry_from(old.inrush)

    def threshold_at(self, t: float) -> float | None:
        """The overcurrent threshold in force at ``t`` (None: check off during inrush blanking)."""
        if self.inrush is None:
            return self.overcurrent_a
        return self.inrush.threshold(self.overcurrent_a, t)

    def update(self, value: float, t: float) -> bool:
        """Feed one sample; True when the tripped state changed."""
        a = self._accept(value, t)
        if a is None:
            return False
        if self._last_t is not None and t - self._last_t > self.max_gap_s:
            self._over_since = self._under_since = None
        self._last_t = t
        self._value = a
        if self.inrush is not None:
            self.inrush.observe(a, t)
        if not self._tripped:
            thr = self.threshold_at(t)
            if thr is not None and a >= thr:
                if self._over_since is None:
                    self._over_since = t
                if t - self._over_since >= self.trip_after_s - TIME_EPS_S:
                    self._over_since = None
                    return self._set_tripped(True, t)
            else:
                self._over_since = None
            return False
        if a <= self.recovery_a:
            if self._under_since is None:
                self._under_since = t
            if t - self._under_since >= self.recover_after_s - TIME_EPS_S:
                self._under_since = None
                return self._set_tripped(False, t)
        else:
            self._under_since = None
        return False

    def settles(self, low: float, high: float, first_t: float) -> bool:
        """A run below the trip threshold (not tripped) or above the recovery one (tripped); never with inrush."""
        if self.inrush is not None or not self._in_order(first_t):
            return False
        return low > self.recovery_a if self._tripped else high < self.overcurrent_a

    def take_run(self, last: float, last_t: float) -> None:
        """Such a run restarts its side's persistence timer at every sample: it ends unset.

        The other side's timer is unset already (a trip clears the overcurrent timer, a
        recovery the recovery timer), so a gap that restarts both changes nothing more.
        """
        if self._tripped:
            self._under_since = None
        else:
            self._over_since = None
        super().take_run(last, last_t)

    def _threshold_value(self) -> float:
        thr = self.threshold_at(self._last_t) if self._last_t is not None else self.overcurrent_a
        return math.inf if thr is None else thr

    def _level_pct(self) -> float:
        thr = self.threshold_at(self._last_t) if self._last_t is not None else self.overcurrent_a
        return level_pct(self._value, thr)
