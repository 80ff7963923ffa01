"""I²t protection: how much heat the current has put into the motor.

Two models, chosen per guard node; both trip at 100 % of their trip level and
recover when the level falls below ``recover_fraction`` (default 0.5) of it.

**Leaky bucket** (:class:`LeakyI2t`, servo-drive style): ``A' = I² − I_cont²``,
floored at 0; trip level ``S = (I_peak² − I_cont²)·t_peak`` (A²s). From cold at a
constant ``I > I_cont`` the trip time is ``S / (I² − I_cont²)``; e.g. 12 A peak,
6 A continuous, 1 s gives S = 108 A²s.

**First-order thermal image** (:class:`ThermalI2t`, IEC 60255-8 / 60255-149):
``θ' = (I²/I_cont² − θ)/τ``, trip at θ >= 1. From cold ``t = τ·ln(I²/(I² − I_cont²))``;
from a warm start at a prior steady current ``I_p``, ``t = τ·ln((I² − I_p²)/(I² − I_cont²))``.
When ``tau_s`` is not given it follows from the leaky model's datasheet figures
so that both agree at the peak point: ``τ = t_peak / ln(I_peak² / (I_peak² − I_cont²))``.
An optional ``tau_cool_s`` is used whenever θ is falling (I²/I_cont² < θ). The
``continuous_a`` given is I_cont itself (the caller multiplies I_rated by k).

**Integration rule.** Each sample's |I| is held (zero-order hold) until the next
sample, and each interval is integrated with its *exact* solution (linear for the
leaky bucket, exponential for the thermal image). This is exact for a
piecewise-constant current, so trip times do not depend on the sample rate
(irregular sampling included); the trip itself is seen at the first sample at or
after the moment the level reaches 100 %, i.e. within one sample period of the
closed forms above.

- A sample older than the latest one (negative dt: clock step back, out-of-order
  frames) is ignored entirely and counted in ``out_of_order``; a repeated
  timestamp integrates nothing and only updates the held current.
- A gap longer than ``max_gap_s`` (give the source's ``max_age_s``) is stale
  data, not one giant step: the held current is integrated for ``max_gap_s``
  only (the time it was still known to be valid), and for the rest of the gap the
  state is frozen (neither heated nor cooled, because nothing is known;
  meanwhile the staleness guard fails the tree anyway). Counted in ``stale_gaps``.
- The state is never NaN and never negative; it is also capped at 10⁶ trip
  levels, so absurd inputs keep it finite.

**Persistence** (see :mod:`canguard.protect.state`): ``export()`` gives a
JSON-able dict; ``restore(state, downtime_s)`` cools it for the downtime with the
*saved* model's own law (leaky: ``A − I_cont²·downtime``, floored at 0; thermal:
``θ·exp(−downtime/τ_cool)``) and takes over the resulting *level* (fraction of
the trip level). So a state saved under other parameters, or by the other kind of
model, is not thrown away (that would start cold: not fail safe) but carried over
as "this close to tripping". A malformed state raises ``ValueError``.
"""

from __future__ import annotations

import math
from abc import abstractmethod
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from canguard.protect.accumulate import clamped_sum, thermal_steps
from canguard.protect.base import REASON_I2T, LatchedModel, ProtectionModel
from canguard.protect.columns import Marks, Screen, longest_step
from canguard.protect.state import KIND_LEAKY, KIND_THERMAL, cooled_level
from canguard.units import AMPERE2_SECOND, THETA

if TYPE_CHECKING:
    from canguard.protect.columns import BoolArray, FloatArray, IndexArray

STATE_VERSION = 1
MAX_LEVEL = 1e6
"""The accumulator is capped at this many trip levels (keeps it finite)."""
RATED_OVERLOAD = 1.5
"""Without a datasheet peak the peak point is this many times the rating (IEC 60034-1 occasional excess)."""
RATED_OVERLOAD_S = 120.0
"""... allowed for this long from cold (IEC 60034-1: 1.5 × I_rated for 2 minutes)."""


def _positive(name: str, value: float | None) -> float:
    if value is None:
        raise ValueError(f"{name} is required")
    v = float(value)
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def _fraction(value: float) -> float:
    v = float(value)
    if not 0 < v < 1:
        raise ValueError(f"recover_fraction must be > 0 and < 1, got {value!r}")
    return v


