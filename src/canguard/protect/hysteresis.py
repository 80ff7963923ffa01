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
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import numpy.typing as npt

from canguard.protect.base import REASON_OVERCURRENT, TIME_EPS_S, LatchedModel, ProtectionModel, Scan
from canguard.protect.columns import FloatArray, IndexArray, last_marked, stretch_begins, stretch_start_times
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


@dataclass
class _Side:
    """One persistence timer over a run: its condition, the stretches meeting it, where it is ready.

    ``before``: the timer's start carried in from the previous run (None: not running).
    """

    cond: npt.NDArray[np.bool_]
    gap: npt.NDArray[np.bool_]
    t: FloatArray
    before: float | None
    hold_s: float
    ready: IndexArray = field(init=False)

    def __post_init__(self) -> None:
        if self.hold_s <= TIME_EPS_S:  # no persistence: every sample meeting the condition is ready
            self.ready = self.cond.nonzero()[0]
        else:
            self.ready = (self.cond & (self.t - self.began >= self.hold_s - TIME_EPS_S)).nonzero()[0]

    @cached_property
    def _begins(self) -> npt.NDArray[np.bool_]:
        return stretch_begins(self.cond, self.gap, self.before)

    @cached_property
    def began(self) -> FloatArray:
        """When the stretch each sample belongs to began (meaningless where the condition fails)."""
        return stretch_start_times(self._begins, self.cond, self.t, self.before)

    @cached_property
    def begin(self) -> IndexArray:
        """Where the stretch each sample belongs to began (-1: carried in from the previous run)."""
        return last_marked(self._begins)

    def next_ready(self, pos: int, after_edge: bool) -> int | None:
        """The first sample from ``pos`` on at which the condition has held long enough (None: none).

        ``after_edge``: an edge happened at ``pos - 1``, so a stretch running through it
        counts from ``pos`` only.
        """
        k = int(np.searchsorted(self.ready, pos))
        if k == self.ready.size:
            return None
        j = int(self.ready[k])
        if not after_edge or self.hold_s <= TIME_EPS_S or self.begin[j] >= pos:
            return j
        rest = self.ready[k:]
        same = rest[self.begin[rest] == self.begin[j]]
        hits = same[self.t[same] - self.t[pos] >= self.hold_s - TIME_EPS_S]
        if hits.size:
            return int(hits[0])
        return self.next_ready(int(same[-1]) + 1, False)

    def since(self, k: int, floor: float | None) -> float | None:
        """The timer's start right after sample ``k`` (no edge at ``k``); ``floor``: the sample after the last edge."""
        if not self.cond[k]:
            return None
        began = float(self.began[k])
        return began if floor is None else max(began, floor)


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

    def _scan(self, t: FloatArray, a: FloatArray) -> Scan:
        """The trip and recovery conditions as columns, their held times as stretches, the edges one by one.

        Over a run the overcurrent condition (|I| >= the threshold in force) and the
        recovery one (|I| <= ``recovery_a``) do not depend on the state; each persistence
        timer runs from the start of the current stretch of samples meeting its condition
        (a gap over ``max_gap_s`` or a sample failing it starts a new stretch), counted no
        earlier than the sample after the latest edge (an edge stops the other timer).
        """
        gap = np.empty(a.size, dtype=bool)
        gap[0] = self._last_t is not None and t[0] - self._last_t > self.max_gap_s
        np.greater(np.diff(t), self.max_gap_s, out=gap[1:])
        inrush = self.inrush.scan(t, a) if self.inrush is not None else None
        over = a >= self.overcurrent_a
        if inrush is not None:
            if self.inrush_threshold_a is None:
                over &= ~inrush.blanking
            else:
                over = np.where(inrush.blanking, a >= self.inrush_threshold_a, over)
        sides = (
            _Side(over, gap, t, None if self._tripped else self._over_since, self.trip_after_s),
            _Side(a <= self.recovery_a, gap, t, self._under_since if self._tripped else None, self.recover_after_s),
        )
        state = np.empty(a.size, dtype=bool)
        edges: list[int] = []
        tripped, pos = self._tripped, 0
        while pos < a.size:
            j = sides[tripped].next_ready(pos, bool(edges))
            if j is None:
                state[pos:] = tripped
                break
            state[pos:j] = tripped
            tripped = not tripped
            state[j] = tripped
            edges.append(j)
            pos = j + 1
        marks = np.asarray(edges, dtype=np.intp)

        def commit(k: int) -> None:
            if inrush is not None:
                inrush.commit(k)
            n = int(np.searchsorted(marks, k, side="right"))
            floor = t[marks[n - 1] + 1] if n and marks[n - 1] < k else None
            now_tripped = bool(state[k])
            self._over_since = None if now_tripped or (n and marks[n - 1] == k) else sides[0].since(k, floor)
            self._under_since = None if not now_tripped or (n and marks[n - 1] == k) else sides[1].since(k, floor)

        return Scan(state, commit)

    @property
    def inrush_threshold_a(self) -> float | None:
        """The overcurrent threshold inside an inrush window (None: no check there, or no inrush helper)."""
        return None if self.inrush is None else self.inrush.inrush_threshold_a

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
