"""What every protection model is: a pure, per-sample state machine.

Models see every valid sample of the signal they guard (``update``), take time
as an argument (never from a clock), and report their state at tick time
(``poll``) with a *peak latch*: a trip that happened at any moment since the
previous poll is reported even when the current sample is back to normal, so a
one-frame spike between two ticks is never lost.

Invalid data (no sample, stale, present = false, NaN/inf, out of range) is
tracked by :class:`canguard.protect.staleness.SourceHealth`, not by the models:
models only ever see finite values.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

# Reasons a guard is not satisfied, as they appear in snapshots and events.
REASON_OK = ""
REASON_OVERCURRENT = "overcurrent"
REASON_I2T = "i2t"
REASON_NO_DATA = "no_data"
REASON_STALE = "stale"
REASON_NOT_PRESENT = "not_present"

TIME_EPS_S = 1e-9
"""Tolerance of duration comparisons (``held >= trip_after_s``): timestamps like
``21 * 0.01`` carry float rounding, and candump resolves microseconds only."""


@dataclass(frozen=True)
class Snapshot:
    """A model's state, small enough for events, metrics and plots.

    ``value``: the latest |value| the model saw (A, or N·m), NaN before any.
    ``threshold``: the trip threshold in force (same unit as value; for I²t the
    trip level of the accumulator, A²s or θ = 1).
    ``level_pct``: how close to tripping, in % of the trip level (100 = trip).
    ``tripped``: True while tripped (or, from ``poll``, tripped at any moment since the last poll).
    ``since``: time of the last trip / recover edge, None if never.
    ``reason``: "" when fine, otherwise why not (``overcurrent``, ``i2t``, ...).
    """

    value: float
    threshold: float
    level_pct: float
    tripped: bool
    since: float | None
    reason: str


class ProtectionModel(ABC):
    """A pure state machine over one signal's samples."""

    THRESHOLD_UNIT: ClassVar[str | None] = None
    """The unit of :attr:`Snapshot.threshold` when it is not the value's own (I²t: A²s or θ)."""
    SAMPLE_DRIVEN: ClassVar[bool] = False
    """True when the state (and :meth:`poll`'s answer) changes only in :meth:`update`, never with time alone.

    The replay engine counts a tick that would repeat the last one instead of running it
    (:mod:`canguard.engine.quiet`) only when every model the tree reads says so. A model
    that cools, counts down or otherwise moves between samples (I²t) leaves it False.
    """

    @abstractmethod
    def update(self, value: float, t: float) -> bool:
        """Feed one finite sample (signed; the model takes |value|) taken at time ``t``.

        Returns True when the tripped state changed (an edge: the engine ticks
        the tree at once). Out-of-order (``t`` earlier than the last sample) and
        repeated timestamps never raise and never corrupt the state.
        """

    @abstractmethod
    def poll(self, now: float) -> Snapshot:
        """The state at tick time ``now``, with the peak latch; resets the latch."""

    @abstractmethod
    def snapshot(self) -> Snapshot:
        """The current state without touching the latch."""

    @property
    @abstractmethod
    def tripped(self) -> bool:
        """True while the model is tripped (no latch)."""