def _gap(value: float) -> float:
    v = float(value)
    if math.isnan(v) or v <= 0:
        raise ValueError(f"max_gap_s must be > 0 (inf: no limit), got {value!r}")
    return v


def _json_float(v: float) -> float | None:
    return v if math.isfinite(v) else None


class _Screen(Marks):
    """A long run screened for the I²t kernel: the accumulator after each sample and the stale gaps up to it.

    Marked: where the level reaches 1 (may trip) and where it is below ``recover_fraction`` (may recover).
    """

    def __init__(self, a: FloatArray, acc: FloatArray, trip: BoolArray, low: BoolArray,
                 stale: IndexArray) -> None:
        super().__init__(trip, low)
        self.a = a
        self.acc = acc
        self.stale = stale


class _I2tModel(LatchedModel):
    """What both I²t models share: sampling, gaps, trip/recover on the level, persistence."""

    kind: str = ""
    reason_tripped = REASON_I2T
    def __init__(self, continuous_a: float, recover_fraction: float, max_gap_s: float) -> None:
        super().__init__()
        self.continuous_a = _positive("continuous_a", continuous_a)
        self.recover_fraction = _fraction(recover_fraction)
        self.max_gap_s = _gap(max_gap_s)
        self._held = math.nan
        self._acc = 0.0
        self._peak = 0.0
        """The highest accumulator value the model stood at (see :attr:`peak_level_pct`)."""
        self.stale_gaps = 0
        """Gaps longer than ``max_gap_s`` seen so far."""

    # -- what each model defines ------------------------------------------------

    @property
    @abstractmethod
    def trip_level(self) -> float:
        """The accumulator value at which the model trips (A²s, or θ = 1)."""

    @abstractmethod
    def _accumulate(self, held: FloatArray, dt: FloatArray) -> FloatArray:
        """The accumulator after each step: |I| = ``held[i]`` for ``dt[i]`` s (0: no step), from the present one.

        The same floats as :meth:`_integrate` one step after the other (the screen of long runs).
        """

    @abstractmethod
    def _integrate(self, held: float, dt: float) -> float:
        """The accumulator after ``dt`` > 0 s at a constant ``held`` A from the present one (the kernel's step)."""

    @abstractmethod
    def params(self) -> dict[str, float | None]:
        """The model's parameters, JSON-able (inf as None)."""

    @abstractmethod
    def time_to_trip(self, current_a: float) -> float:
        """Seconds until a trip from the present state at a constant ``current_a`` (inf: never)."""

    # -- shared -------------------------------------------------------------------

    @property
    def accumulator(self) -> float:
        """The raw state: A (A²s) for the leaky bucket, θ for the thermal image."""
        return self._acc

    @property
    def held_a(self) -> float:
        """The |I| held since the latest sample (A; NaN before any sample and after a restore)."""
        return self._held

    @property
    def level(self) -> float:
        """The state as a fraction of the trip level (1.0 = trip); may exceed 1."""
        return self._acc / self.trip_level

    @property
    def peak_level_pct(self) -> float:
        """The highest level the model stood at, in % of the trip level (the replay summary's I²t peak).

        Taken over every sample the model took (the heat moves only at samples, so this is the
        true peak, not the level seen at ticks) and the states it was put in (a restore, a reload's
        carry, the worst case); a :meth:`rewind` takes it back with the rest of the state.
        """
        return 100.0 * (self._peak / self.trip_level)

    def _set_acc(self, acc: float) -> None:
        cap = MAX_LEVEL * self.trip_level
        if math.isnan(acc):  # unreachable by construction; fail safe if it ever happens
            acc = cap
        self._acc = min(max(acc, 0.0), cap)
        if self._acc > self._peak:
            self._peak = self._acc

    def carry_from(self, old: ProtectionModel) -> None:
        """The base state plus the heat, as a fraction of the trip level (as a restore does), and the held current.

        Thresholds or the model kind may differ: the new model starts exactly as close to
        tripping as the old one stood, not cold (that would not be fail safe).
        """
        super().carry_from(old)
        if isinstance(old, _I2tModel):
            self._set_acc(old.level * self.trip_level)
            self._held = old.held_a
            self.stale_gaps = old.stale_gaps

    def _step(self, t: float, a: float) -> bool:
        """The kernel: integrate the held |I| up to ``t`` (a stale gap cut to ``max_gap_s``), hold ``a``, decide.

        Trips when the level reaches 1, recovers when it falls below ``recover_fraction``.
        """
        if self._last_t is not None and not math.isnan(self._held):
            dt = t - self._last_t
            if dt > self.max_gap_s:
                self.stale_gaps += 1
                dt = self.max_gap_s
            if dt > 0:
                acc = self._acc = self._integrate(self._held, dt)
                if acc > self._peak:
                    self._peak = acc
        self._held = a
        return self._decide(self._acc / self.trip_level)

    def _decide(self, level: float) -> bool:
        """The tripped state at ``level``: tripped from 1 on, recovered below ``recover_fraction``, else held."""
        if level >= 1.0:
            return True
        return self._tripped and level >= self.recover_fraction

    def _screen(self, t: FloatArray, a: FloatArray) -> _Screen:
        """The accumulator after each sample (see :meth:`_accumulate`), marked where the level can flip the state.

        The time steps are the time column's differences (the first against the
        previous run's last sample), cut to ``max_gap_s`` (a stale gap) and zero where
        nothing is integrated (before any sample, a repeated timestamp).
        """
        import numpy as np

        held = np.empty(a.size)
        held[0] = self._held
        held[1:] = a[:-1]
        dt = np.empty(a.size)
        dt[0] = math.nan if self._last_t is None else t[0] - self._last_t
        np.subtract(t[1:], t[:-1], out=dt[1:])
        stale = dt > self.max_gap_s
        stale[0] &= not math.isnan(self._held)
        dt = np.where(np.isnan(held) | ~(dt > 0), 0.0, np.minimum(dt, self.max_gap_s))
        acc = self._accumulate(held, dt)
        level = acc / self.trip_level
        return _Screen(a, acc, level >= 1.0, level < self.recover_fraction, np.cumsum(stale))

    def _rest(self, screen: Screen, first: int, last: int) -> None:
        """Quiet samples: the accumulator the screen found after the last one, its current held, its stale gaps."""
        assert isinstance(screen, _Screen)
        self._acc = float(screen.acc[last])
        self._held = float(screen.a[last])
        self.stale_gaps += int(screen.stale[last] - (screen.stale[first - 1] if first else 0))

    def _finish(self, screen: Screen, last: int) -> None:
        """The peak over the samples taken: the screen's accumulator is the kernel's, sample for sample."""
        assert isinstance(screen, _Screen)
        top = float(screen.acc[: last + 1].max())
        if top > self._peak:
            self._peak = top

    def _threshold_value(self) -> float:
        return self.trip_level

    def _level_pct(self) -> float:
        return 100.0 * self.level

    def set_hot(self, t: float | None = None) -> None:
        """Worst case: put the state at the trip level (the model trips; ``t`` becomes ``since``)."""
        self._set_acc(self.trip_level)
        self._set_tripped(True, t)

    def export(self) -> dict[str, Any]:
        """The state as a JSON-able dict: kind, version, parameters, accumulator, level, tripped, time."""
        return {
            "kind": self.kind,
            "version": STATE_VERSION,
            "params": self.params(),
            "accumulator": self._acc,
            "level": self.level,
            "tripped": self._tripped,
            "t": self._last_t,
        }

    def restore(self, state: Mapping[str, Any], downtime_s: float) -> None:
        """Take over an exported state cooled for ``downtime_s`` seconds (see the module docstring).

        The level is carried over even when the saved parameters or kind differ.
        The model is tripped after it when the cooled level is >= 1, or when the
        saved model was tripped and the level has not yet fallen below
        ``recover_fraction``. The sample history restarts (the next sample only
        sets the held current). ValueError on a malformed state (the model is
        left unchanged).
        """
        lvl = cooled_level(state, downtime_s)
        was_tripped = state.get("tripped") is True
        self._set_acc(lvl * self.trip_level)
        self._last_t = None
        self._held = self._value = math.nan
        self._tripped = self.level >= 1.0 or (was_tripped and self.level >= self.recover_fraction)
        self._latch = self._tripped
        self._since = None


