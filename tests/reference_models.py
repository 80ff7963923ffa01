"""The per-sample maths the protection models were first written as: the reference for their run methods.

Each class here takes one sample at a time, exactly as the models did before they advanced
over runs (plain Python floats, one branch per rule). The differential tests feed the same
samples to a reference and to a model, as runs of one, one long run and runs split at random
points, and hold them equal: every trip and recovery at the same sample, values within 1e-9
relative. Nothing in ``src/`` imports this module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from canguard.io.frame import INVALID_INF, INVALID_NAN, INVALID_RANGE
from canguard.protect.base import REASON_NO_DATA, REASON_NOT_PRESENT, REASON_OK, REASON_STALE, TIME_EPS_S
from canguard.protect.i2t import MAX_LEVEL
from canguard.protect.staleness import COUNTER, PRESENT, REASON_FROZEN


@dataclass
class RefLatched:
    """The shared bookkeeping: the sample filter, tripped state, edge time, latest value."""

    tripped: bool = False
    since: float | None = None
    value: float = math.nan
    last_t: float | None = None

    def accept(self, value: float, t: float) -> float | None:
        """|value| when the sample may be used, None when it must be ignored."""
        if not (math.isfinite(value) and math.isfinite(t)):
            return None
        if self.last_t is not None and t < self.last_t:
            return None
        return abs(value)

    def set_tripped(self, tripped: bool, t: float) -> bool:
        """Enter ``tripped``; True on an edge."""
        if tripped == self.tripped:
            return False
        self.tripped, self.since = tripped, t
        return True


@dataclass
class RefThreshold(RefLatched):
    """Tripped while |value| > max_value."""

    max_value: float = 10.0

    def update(self, value: float, t: float) -> bool:
        """One sample; True on an edge."""
        a = self.accept(value, t)
        if a is None:
            return False
        self.last_t, self.value = t, a
        return self.set_tripped(a > self.max_value, t)


@dataclass
class RefInrush:
    """Motor starts and blanking windows, one sample at a time."""

    start_current_a: float = 2.0
    inrush_time_s: float = 0.1
    inrush_threshold_a: float | None = None
    below_since: float | None = None
    window_start: float | None = None
    last_t: float | None = None

    def observe(self, a: float, t: float) -> bool:
        """One |I| sample; True on a motor start."""
        if not (math.isfinite(a) and math.isfinite(t)) or (self.last_t is not None and t < self.last_t):
            return False
        self.last_t = t
        if a <= self.start_current_a:
            if self.below_since is None:
                self.below_since = t
            return False
        started = self.below_since is not None and t - self.below_since >= self.inrush_time_s - TIME_EPS_S
        self.below_since = None
        if started:
            self.window_start = t
        return started

    def threshold(self, normal: float, t: float) -> float | None:
        """The overcurrent threshold in force at ``t``."""
        w = self.window_start
        if w is not None and w <= t < w + self.inrush_time_s - TIME_EPS_S:
            return self.inrush_threshold_a
        return normal


@dataclass
class RefHysteresis(RefLatched):
    """Trip at >= overcurrent_a, recover at <= recovery_a, with persistence timers, gaps and inrush."""

    overcurrent_a: float = 35.0
    recovery_a: float = 25.0
    trip_after_s: float = 0.0
    recover_after_s: float = 0.0
    max_gap_s: float = math.inf
    inrush: RefInrush | None = None
    over_since: float | None = None
    under_since: float | None = None

    def update(self, value: float, t: float) -> bool:
        """One sample; True on an edge."""
        a = self.accept(value, t)
        if a is None:
            return False
        if self.last_t is not None and t - self.last_t > self.max_gap_s:
            self.over_since = self.under_since = None
        self.last_t, self.value = t, a
        if self.inrush is not None:
            self.inrush.observe(a, t)
        if not self.tripped:
            thr = self.overcurrent_a if self.inrush is None else self.inrush.threshold(self.overcurrent_a, t)
            if thr is not None and a >= thr:
                if self.over_since is None:
                    self.over_since = t
                if t - self.over_since >= self.trip_after_s - TIME_EPS_S:
                    self.over_since = None
                    return self.set_tripped(True, t)
            else:
                self.over_since = None
            return False
        if a <= self.recovery_a:
            if self.under_since is None:
                self.under_since = t
            if t - self.under_since >= self.recover_after_s - TIME_EPS_S:
                self.under_since = None
                return self.set_tripped(False, t)
        else:
            self.under_since = None
        return False


@dataclass
class RefI2t(RefLatched):
    """Leaky bucket (``kind="leaky"``) or thermal image (``"thermal"``), zero-order hold, exact per interval."""

    kind: str = "leaky"
    continuous_a: float = 6.0
    peak_a: float = 12.0
    peak_time_s: float = 1.0
    tau_s: float = 1.0
    tau_cool_s: float = 1.0
    recover_fraction: float = 0.5
    max_gap_s: float = math.inf
    acc: float = 0.0
    held: float = math.nan
    peak: float = 0.0
    """The highest accumulator value so far."""
    trip_level: float = field(init=False)

    def __post_init__(self) -> None:
        leaky = (self.peak_a**2 - self.continuous_a**2) * self.peak_time_s
        self.trip_level = leaky if self.kind == "leaky" else 1.0

    def set_acc(self, acc: float) -> None:
        """Store the accumulator, floored at 0 and capped at MAX_LEVEL trip levels."""
        cap = MAX_LEVEL * self.trip_level
        self.acc = cap if math.isnan(acc) else min(max(acc, 0.0), cap)
        self.peak = max(self.peak, self.acc)

    def integrate(self, current_a: float, dt: float) -> None:
        """Advance the accumulator by ``dt`` > 0 s at a constant ``current_a``."""
        if self.kind == "leaky":
            rate = current_a * current_a - self.continuous_a * self.continuous_a
            if rate != 0:
                self.set_acc(self.acc + rate * dt)
            return
        q = min(current_a * current_a / (self.continuous_a * self.continuous_a), MAX_LEVEL)
        tau = self.tau_cool_s if q < self.acc else self.tau_s
        self.set_acc(q + (self.acc - q) * math.exp(-dt / tau))

    def update(self, value: float, t: float) -> bool:
        """One sample; True on an edge."""
        a = self.accept(value, t)
        if a is None:
            return False
        if self.last_t is not None and not math.isnan(self.held):
            dt = t - self.last_t
            if dt > self.max_gap_s:
                dt = self.max_gap_s
            if dt > 0:
                self.integrate(self.held, dt)
        self.last_t, self.value, self.held = t, a, a
        level = self.acc / self.trip_level
        if level >= 1.0:
            return self.set_tripped(True, t)
        if self.tripped and level < self.recover_fraction:
            return self.set_tripped(False, t)
        return False


@dataclass
class RefHealth:
    """Freshness, presence and validity of one source, one sample at a time (no fast path)."""

    max_age_s: float
    value_roles: tuple[str, ...]
    has_present: bool = False
    ranges: dict[str, tuple[float | None, float | None]] = field(default_factory=dict)
    latest_t: dict[str, float] = field(default_factory=dict)
    invalid: dict[str, str] = field(default_factory=dict)
    values: dict[str, float] = field(default_factory=dict)
    valid_t: dict[str, float] = field(default_factory=dict)
    last_reason: str = REASON_NO_DATA
    counter: float | None = None
    counter_since: float = math.nan
    frozen: bool = False

    def check(self, role: str, value: float, reason: str) -> str:
        """The sample's invalid reason."""
        if reason:
            return reason
        if math.isnan(value):
            return INVALID_NAN
        if math.isinf(value):
            return INVALID_INF
        lo, hi = self.ranges.get(role, (None, None))
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            return INVALID_RANGE
        return ""

    def observe(self, role: str, t: float, value: float, reason: str = "") -> bool:
        """One sample; True when the source's reason changed."""
        latest = self.latest_t.get(role)
        if math.isnan(t) or (latest is not None and t < latest):
            return False
        bad = self.check(role, value, reason)
        if (not bad and latest is not None and role not in (PRESENT, COUNTER)
                and t - latest <= self.max_age_s and not self.invalid.get(role)):
            self.latest_t[role], self.values[role], self.valid_t[role] = t, value, t
            return False
        before = self.reason(t)
        if role == COUNTER and not bad:
            if value != self.counter:
                self.counter, self.counter_since = value, t
            self.frozen = t - self.counter_since > self.max_age_s
        self.latest_t[role] = t
        self.invalid[role] = bad
        if not bad:
            self.values[role], self.valid_t[role] = value, t
        after = self.reason(t)
        edge = after != before or after != self.last_reason
        self.last_reason = after
        return edge

    def role_reason(self, now: float, role: str) -> str:
        """One role's reason at ``now``."""
        t = self.latest_t.get(role)
        if t is None:
            return REASON_NO_DATA
        if now - t > self.max_age_s:
            return REASON_STALE
        bad = self.invalid.get(role, "")
        if bad:
            return bad
        if role == PRESENT and self.values.get(PRESENT, 0.0) == 0:
            return REASON_NOT_PRESENT
        return REASON_OK

    def reason(self, now: float, role: str | None = None) -> str:
        """The source's (or a role's) reason at ``now``."""
        if self.frozen:
            return REASON_FROZEN
        if self.has_present:
            r = self.role_reason(now, PRESENT)
            if r or role == PRESENT:
                return r
        if role is not None:
            return self.role_reason(now, role)
        for name in self.value_roles:
            r = self.role_reason(now, name)
            if r:
                return r
        return REASON_OK
