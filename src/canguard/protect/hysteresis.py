"""Overcurrent with hysteresis: behind IsCurrentSafe (docs/protection.md)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from canguard.protect.base import REASON_OVERCURRENT, TIME_EPS_S, LatchedModel, ProtectionModel, check_gap, check_limit
from canguard.protect.columns import Screen
from canguard.protect.inrush import InrushBlanking, in_window
from canguard.protect.threshold import level_pct

if TYPE_CHECKING:
    from canguard.protect.columns import FloatArray, IndexArray


def check_thresholds(overcurrent_a: float, recovery_a: float) -> tuple[float, float]:
    """Validate a threshold pair; ValueError naming both values when they do not make a hysteresis."""
    over = check_limit("overcurrent_a", overcurrent_a)
    rec = check_limit("recovery_a", recovery_a)
    if rec > over:
        raise ValueError(f"recovery_a ({recovery_a!r} A) must not exceed overcurrent_a ({overcurrent_a!r} A): "
                         "the current must fall below the trip threshold to recover")
    return over, rec


class _Screen(Screen):
    """A long run with the threshold in force at each sample, the stale gaps up to it, the inrush state before."""

    def __init__(self, t: FloatArray, a: FloatArray, thr: FloatArray, recovery_a: float, gaps: IndexArray,
                 inrush: tuple[float | None, float | None, float | None, int] | None) -> None:
        super().__init__(a >= thr, a <= recovery_a)
        self.t, self.a, self.thr, self.gaps, self.inrush = t, a, thr, gaps, inrush


class Hysteresis(LatchedModel[_Screen]):
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
        return self._decide(t, a, thr)

    def _decide(self, t: float, a: float, thr: float) -> bool:
        """The kernel, ``thr`` the threshold in force."""
        if self._last_t is not None and t - self._last_t > self.max_gap_s:
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

    def _screen(self, t: FloatArray, a: FloatArray) -> _Screen:
        import numpy as np

        gap = np.empty(a.size, dtype=bool)
        gap[0] = self._last_t is not None and t[0] - self._last_t > self.max_gap_s
        np.greater(np.diff(t), self.max_gap_s, out=gap[1:])
        thr = np.full(a.size, self.overcurrent_a)
        inrush = None
        if self.inrush is not None:
            inrush = self.inrush.running()
            window = self.inrush.windows(t, self.inrush.starts_in(t, a), inrush[1])
            blank = self.inrush.inrush_threshold_a
            thr[in_window(window, t, self.inrush.inrush_time_s)] = math.inf if blank is None else blank
        return _Screen(t, a, thr, self.recovery_a, np.cumsum(gap), inrush)

    def _step_at(self, screen: _Screen, j: int, t: float, a: float) -> bool:
        return self._decide(t, a, float(screen.thr[j]))

    def _rest(self, screen: _Screen, first: int, last: int) -> None:
        """A gap among quiet samples restarts the other timer too."""
        if screen.gaps[last] - (screen.gaps[first - 1] if first else 0) > 0:
            self._over_since = self._under_since = None

    def _at_rest(self) -> bool:
        return (self._under_since if self._tripped else self._over_since) is None

    def _finish(self, screen: _Screen, last: int) -> None:
        if self.inrush is None or screen.inrush is None or last == screen.size - 1:
            return
        self.inrush.resume(screen.inrush)
        self.inrush.starts_in(screen.t[: last + 1], screen.a[: last + 1])

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
        if self.inrush is not None and self._last_t is not None:
            thr = self.inrush.threshold(self.overcurrent_a, self._last_t)
        return (math.inf if thr is None else thr), level_pct(self._value, thr)