class LeakyI2t(_I2tModel):
    """Leaky-bucket I²t (servo-drive style); reason ``i2t``.

    ``continuous_a`` (A, > 0), ``peak_a`` (A, > continuous_a), ``peak_time_s`` (s,
    > 0): trip level S = (peak_a² − continuous_a²)·peak_time_s A²s.
    ``recover_fraction`` (0..1 exclusive, default 0.5), ``max_gap_s`` (s, default
    inf; pass the source's max_age_s). ValueError naming the parameter at fault.
    """

    kind = KIND_LEAKY
    THRESHOLD_UNIT = AMPERE2_SECOND

    def __init__(
        self,
        continuous_a: float,
        peak_a: float,
        peak_time_s: float,
        recover_fraction: float = 0.5,
        max_gap_s: float = math.inf,
    ) -> None:
        super().__init__(continuous_a, recover_fraction, max_gap_s)
        self.peak_a = _positive("peak_a", peak_a)
        self.peak_time_s = _positive("peak_time_s", peak_time_s)
        if self.peak_a <= self.continuous_a:
            raise ValueError(f"peak_a ({peak_a!r} A) must exceed continuous_a ({continuous_a!r} A)")
        self._s = (self.peak_a**2 - self.continuous_a**2) * self.peak_time_s

    @property
    def trip_level(self) -> float:
        """S = (peak_a² − continuous_a²)·peak_time_s, in A²s."""
        return self._s

    def _accumulate(self, held: FloatArray, dt: FloatArray) -> FloatArray:
        """A running sum of ``(I² − I_cont²)·dt`` floored at 0 and capped (see :func:`clamped_sum`)."""
        import numpy as np

        c2 = self.continuous_a * self.continuous_a
        with np.errstate(invalid="ignore", over="ignore"):
            rate = held * held - c2
            steps = np.where(dt > 0, rate * dt, 0.0)
        return clamped_sum(self._acc, steps, MAX_LEVEL * self._s, self._add)

    def _quiet_side(self, t: Any, low_a: float, high_a: float) -> bool:
        """An empty bucket (not tripped) that stays empty: every current held through the run at or below
        I_cont (each step adds <= 0 to a sum floored at 0), and no gap over ``max_gap_s`` to count."""
        if self._acc != 0.0 or self._tripped:
            return False
        cont = self.continuous_a
        if self._held > cont or high_a > cont:  # a NaN held (no sample yet) integrates nothing
            return False
        if self.max_gap_s == math.inf:
            return True
        last = self._last_t
        return not ((last is not None and float(t[0]) - last > self.max_gap_s) or longest_step(t) > self.max_gap_s)

    def _take_quiet(self, final_a: float) -> None:
        """The last sample's current is held from now on; the bucket stays empty."""
        self._held = final_a

    def _integrate(self, held: float, dt: float) -> float:
        """A + (I² − I_cont²)·dt, floored at 0 and capped."""
        return self._add(self._acc, (held * held - self.continuous_a * self.continuous_a) * dt)

    def _add(self, acc: float, step: float) -> float:
        """The leaky sum's one step: ``acc + step`` floored at 0 and capped at MAX_LEVEL trip levels."""
        out = acc + step
        if out < 0.0:
            return 0.0
        cap = MAX_LEVEL * self._s
        return cap if not out <= cap else out

    def params(self) -> dict[str, float | None]:
        """continuous_a, peak_a, peak_time_s, recover_fraction, max_gap_s (None = inf)."""
        return {
            "continuous_a": self.continuous_a,
            "peak_a": self.peak_a,
            "peak_time_s": self.peak_time_s,
            "recover_fraction": self.recover_fraction,
            "max_gap_s": _json_float(self.max_gap_s),
        }

    def time_to_trip(self, current_a: float) -> float:
        """(S − A) / (I² − I_cont²) from the present A; 0 when already there, inf when I <= I_cont."""
        if self._acc >= self._s:
            return 0.0
        rate = current_a * current_a - self.continuous_a**2
        return (self._s - self._acc) / rate if rate > 0 else math.inf


