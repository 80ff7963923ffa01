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
from typing import TYPE_CHECKING, Any

from canguard.protect.base import REASON_OVERCURRENT, TIME_EPS_S, LatchedModel, ProtectionModel
from canguard.protect.columns import Marks, Screen
from canguard.protect.inrush import InrushBlanking, in_window
from canguard.protect.threshold import check_limit, level_pct

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


class _Screen(Marks):
    """A long run screened for the hysteresis kernel: the threshold in force and the gaps at each sample.

    ``thr``: the overcurrent threshold in force (inf: no check, inrush blanking).
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


class Hysteresis(LatchedModel):
    """Overcurrent guard with a trip and a lower recovery threshold; reason ``overcurrent``.

    ``overcurrent_a`` (A, default 35), ``recovery_a`` (A, default 25, must be <=
    ``overcurrent_a``), ``trip_after_s`` / ``recover_after_s`` (s, default 0:
    immediate), ``inrush`` (optional blanking helper), ``max_gap_s`` (s, default
    inf: a longer gap between samples restarts the persistence timers).
    ValueError on negative values or ``recovery_a`` > ``overcurrent_a``.
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
            self._over_since, self._under_since = old.timers
            if self.inrush is not None and old.inrush is not None:
                self.inrush.carry_from(old.inrush)

    @property
    def timers(self) -> tuple[float | None, float | None]:
        """The running persistence timers: since when the overcurrent, and the recovery, held (None: not running)."""
        return self._over_since, self._under_since

    def threshold_at(self, t: float) -> float | None:
        """The overcurrent threshold in force at ``t`` (None: check off during inrush blanking)."""
        if self.inrush is None:
            return self.overcurrent_a
        return self.inrush.threshold(self.overcurrent_a, t)

    def _step(self, t: float, a: float) -> bool:
        """One sample: the inrush helper sees it first, then the kernel decides on the threshold it gives."""
        thr = self.overcurrent_a
        if self.inrush is not None:
            self.inrush.observe(a, t)
            in_force = self.inrush.threshold(thr, t)
            thr = math.inf if in_force is None else in_force
        return self._decide(t, a, thr)

    def _decide(self, t: float, a: float, thr: float) -> bool:
        """The kernel: the tripped state after a sample ``a`` at ``t`` with ``thr`` the threshold in force.

        A gap over ``max_gap_s`` restarts both timers; each side's timer runs from the
        first sample meeting its condition and the edge comes once it has held long enough.
        """
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
            before = self.inrush.running()
            started = self.inrush.starts_in(t, a)
            window = self.inrush.windows(t, started, before[1])
            blank = self.inrush_threshold_a
            thr[in_window(window, t, self.inrush.inrush_time_s)] = math.inf if blank is None else blank
            inrush = before
        return _Screen(t, a, thr, self.recovery_a, np.cumsum(gap), inrush)

    def _step_at(self, screen: Screen, j: int, t: float, a: float) -> bool:
        """The kernel with the threshold the screen found in force at sample ``j``."""
        assert isinstance(screen, _Screen)
        return self._decide(t, a, float(screen.thr[j]))

    def _rest(self, screen: Screen, first: int, last: int) -> None:
        """Quiet samples keep the resting timer unset; a gap among them restarts the other one too."""
        assert isinstance(screen, _Screen)
        if screen.gaps[last] - (screen.gaps[first - 1] if first else 0) > 0:
            self._over_since = self._under_since = None

    def _at_rest(self) -> bool:
        """No persistence timer running on the side the state is on."""
        return (self._under_since if self._tripped else self._over_since) is None

    def _finish(self, screen: Screen, last: int) -> None:
        """A walk stopped before the run's end leaves the inrush helper right after sample ``last`` too."""
        assert isinstance(screen, _Screen)
        if self.inrush is None or screen.inrush is None or last == screen.size - 1:
            return
        self.inrush.resume(screen.inrush)
        self.inrush.starts_in(screen.t[: last + 1], screen.a[: last + 1])

    @property
    def inrush_threshold_a(self) -> float | None:
        """The overcurrent threshold inside an inrush window (None: no check there, or no inrush helper)."""
        return None if self.inrush is None else self.inrush.inrush_threshold_a

    def mark(self) -> Any:
        """The base's running state and the inrush helper's."""
        return super().mark(), None if self.inrush is None else self.inrush.running()

    def rewind(self, mark: Any) -> None:
        """Back to :meth:`mark`'s state, the inrush helper's too."""
        own, inrush = mark
        super().rewind(own)
        if self.inrush is not None and inrush is not None:
            self.inrush.resume(inrush)

    def _quiet_side(self, t: Any, low_a: float, high_a: float) -> bool:
        """No timer, no inrush helper, every sample below the trip threshold (not tripped) or above the recovery
        one (tripped): each sample only keeps its side's timer unset (a gap restarts timers that are unset)."""
        if self.inrush is not None or self._over_since is not None or self._under_since is not None:
            return False
        if self._tripped:
            return low_a > self.recovery_a
        return high_a < self.overcurrent_a

    def _threshold_value(self) -> float:
        thr = self.threshold_at(self._last_t) if self._last_t is not None else self.overcurrent_a
        return math.inf if thr is None else thr

    def _level_pct(self) -> float:
        thr = self.threshold_at(self._last_t) if self._last_t is not None else self.overcurrent_a
        return level_pct(self._value, thr)
