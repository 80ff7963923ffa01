"""I²t protection: how much heat the current has put into the motor (docs/protection.md has the maths).

:class:`LeakyI2t` (``A' = I² − I_cont²`` floored at 0) and :class:`ThermalI2t` (IEC 60255-8,
``θ' = (I²/I_cont² − θ)/τ``); ``export`` / ``restore``: :mod:`canguard.protect.state`.
"""

from __future__ import annotations

import math
from abc import abstractmethod
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

from canguard.protect.base import REASON_I2T, LatchedModel, ProtectionModel, check_gap, check_limit
from canguard.protect.columns import Screen, longest_step
from canguard.protect.state import KIND_LEAKY, KIND_THERMAL, cooled_level
from canguard.units import AMPERE2_SECOND, THETA

if TYPE_CHECKING:
    import numpy as np

    from canguard.protect.columns import BoolArray, FloatArray, IndexArray

STATE_VERSION = 1
MAX_LEVEL = 1e6
"""The accumulator is capped at this many trip levels (keeps it finite)."""
RATED_OVERLOAD = 1.5
"""Without a datasheet peak the peak point is this many times the rating (IEC 60034-1 occasional excess)."""
RATED_OVERLOAD_S = 120.0
"""... allowed for this long from cold (IEC 60034-1: 1.5 × I_rated for 2 minutes)."""


def next_where(mask: np.ndarray) -> np.ndarray:
    """For each position, the first position at or after it where ``mask`` is set (``len``: none)."""
    import numpy as np

    n = mask.size
    pos = np.where(mask, np.arange(n), n)
    return np.minimum.accumulate(pos[::-1])[::-1]


def clamped_sum(start: float, steps: FloatArray, cap: float, add: Callable[[float, float], float]) -> FloatArray:
    """The running sum ``acc ← add(acc, step)`` from ``start``, after each step; ``add`` bounds it to [0, ``cap``].

    The same floats as ``add`` step by step: between bounds a sequential ``numpy.add.accumulate`` adds in
    the same order; at a bound ``add`` takes the step and the steps that keep it there are skipped as a
    block. Windows double while no bound is hit.
    """
    import numpy as np

    n = steps.size
    out = np.empty(n)
    stays: tuple[np.ndarray, np.ndarray] | None = None  # where each bound is left, found at the first hit
    acc, pos, size = float(start), 0, 64
    while pos < n:
        end = min(n, pos + size)
        run = np.add.accumulate(np.concatenate(((acc,), steps[pos:end])))[1:]
        hit = (~((run >= 0.0) & (run <= cap))).nonzero()[0]
        if not hit.size:
            out[pos:end] = run
            acc, pos, size = float(run[-1]), end, 2 * size
            continue
        p = pos + int(hit[0])
        out[pos:p] = run[: p - pos]
        acc = add(float(out[p - 1]) if p > pos else acc, float(steps[p]))
        if p + 1 == n:
            out[p] = acc
            break
        if stays is None:
            stays = next_where(steps > 0), next_where(steps < 0)
        stay = int(stays[acc != 0.0][p + 1])
        out[p:stay] = acc
        pos, size = stay, 64
    return out


def thermal_steps(theta: float, q: Sequence[float], dt: Sequence[float], tau_heat: float, tau_cool: float,
                  cap: float) -> list[float]:
    """θ after each step ``θ ← q + (θ − q)·exp(−dt/τ)`` (none where dt is 0), clamped to [0, ``cap``].

    τ is ``tau_cool`` while ``q < θ``, else ``tau_heat``: the state picks it, so the steps run one by one.
    """
    exp = math.exp
    out: list[float] = []
    append = out.append
    for qi, d in zip(q, dt, strict=True):
        if d > 0.0:
            theta = qi + (theta - qi) * exp(-d / (tau_cool if qi < theta else tau_heat))
            if theta < 0.0:
                theta = 0.0
            elif theta > cap:
                theta = cap
        append(theta)
    return out


class _Screen(Screen):
    """A long run's accumulator after each sample and its stale gaps; marked where the level may flip the state."""

    def __init__(self, a: FloatArray, acc: FloatArray, trip: BoolArray, low: BoolArray,
                 stale: IndexArray) -> None:
        super().__init__(trip, low)
        self.a, self.acc, self.stale = a, acc, stale