class LatchedModel(ProtectionModel):
    """Bookkeeping every concrete model shares: tripped state, edge time, peak latch.

    Subclasses implement ``update`` (calling :meth:`_accept` first and
    :meth:`_set_tripped` to change state) plus :meth:`_threshold_value` and
    :meth:`_level_pct`. Samples with a non-finite value or time, and samples
    older than the latest one (``t`` < last ``t``), are ignored and counted in
    ``out_of_order`` / ``rejected``; a repeated timestamp is a normal sample.
    """

    reason_tripped: str = REASON_OVERCURRENT
    """The snapshot reason while tripped."""

    def __init__(self) -> None:
        self._tripped = False
        self._latch = False
        self._since: float | None = None
        self._value = math.nan
        self._last_t: float | None = None
        self.out_of_order = 0
        """Samples ignored because they were older than the latest one."""
        self.rejected = 0
        """Samples ignored because their value or time was not finite."""

    @property
    def tripped(self) -> bool:
        """True while the model is tripped (no latch)."""
        return self._tripped

    @property
    def last_t(self) -> float | None:
        """Time of the latest accepted sample, None before any."""
        return self._last_t

    @property
    def since(self) -> float | None:
        """Time of the last trip / recover edge, None if never."""
        return self._since

    def _accept(self, value: float, t: float) -> float | None:
        """Return |value| when the sample may be used, None (and count it) when it must be ignored."""
        if not (math.isfinite(value) and math.isfinite(t)):
            self.rejected += 1
            return None
        if self._last_t is not None and t < self._last_t:
            self.out_of_order += 1
            return None
        return abs(value)

    def settles(self, low: float, high: float, first_t: float) -> bool:
        """True when a run of samples, fed one by one, would trip or recover nothing (nothing is changed here).

        The run: samples from ``first_t`` on, in time order, with |values| between ``low``
        and ``high``. Then the state after the run depends only on its last sample
        (:meth:`take_run`). Used by the replay's column path (:mod:`canguard.engine.settle`);
        the default says no.
        """
        return False

    def take_run(self, last: float, last_t: float) -> None:
        """Take a run :meth:`settles` accepted: the state its samples would have left, from its last one.

        ``last``: the run's last sample (signed), at ``last_t``.
        """
        self._last_t = last_t
        self._value = abs(last)

    def _in_order(self, first_t: float) -> bool:
        """True when a run starting at ``first_t`` would be taken (not counted out of order)."""
        return self._last_t is None or first_t >= self._last_t

    def carry_from(self, old: ProtectionModel) -> None:
        """Take over the running state of the model this one replaces (config reload, same guard).

        The new model keeps its own parameters (thresholds, times) and continues from where
        the old one stood: tripped or not and since when, the latest sample, an unreported
        trip still in the peak latch. Subclasses add what their maths keeps (a running
        ``trip_after`` timer, I²t heat). A model of another kind carries only this part.
        A trip is never cleared by a reload: the new model recovers by its own rule.
        """
        if not isinstance(old, LatchedModel):
            return
        self._tripped = old._tripped
        self._since = old._since
        self._latch = old._latch
        self._value = old._value
        self._last_t = old._last_t

    def _set_tripped(self, tripped: bool, t: float | None) -> bool:
        """Enter ``tripped``; True on an edge. A trip edge arms the peak latch.

        Only the edge arms it: a trip the last poll already reported and that lasted up
        to a recovery must not be reported again after that recovery (issue 12: every
        recovery came one tick late).
        """
        if tripped == self._tripped:
            return False
        if tripped:
            self._latch = True
        self._tripped = tripped
        self._since = t
        return True

    @abstractmethod
    def _threshold_value(self) -> float:
        """The trip threshold in force, in the snapshot's unit."""

    @abstractmethod
    def _level_pct(self) -> float:
        """How close to tripping, in % of the trip level."""

    def _make_snapshot(self, tripped: bool) -> Snapshot:
        return Snapshot(
            value=self._value,
            threshold=self._threshold_value(),
            level_pct=self._level_pct(),
            tripped=tripped,
            since=self._since,
            reason=self.reason_tripped if tripped else REASON_OK,
        )

    def poll(self, now: float) -> Snapshot:
        """The state at tick time ``now``: tripped if tripped now or if a trip began since the last poll.

        The latch is then cleared: a model still tripped keeps reporting tripped (it is),
        a spike already over is reported exactly once, and a recovery since the last poll
        is reported at this poll, the first at or after it (not one poll later).
        """
        snap = self._make_snapshot(self._tripped or self._latch)
        self._latch = False
        return snap

    def snapshot(self) -> Snapshot:
        """The present state, without reading or resetting the latch."""
        return self._make_snapshot(self._tripped)
