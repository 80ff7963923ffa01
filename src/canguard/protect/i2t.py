"""I²t protection: how much heat the current has put into the motor (docs/protection.md has the maths).

:class:`LeakyI2t` (``A' = I² − I_cont²`` floored at 0) and :class:`ThermalI2t` (IEC 60255-8,
``θ' = (I²/I_cont² − θ)/τ``); ``export`` / ``restore``: :mod:`canguard.protect.state`.
"""

from __future__ import annotations

import math
from abc import abstractmethod
from collections.abc import Mapping
from typing import Any

from canguard.protect.base import REASON_I2T, LatchedModel, ProtectionModel, check_gap, check_limit
from canguard.protect.columns import longest_step
from canguard.protect.state import KIND_LEAKY, KIND_THERMAL, cooled_level
from canguard.units import AMPERE2_SECOND, THETA

STATE_VERSION = 1
MAX_LEVEL = 1e6
"""The accumulator is capped at this many trip levels (keeps it finite)."""
RATED_OVERLOAD = 1.5
"""Without a datasheet peak the peak point is this many times the rating (IEC 60034-1 occasional excess)."""
RATED_OVERLOAD_S = 120.0
"""... allowed for this long from cold (IEC 60034-1: 1.5 × I_rated for 2 minutes)."""


class _I2tModel(LatchedModel):
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
        self.held_a = math.nan
        """The |I| held since the latest sample (A; NaN before any and after a restore)."""
        self.accumulator = 0.0
        """The raw state: A (A²s) for the leaky bucket, θ for the thermal image."""
        self._peak = 0.0

    @abstractmethod
    def _integrate(self, held: float, dt: float) -> float:
        """The accumulator after ``dt`` > 0 s at a constant ``held`` A from the present one."""

    def params(self) -> dict[str, float | None]:
        """The model's parameters, JSON-able (inf as None)."""
        return {"continuous_a": self.continuous_a, "peak_a": self.peak_a, "peak_time_s": self.peak_time_s,
                "recover_fraction": self.recover_fraction,
                "max_gap_s": None if self.max_gap_s == math.inf else self.max_gap_s}

    @property
    def level(self) -> float:
        """The state as a fraction of the trip level (1.0 = trip); may exceed 1."""
        return self.accumulator / self.trip_level

    @property
    def peak_level_pct(self) -> float:
        """The highest level the model stood at (samples, restores, carries), in % of the trip level."""
        return 100.0 * (self._peak / self.trip_level)

    def _set_acc(self, acc: float) -> None:
        cap = MAX_LEVEL * self.trip_level
        if math.isnan(acc):  # unreachable by construction; fail safe if it ever happens
            acc = cap
        self.accumulator = min(max(acc, 0.0), cap)
        if self.accumulator > self._peak:
            self._peak = self.accumulator

    def carry_from(self, old: ProtectionModel) -> None:
        """The base state, the held current and the heat as a fraction of the trip level (as a restore does)."""
        super().carry_from(old)
        if isinstance(old, _I2tModel):
            self._set_acc(old.level * self.trip_level)
            self.held_a = old.held_a

    def _step(self, t: float, a: float) -> bool:
        """Integrate the held |I| up to ``t`` (a stale gap cut to ``max_gap_s``), hold ``a``, decide."""
        if self.last_t is not None and not math.isnan(self.held_a):
            dt = t - self.last_t
            if dt > self.max_gap_s:  # a stale gap integrates as max_gap_s
                dt = self.max_gap_s
            if dt > 0:
                acc = self.accumulator = self._integrate(self.held_a, dt)
                if acc > self._peak:
                    self._peak = acc
        self.held_a = a
        level = self.accumulator / self.trip_level
        return level >= 1.0 or (self._tripped and level >= self.recover_fraction)

    def _levels(self) -> tuple[float, float]:
        return self.trip_level, 100.0 * self.level

    def set_hot(self, t: float | None = None) -> None:
        """Worst case: put the state at the trip level; the model trips (``t`` becomes ``since``). Only the trip edge
        arms the latch: a trip already reported is not reported again."""
        self._set_acc(self.trip_level)
        if not self._tripped:
            self._tripped = self._latch = True
            self.since = t

    def export(self) -> dict[str, Any]:
        """The state as a JSON-able dict: kind, version, parameters, accumulator, level, tripped, time."""
        return {"kind": self.kind, "version": STATE_VERSION, "params": self.params(), "accumulator": self.accumulator,
                "level": self.level, "tripped": self._tripped, "t": self.last_t}

    def restore(self, state: Mapping[str, Any], downtime_s: float) -> None:
        """Take over an exported state cooled for ``downtime_s`` s, whatever the saved parameters or kind: tripped when
        the cooled level is >= 1, or was tripped and is not below ``recover_fraction``. ValueError: malformed."""
        lvl = cooled_level(state, downtime_s)
        was_tripped = state.get("tripped") is True
        self._set_acc(lvl * self.trip_level)
        self.last_t = None
        self.held_a = self._value = math.nan
        self._tripped = self.level >= 1.0 or (was_tripped and self.level >= self.recover_fraction)
        self._latch = self._tripped
        self.since = None