class _I2tModel(LatchedModel[_Screen]):
    """What both I²t models share: ``continuous_a`` is I_cont (A), ``peak_a`` / ``peak_time_s`` the datasheet's peak
    point, ``max_gap_s`` the source's max_age_s; ValueError naming the parameter at fault."""

    kind: str = ""
    reason_tripped = REASON_I2T
    trip_level: float
    """The accumulator value at which the model trips (A²s, or θ = 1)."""

    def __init__(self, continuous_a: float, recover_fraction: float, max_gap_s: float, peak_a: float | None,
                 peak_time_s: float | None) -> None:
        super().__init__()
        self.continuous_a = check_limit("continuous_a", continuous_a, positive=True)
        if not 0 < float(recover_fraction) < 1:
            raise ValueError(f"recover_fraction must be > 0 and < 1, got {recover_fraction!r}")
        self.recover_fraction = float(recover_fraction)
        self.max_gap_s = check_gap(max_gap_s)
        self.peak_a = None if peak_a is None else check_limit("peak_a", peak_a, positive=True)
        self.peak_time_s = None if peak_time_s is None else check_limit("peak_time_s", peak_time_s, positive=True)
        if self.peak_a is not None and self.peak_a <= self.continuous_a:
            raise ValueError(f"peak_a ({peak_a!r} A) must exceed continuous_a ({continuous_a!r} A)")
        self._held = math.nan
        self._acc = 0.0
        self._peak = 0.0
        self.stale_gaps = 0
        """Gaps longer than ``max_gap_s`` seen so far."""

    @abstractmethod
    def _accumulate(self, held: FloatArray, dt: FloatArray) -> FloatArray:
        """The accumulator after each step ``held[i]`` A for ``dt[i]`` s: :meth:`_integrate`'s floats, step by step."""

    @abstractmethod
    def _integrate(self, held: float, dt: float) -> float:
        """The accumulator after ``dt`` > 0 s at a constant ``held`` A from the present one."""

    def params(self) -> dict[str, float | None]:
        """The model's parameters, JSON-able (inf as None)."""
        return {"continuous_a": self.continuous_a, "peak_a": self.peak_a, "peak_time_s": self.peak_time_s,
                "recover_fraction": self.recover_fraction,
                "max_gap_s": None if self.max_gap_s == math.inf else self.max_gap_s}

    @property
    def accumulator(self) -> float:
        """The raw state: A (A²s) for the leaky bucket, θ for the thermal image."""
        return self._acc

    @property
    def held_a(self) -> float:
        """The |I| held since the latest sample (A; NaN before any and after a restore)."""
        return self._held

    @property
    def level(self) -> float:
        """The state as a fraction of the trip level (1.0 = trip); may exceed 1."""
        return self._acc / self.trip_level

    @property
    def peak_level_pct(self) -> float:
        """The highest level the model stood at (samples, restores, carries), in % of the trip level."""
        return 100.0 * (self._peak / self.trip_level)

    def _set_acc(self, acc: float) -> None:
        cap = MAX_LEVEL * self.trip_level
        if math.isnan(acc):  # unreachable by construction; fail safe if it ever happens
            acc = cap
        self._acc = min(max(acc, 0.0), cap)
        if self._acc > self._peak:
            self._peak = self._acc

    def carry_from(self, old: ProtectionModel) -> None:
        """The base state, the held current and the heat as a fraction of the trip level (as a restore does)."""
        super().carry_from(old)
        if isinstance(old, _I2tModel):
            self._set_acc(old.level * self.trip_level)
            self._held = old.held_a
            self.stale_gaps = old.stale_gaps

    def _step(self, t: float, a: float) -> bool:
        """Integrate the held |I| up to ``t`` (a stale gap cut to ``max_gap_s``), hold ``a``, decide."""
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
        level = self._acc / self.trip_level
        return level >= 1.0 or (self._tripped and level >= self.recover_fraction)

    def _screen(self, t: FloatArray, a: FloatArray) -> _Screen:
        """Steps: the time differences cut to ``max_gap_s``, zero where nothing is integrated."""
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

    def _rest(self, screen: _Screen, first: int, last: int) -> None:
        self._acc = float(screen.acc[last])
        self._held = float(screen.a[last])
        self.stale_gaps += int(screen.stale[last] - (screen.stale[first - 1] if first else 0))

    def _finish(self, screen: _Screen, last: int) -> None:
        top = float(screen.acc[: last + 1].max())
        if top > self._peak:
            self._peak = top

    def _levels(self) -> tuple[float, float]:
        return self.trip_level, 100.0 * self.level

    def set_hot(self, t: float | None = None) -> None:
        """Worst case: put the state at the trip level; the model trips (``t`` becomes ``since``).

        Only the trip edge arms the latch: a trip already reported is not reported again.
        """
        self._set_acc(self.trip_level)
        if not self._tripped:
            self._tripped = self._latch = True
            self._since = t

    def export(self) -> dict[str, Any]:
        """The state as a JSON-able dict: kind, version, parameters, accumulator, level, tripped, time."""
        return {"kind": self.kind, "version": STATE_VERSION, "params": self.params(), "accumulator": self._acc,
                "level": self.level, "tripped": self._tripped, "t": self._last_t}

    def restore(self, state: Mapping[str, Any], downtime_s: float) -> None:
        """Take over an exported state cooled for ``downtime_s`` seconds, whatever the saved parameters or kind.

        Tripped when the cooled level is >= 1, or was tripped and is not below ``recover_fraction``; the
        sample history restarts. ValueError on a malformed state (the model unchanged).
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
    """Leaky-bucket I²t (servo-drive style), reason ``i2t``: trip level S = (peak_a² − continuous_a²)·peak_time_s."""

    kind = KIND_LEAKY
    THRESHOLD_UNIT = AMPERE2_SECOND

    def __init__(self, continuous_a: float, peak_a: float, peak_time_s: float, recover_fraction: float = 0.5,
                 max_gap_s: float = math.inf) -> None:
        super().__init__(continuous_a, recover_fraction, max_gap_s, peak_a, peak_time_s)
        assert self.peak_a is not None and self.peak_time_s is not None
        self.trip_level = (self.peak_a**2 - self.continuous_a**2) * self.peak_time_s

    def _accumulate(self, held: FloatArray, dt: FloatArray) -> FloatArray:
        import numpy as np

        c2 = self.continuous_a * self.continuous_a
        with np.errstate(invalid="ignore", over="ignore"):
            rate = held * held - c2
            steps = np.where(dt > 0, rate * dt, 0.0)
        return clamped_sum(self._acc, steps, MAX_LEVEL * self.trip_level, self._add)

    def _quiet(self, t: Any, low_a: float, high_a: float, final_a: float) -> bool:
        """An empty bucket that stays empty: every current held at or below I_cont, no stale gap to count."""
        if self._acc != 0.0 or self._tripped:
            return False
        cont = self.continuous_a
        if self._held > cont or high_a > cont:  # a NaN held (no sample yet) integrates nothing
            return False
        last = self._last_t
        if self.max_gap_s != math.inf and (
                (last is not None and float(t[0]) - last > self.max_gap_s) or longest_step(t) > self.max_gap_s):
            return False
        self._held = final_a
        return True

    def _integrate(self, held: float, dt: float) -> float:
        return self._add(self._acc, (held * held - self.continuous_a * self.continuous_a) * dt)

    def _add(self, acc: float, step: float) -> float:
        """One step of the leaky sum, floored at 0 and capped."""
        out = acc + step
        if out < 0.0:
            return 0.0
        cap = MAX_LEVEL * self.trip_level
        return cap if not out <= cap else out


def thermal_tau(continuous_a: float, peak_a: float, peak_time_s: float) -> float:
    """τ = t_peak / ln(I_peak² / (I_peak² − I_cont²)): a cold thermal image trips at ``peak_a`` after
    ``peak_time_s``, as the leaky bucket of the same figures does."""
    p2, c2 = peak_a * peak_a, continuous_a * continuous_a
    return peak_time_s / math.log(p2 / (p2 - c2))


class ThermalI2t(_I2tModel):
    """First-order thermal image (IEC 60255-8), θ in units of the steady state at I_cont; reason ``i2t``.

    τ is ``tau_s``, else :func:`thermal_tau` of the peak point; ``tau_cool_s`` (default τ) while θ falls.
    """

    kind = KIND_THERMAL
    THRESHOLD_UNIT = THETA

    def __init__(self, continuous_a: float, peak_a: float | None = None, peak_time_s: float | None = None,
                 tau_s: float | None = None, tau_cool_s: float | None = None, recover_fraction: float = 0.5,
                 max_gap_s: float = math.inf) -> None:
        super().__init__(continuous_a, recover_fraction, max_gap_s, peak_a, peak_time_s)
        if tau_s is not None:
            self.tau_s = check_limit("tau_s", tau_s, positive=True)
        elif self.peak_a is not None and self.peak_time_s is not None:
            self.tau_s = thermal_tau(self.continuous_a, self.peak_a, self.peak_time_s)
        else:
            raise ValueError("tau_s is required unless both peak_a and peak_time_s are given "
                             f"(got tau_s=None, peak_a={peak_a!r}, peak_time_s={peak_time_s!r})")
        self.tau_cool_s = self.tau_s if tau_cool_s is None else check_limit("tau_cool_s", tau_cool_s, positive=True)
        self._c2 = self.continuous_a * self.continuous_a
        self.trip_level = 1.0

    def _accumulate(self, held: FloatArray, dt: FloatArray) -> FloatArray:
        import numpy as np

        with np.errstate(invalid="ignore", over="ignore"):
            q = np.minimum(held * held / self._c2, MAX_LEVEL)
        return np.asarray(thermal_steps(self._acc, q.tolist(), dt.tolist(), self.tau_s, self.tau_cool_s, MAX_LEVEL))

    def _integrate(self, held: float, dt: float) -> float:
        q = min(held * held / self._c2, MAX_LEVEL)
        return thermal_steps(self._acc, (q,), (dt,), self.tau_s, self.tau_cool_s, MAX_LEVEL)[0]

    def params(self) -> dict[str, float | None]:
        """The shared parameters, and tau_s and tau_cool_s (resolved)."""
        return {**super().params(), "tau_s": self.tau_s, "tau_cool_s": self.tau_cool_s}