def thermal_tau(continuous_a: float, peak_a: float, peak_time_s: float) -> float:
    """τ = t_peak / ln(I_peak² / (I_peak² − I_cont²)).

    The τ with which a cold thermal image trips at ``peak_a`` after ``peak_time_s``.
    """
    p2, c2 = peak_a * peak_a, continuous_a * continuous_a
    return peak_time_s / math.log(p2 / (p2 - c2))


class ThermalI2t(_I2tModel):
    """First-order thermal image (IEC 60255-8); θ in units of the steady state at I_cont; reason ``i2t``.

    ``continuous_a`` (A, > 0) is I_cont = k·I_rated. τ is ``tau_s`` (s) when given,
    otherwise derived from ``peak_a`` (A, > continuous_a) and ``peak_time_s`` (s) by
    :func:`thermal_tau`. ``tau_cool_s`` (s, default τ) applies while θ falls.
    ``recover_fraction`` (default 0.5), ``max_gap_s`` (s, default inf).
    ValueError naming the parameter at fault, e.g. when neither ``tau_s`` nor
    both peak figures are given.
    """

    kind = KIND_THERMAL
    THRESHOLD_UNIT = THETA

    def __init__(
        self,
        continuous_a: float,
        peak_a: float | None = None,
        peak_time_s: float | None = None,
        tau_s: float | None = None,
        tau_cool_s: float | None = None,
        recover_fraction: float = 0.5,
        max_gap_s: float = math.inf,
    ) -> None:
        super().__init__(continuous_a, recover_fraction, max_gap_s)
        self.peak_a = None if peak_a is None else _positive("peak_a", peak_a)
        self.peak_time_s = None if peak_time_s is None else _positive("peak_time_s", peak_time_s)
        if self.peak_a is not None and self.peak_a <= self.continuous_a:
            raise ValueError(f"peak_a ({peak_a!r} A) must exceed continuous_a ({continuous_a!r} A)")
        if tau_s is not None:
            self.tau_s = _positive("tau_s", tau_s)
        elif self.peak_a is not None and self.peak_time_s is not None:
            self.tau_s = thermal_tau(self.continuous_a, self.peak_a, self.peak_time_s)
        else:
            raise ValueError(
                "tau_s is required unless both peak_a and peak_time_s are given "
                f"(got tau_s=None, peak_a={peak_a!r}, peak_time_s={peak_time_s!r})"
            )
        self.tau_cool_s = self.tau_s if tau_cool_s is None else _positive("tau_cool_s", tau_cool_s)
        self._c2 = self.continuous_a * self.continuous_a

    @property
    def trip_level(self) -> float:
        """θ = 1."""
        return 1.0

    def _accumulate(self, held: FloatArray, dt: FloatArray) -> FloatArray:
        """θ ← q + (θ − q)·exp(−dt/τ) per step, q = I²/I_cont² (capped), τ the cooling one while q < θ.

        The time constant depends on the state (heating or cooling), so the steps run
        one after the other, over plain floats (the columns prepared by numpy).
        """
        import numpy as np

        with np.errstate(invalid="ignore", over="ignore"):
            q = np.minimum(held * held / self._c2, MAX_LEVEL)
        return np.asarray(thermal_steps(self._acc, q.tolist(), dt.tolist(), self.tau_s, self.tau_cool_s, MAX_LEVEL))

    def _integrate(self, held: float, dt: float) -> float:
        """θ after one step (the same :func:`thermal_steps` the screen runs over a column)."""
        q = min(held * held / self._c2, MAX_LEVEL)
        return thermal_steps(self._acc, (q,), (dt,), self.tau_s, self.tau_cool_s, MAX_LEVEL)[0]

    def params(self) -> dict[str, float | None]:
        """continuous_a, peak_a, peak_time_s, tau_s and tau_cool_s (resolved), recover_fraction, max_gap_s."""
        return {
            "continuous_a": self.continuous_a,
            "peak_a": self.peak_a,
            "peak_time_s": self.peak_time_s,
            "tau_s": self.tau_s,
            "tau_cool_s": self.tau_cool_s,
            "recover_fraction": self.recover_fraction,
            "max_gap_s": _json_float(self.max_gap_s),
        }

    def time_to_trip(self, current_a: float) -> float:
        """τ·ln((q − θ)/(q − 1)) with q = I²/I_cont², from the present θ; 0 when θ >= 1, inf when q <= 1."""
        if self._acc >= 1.0:
            return 0.0
        q = current_a * current_a / self._c2
        if q <= 1.0:
            return math.inf
        return self.tau_s * math.log((q - self._acc) / (q - 1.0))