class LeakyI2t(_I2tModel):
    """Leaky-bucket I²t (servo-drive style), reason ``i2t``: trip level S = (peak_a² − continuous_a²)·peak_time_s."""

    kind = KIND_LEAKY
    THRESHOLD_UNIT = AMPERE2_SECOND

    def __init__(self, continuous_a: float, peak_a: float, peak_time_s: float, recover_fraction: float = 0.5,
                 max_gap_s: float = math.inf) -> None:
        super().__init__(continuous_a, recover_fraction, max_gap_s, peak_a, peak_time_s)
        assert self.peak_a is not None and self.peak_time_s is not None
        self.trip_level = (self.peak_a**2 - self.continuous_a**2) * self.peak_time_s

    def _quiet(self, t: Any, low_a: float, high_a: float, final_a: float) -> bool:
        """An empty bucket that stays empty: every current held at or below I_cont, no stale gap to count."""
        if self.accumulator != 0.0 or self._tripped:
            return False
        cont = self.continuous_a
        if self.held_a > cont or high_a > cont:  # a NaN held (no sample yet) integrates nothing
            return False
        last = self.last_t
        if self.max_gap_s != math.inf and (
                (last is not None and float(t[0]) - last > self.max_gap_s) or longest_step(t) > self.max_gap_s):
            return False
        self.held_a = final_a
        return True

    def _integrate(self, held: float, dt: float) -> float:
        """The leaky sum after one step, floored at 0 and capped."""
        out = self.accumulator + (held * held - self.continuous_a * self.continuous_a) * dt
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
    """First-order thermal image (IEC 60255-8), θ in units of the steady state at I_cont; reason ``i2t``. τ is
    ``tau_s``, else :func:`thermal_tau` of the peak point; ``tau_cool_s`` (default τ) while θ falls."""

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

    def _integrate(self, held: float, dt: float) -> float:
        """θ ← q + (θ − q)·exp(−dt/τ), τ ``tau_cool_s`` while q < θ, clamped to [0, MAX_LEVEL]."""
        q = min(held * held / self._c2, MAX_LEVEL)
        theta = self.accumulator
        theta = q + (theta - q) * math.exp(-dt / (self.tau_cool_s if q < theta else self.tau_s))
        return 0.0 if theta < 0.0 else (MAX_LEVEL if theta > MAX_LEVEL else theta)

    def params(self) -> dict[str, float | None]:
        """The shared parameters, and tau_s and tau_cool_s (resolved)."""
        return {**super().params(), "tau_s": self.tau_s, "tau_cool_s": self.tau_cool_s}
