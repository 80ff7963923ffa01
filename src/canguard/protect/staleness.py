"""Staleness and validity of one source: is there a usable, fresh value? (docs/protection.md)

A drive's health roles gate every value, as ``present`` does, and are checked first. The latest sample decides,
but an invalid one never replaces the latest valid value.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from canguard.config.schema import NON_VALUE_ROLES, SourceConfig
from canguard.io.frame import INVALID_INF, INVALID_NAN, INVALID_RANGE
from canguard.protect.base import REASON_NO_DATA, REASON_NOT_PRESENT, REASON_OK, REASON_STALE
from canguard.protect.columns import longest_step, ordered, values_span
from canguard.protect.results import Run, edges, quiet_cached, quiet_run

PRESENT = "present"
"""The role of a source's presence signal."""
COUNTER = "counter"
REASON_FROZEN = "frozen_counter"
NMT, EMCY, FAULT = "nmt", "emcy", "fault"
"""A CANopen drive's health roles: NMT state (from the heartbeat), EMCY error register, statusword Fault bit."""
NMT_OPERATIONAL = 5
REASON_NO_HEARTBEAT = "no_heartbeat"
REASON_EMCY = "emcy"
REASON_DRIVE_FAULT = "drive_fault"
GATE_ROLES = (NMT, EMCY, FAULT)
ROW_ROLES = NON_VALUE_ROLES - {PRESENT}
"""Roles a replay block cannot take as columns: every row is fed."""

_BIG = 1.7976931348623157e308
"""The largest float: open range bounds, so that +-inf (and NaN) fail the range test."""
_ANY = (-_BIG, _BIG)
_PER_ROLE = ("_latest_t", "_invalid", "_value", "_valid_t")
"""The state kept per role (copied by :meth:`SourceHealth.mark`)."""


