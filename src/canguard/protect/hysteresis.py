"""Overcurrent with hysteresis: behind IsCurrentSafe (docs/protection.md).

Trips when |I| >= ``overcurrent_a``, recovers only when |I| <= ``recovery_a`` (both inclusive); in
between the state holds. With ``trip_after_s`` / ``recover_after_s`` > 0 the condition must hold at
every sample for that long, from the first such sample; a sample that breaks it, or a gap between
samples longer than ``max_gap_s`` (stale data), restarts the timer. With ``inrush`` every sample is
first fed to it and the overcurrent threshold in force is the one it gives (None: no overcurrent
check in the window); recovery is never blanked.
"""

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
        raise ValueError(
            f"recovery_a ({recovery_a!r} A) must not exceed overcurrent_a ({overcurrent_a!r} A): "
            "the current must fall below the trip threshold to recover"
        )
    return over, rec


class _Screen(Screen):
    """A long run screened for the hysteresis kernel.

    ``thr``: the overcurrent threshold in force at each sample (inf: no check, inrush blanking).
    ``gaps``: how many gaps over ``max_gap_s`` lie before or at each sample.
    ``inrush``: the inrush helper's state before the run (None: no helper).
    """

    def __init__(self, t: FloatArray, a: FloatArray, thr: FloatArray, recovery_a: float, gaps: IndexArray,
                 inrush: tuple[float | None, float | None, float | None, int] | None) -> None:
        super().__init__(a >= thr, a <= recovery_a)
        self.t = t
        self.a = a
        self.thr = thr
        self.gaps = gaps
        self.inrush = inrush


class Hysteresis(LatchedModel[_Screen]):
    """Overcurrent guard with a trip and a lower recovery threshold; reason ``overcurrent``.

    ``overcurrent_a`` (A, default 35), ``recovery_a`` (A, default 25, at most ``overcurrent_a``),
    ``trip_after_s`` / ``recover_after_s`` (s, default 0: immediate), ``inrush`` (optional
    blanking helper), ``max_gap_s`` (s, default inf). ValueError on a value out of range.
    """

    reason_tripped = REASON_OVERCURRENT

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
        self.max_gap_s = check_gap(max_gap_s)
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
            self._over_since, self._under_since = old.timers
            if self.inrush is not None and old.inrush is not None:
                self.inrush.resume(old.inrush.running())

    @property
    def timers(self) -> tuple[float | None, float | None]:
        """The running persistence timers: since when the overcurrent, and the recovery, held (None: not running)."""
        return self._over_since, self._under_since

    def _step(self, t: float, a: float) -> bool:
        """The inrush helper sees the sample first, then :meth:`_decide` on the threshold it gives."""
        thr = self.overcurrent_a
        if self.inrush is not None:
            self.inrush.observe(a, t)
            in_force = self.inrush.threshold(thr, t)
            thr = math.inf if in_force is None else in_force
        return self._decide(t, a, thr)

    def _decide(self, t: float, a: float, thr: float) -> bool:
        """The kernel: the tripped state after a sample ``a`` at ``t`` with ``thr`` the threshold in force."""
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
        """The threshold in force at each sample (the inrush helper run over the run first) and the gaps."""
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
        """Quiet samples keep the resting timer unset; a gap among them restarts the other one too."""
        if screen.gaps[last] - (screen.gaps[first - 1] if first else 0) > 0:
            self._over_since = self._under_since = None

    def _at_rest(self) -> bool:
        """No persistence timer running on the side the state is on."""
        return (self._under_since if self._tripped else self._over_since) is None

    def _finish(self, screen: _Screen, last: int) -> None:
        """A walk stopped before the run's end leaves the inrush helper right after sample ``last`` too."""
        if self.inrush is None or screen.inrush is None or last == screen.size - 1:
            return
        self.inrush.resume(screen.inrush)
        self.inrush.starts_in(screen.t[: last + 1], screen.a[: last + 1])

    def mark(self) -> Any:
        """The base's running state and the inrush helper's."""
        return super().mark(), None if self.inrush is None else self.inrush.running()

    def rewind(self, mark: Any) -> None:
        """Back to :meth:`mark`'s state, the inrush helper's too."""
        own, inrush = mark
        super().rewind(own)
        if self.inrush is not None and inrush is not None:
            self.inrush.resume(inrush)

    def _quiet(self, t: Any, low_a: float, high_a: float, final_a: float) -> bool:
        """No timer, no inrush helper, every sample below the trip threshold (not tripped) or above the recovery
        one (tripped): each sample only keeps its side's timer unset (a gap restarts timers that are unset)."""
        if self.inrush is not None or self._over_since is not None or self._under_since is not None:
            return False
        return low_a > self.recovery_a if self._tripped else high_a < self.overcurrent_a

    def _levels(self) -> tuple[float, float]:
        """The overcurrent threshold in force at the latest sample (inf: no check during inrush blanking)."""
        thr: float | None = self.overcurrent_a
        if self.inrush is not None and self._last_t is not None:
            thr = self.inrush.threshold(self.overcurrent_a, self._last_t)
        return (math.inf if thr is None else thr), level_pct(self._value, thr)