class SourceHealth:
    """Freshness, presence and validity of one source's signals (time is an argument)."""

    def __init__(self, source: SourceConfig) -> None:
        self.source = source
        self.max_age_s = float(source.max_age_s)
        self.value_roles: tuple[str, ...] = source.value_roles
        """The source's value roles, in config order (``present`` and ``counter`` are not value roles)."""
        self._has_present = source.signal(PRESENT) is not None
        self._gates = tuple(r for r in GATE_ROLES if source.signal(r) is not None)
        self._roles = frozenset(s.role for s in source.signals)
        nmt = source.signal(NMT)
        self._heartbeat_s = self.max_age_s if nmt is None or nmt.max_age_s is None else float(nmt.max_age_s)
        """How old the drive's heartbeat may be (its own timeout, not a TPDO's period)."""
        self._window_s = min(self.max_age_s, self._heartbeat_s)
        self._counter: float | None = None
        self._counter_since = math.nan
        self._frozen = False
        self.ranges: dict[str, tuple[float | None, float | None]] = {
            s.role: (s.minimum, s.maximum) for s in source.signals if s.minimum is not None or s.maximum is not None}
        """The DBC [min|max] of each role that has one: values outside are ``out_of_range``."""
        self._limits = {role: (-_BIG if lo is None else float(lo), _BIG if hi is None else float(hi))
                        for role, (lo, hi) in self.ranges.items()}
        self._latest_t: dict[str, float] = {}
        self._invalid: dict[str, str] = {}
        self._value: dict[str, float] = {}
        self._valid_t: dict[str, float] = {}
        self._last_reason = REASON_NO_DATA
        self._ok_since = math.nan
        """When every role was last usable, the oldest of their latest times (NaN: not known): within ``_window_s``
        of it :meth:`reason` is "" (only the full path can make a role unusable; it clears this)."""

    def latest_t(self, role: str) -> float | None:
        """Time of the latest sample of ``role``, valid or not (None: none yet)."""
        return self._latest_t.get(role)

    def advance(self, roles: Sequence[str], times: Sequence[float], columns: Sequence[Sequence[float]],
                reasons: Sequence[Sequence[str]] | None = None, *, until_edge: bool = False) -> Run:
        """Take a run of rows (row ``i``: ``columns[k][i]`` of ``roles[k]`` at ``times[i]``, its own invalid reason
        ``reasons[k][i]``) in arrival order; where the reason changed (``tripped``: unusable after the edge)."""
        n = len(times)
        if n == 1 and reasons is None:  # a live frame: each sample to the kernel, nothing built
            t = float(times[0])
            if len(roles) == 1:
                edge = self._sample(roles[0], t, float(columns[0][0]))
            else:
                edge = False
                for k, role in enumerate(roles):
                    if self._sample(role, t, float(columns[k][0])):
                        edge = True
            if not edge:
                return quiet_cached(1) or quiet_run(1)
            return edges((0,), (t,), (bool(self._last_reason),), 1)
        if reasons is None and n > 1:
            if self._quiet(roles, times, columns):
                self._take_quiet(roles, times, columns)
                return quiet_run(n)
            if type(times) is not list and type(times) is not tuple:  # numpy columns: sample by sample as floats
                times, columns = times.tolist(), [column.tolist() for column in columns]  # type: ignore[attr-defined]
        found: list[int] = []
        after: list[bool] = []
        taken = n
        sample = self._sample
        for i in range(n):
            t = times[i]
            edge = False
            for k, role in enumerate(roles):
                if sample(role, t, columns[k][i], reasons[k][i] if reasons is not None else ""):
                    edge = True
            if edge:
                found.append(i)
                after.append(bool(self._last_reason))
                if until_edge:
                    taken = i + 1
                    break
        if not found:
            return quiet_run(taken)
        return edges(found, [times[i] for i in found], after, taken)

    def take_quiet(self, parts: Sequence[tuple[Sequence[str], Sequence[float], Sequence[Sequence[float]]]]) -> bool:
        """Runs of rows from several messages (roles, times, columns; roles of their own), taken whole when each is
        quiet (a quiet sample only becomes its role's latest, so their order does not matter); False: none taken."""
        seen: set[str] = set()
        for roles, times, columns in parts:
            if not len(times) or not seen.isdisjoint(roles) or not self._quiet(roles, times, columns):
                return False
            seen.update(roles)
        for roles, times, columns in parts:
            self._take_quiet(roles, times, columns)
        return True

    def _take_quiet(self, roles: Sequence[str], times: Sequence[float], columns: Sequence[Sequence[float]]) -> None:
        last = float(times[-1])
        for role, column in zip(roles, columns, strict=True):
            self._latest_t[role] = self._valid_t[role] = last
            self._value[role] = float(column[-1])

    def _quiet(self, roles: Sequence[str], times: Sequence[float], columns: Sequence[Sequence[float]]) -> bool:
        """True when a run of rows changes nothing but each role's latest value: in order, fresh, valid, in range,
        no role whose value gates the reason (a presence flag only while set and staying set)."""
        if not ordered(times):
            return False
        first, final = float(times[0]), float(times[-1])
        max_age = self.max_age_s
        if final - first > max_age and longest_step(times) > max_age:
            return False
        latest_t, invalid = self._latest_t, self._invalid
        for role, column in zip(roles, columns, strict=True):
            latest = latest_t.get(role)
            if latest is None or not latest <= first or first - latest > max_age or invalid.get(role):
                return False
            if role in NON_VALUE_ROLES and not (role == PRESENT and self._present_quiet(roles, column)):
                return False
            lo, hi = self._limits.get(role, _ANY)
            span = values_span(column)
            if span is None or not (lo <= span[0] and span[1] <= hi):
                return False
        return True

    def _present_quiet(self, roles: Sequence[str], column: Sequence[float]) -> bool:
        """A presence flag that was set and stays set, in a run carrying every role of the source."""
        return (not self._last_reason and not self._frozen and bool(self._value.get(PRESENT))
                and bool(all(column) if type(column) is list or type(column) is tuple else column.all())  # type: ignore[attr-defined]
                and self._roles.issubset(roles))

    def _sample(self, role: str, t: float, value: float, own: str = "") -> bool:
        """The kernel: one sample of ``role`` at ``t`` (``own``: its own invalid reason); True on an edge."""
        latest = self._latest_t.get(role)
        if latest is not None:
            if not t >= latest:  # older than the latest, or a NaN time: ignored
                return False
            lo, hi = self._limits.get(role, _ANY)
            if not own and lo <= value <= hi and t - latest <= self.max_age_s and role not in NON_VALUE_ROLES \
                    and not self._invalid.get(role):
                self._latest_t[role] = self._valid_t[role] = t
                self._value[role] = value
                return False
        elif t != t:
            return False
        return self._full_step(role, t, value, self._invalid_code(role, value, own))

    def mark(self) -> dict[str, Any]:
        """The running state, to go back to with :meth:`rewind` (nothing is changed)."""
        state = self.__dict__.copy()
        for k in _PER_ROLE:
            state[k] = dict(state[k])
        return state

    def rewind(self, mark: dict[str, Any]) -> None:
        """Go back to the state :meth:`mark` gave, as if the runs taken since had not come."""
        self.__dict__.update(mark)
        for k in _PER_ROLE:  # copies again: a mark may be gone back to more than once
            self.__dict__[k] = dict(mark[k])

    def _invalid_code(self, role: str, value: float, own: str) -> str:
        if own:
            return own
        if math.isnan(value):
            return INVALID_NAN
        if math.isinf(value):
            return INVALID_INF
        lo, hi = self._limits.get(role, _ANY)
        return "" if lo <= value <= hi else INVALID_RANGE

    def _full_step(self, role: str, t: float, value: float, bad: str) -> bool:
        before = self.reason(t)
        if role == COUNTER and not bad:
            if value != self._counter:
                self._counter, self._counter_since = value, t
            self._frozen = t - self._counter_since > self.max_age_s
        self._latest_t[role] = t
        self._invalid[role] = bad
        if not bad:
            self._value[role] = value
            self._valid_t[role] = t
        self._ok_since = math.nan  # this sample may have made a role unusable
        after = self.reason(t)
        edge = after != before or after != self._last_reason
        self._last_reason = after
        return edge

    def _role_reason(self, now: float, role: str) -> str:
        """The reason of one role (an EMCY never goes stale)."""
        t = self._latest_t.get(role)
        if role == EMCY:
            return REASON_EMCY if t is not None and (self._invalid.get(role) or self._value.get(role, 0.0)) else ""
        if t is None:
            return REASON_NO_DATA
        if role == NMT:
            if now - t > self._heartbeat_s:
                return REASON_NO_HEARTBEAT
        elif now - t > self.max_age_s:
            return REASON_STALE
        bad = self._invalid.get(role, "")
        if bad:
            return bad
        if role == NMT:
            return REASON_NOT_PRESENT if self._value.get(NMT) != NMT_OPERATIONAL else REASON_OK
        if role == FAULT:
            return REASON_DRIVE_FAULT if self._value.get(FAULT, 0.0) else REASON_OK
        return REASON_NOT_PRESENT if role == PRESENT and self._value.get(PRESENT, 0.0) == 0 else REASON_OK

    def reason(self, now: float, role: str | None = None) -> str:
        """Why the source (or its ``role`` signal, with gates and presence) cannot be used at ``now``; "" if it can
        (``role=None``: the first reason of the gates, presence, then every value role in config order)."""
        if self._frozen:
            return REASON_FROZEN
        if now - self._ok_since <= self._window_s:
            return REASON_OK
        for gate in self._gates:
            r = self._role_reason(now, gate)
            if r or role == gate:
                return r
        if self._has_present:
            r = self._role_reason(now, PRESENT)
            if r or role == PRESENT:
                return r
        if role is not None:
            return self._role_reason(now, role)
        for r_name in self.value_roles:
            r = self._role_reason(now, r_name)
            if r:
                return r
        if self._latest_t:
            self._ok_since = min(self._latest_t.values())
        return REASON_OK

    def value(self, role: str) -> float:
        """The latest valid value of ``role`` (however old), NaN if none."""
        return self._value.get(role, math.nan)

    def last_t(self, role: str) -> float | None:
        """Time of the latest valid value of ``role``, None if none."""
        return self._valid_t.get(role)

    def age(self, now: float) -> float:
        """Seconds since the latest valid value of the oldest value role (inf while one has none)."""
        return max((now - self._valid_t.get(r, -math.inf) for r in self.value_roles), default=math.inf)

    def latest_times(self) -> dict[str, float]:
        """Each role's latest sample time, valid or not (a copy)."""
        return dict(self._latest_t)
