"""What every protection model is: a pure state machine that advances over runs of samples.

**The run API** (what the engine calls; the only way samples reach a model):

``model.advance(times, values, *, until_edge=False) -> Run``

- A *run* is a stretch of samples of the one signal the model guards, in arrival
  order: two equal-length 1-D arrays (anything ``numpy.asarray`` takes), ``times``
  in seconds (the engine's clock or the log's timestamps) and ``values`` in the
  signal's unit (A, or N·m; signed: the model takes |value|). A run may hold one
  sample (the live bus) or millions (a log); it is copied to float64 internally.
- The returned :class:`Run` says where the model's tripped state changed: the
  positions in the run (``index``), their times (``t``), and the state entered at
  each (``tripped``); ``taken`` is how many samples were consumed and ``peak`` the
  largest |value| among them (every sample counts: reports take their lowest
  margin from it). With ``until_edge=True`` the model stops right after the first
  sample at which its state changed (``taken`` = that position + 1, at most one
  edge returned): the engine ticks the tree there (the tree may change a model's
  thresholds, and :meth:`ProtectionModel.poll` must see the state of that moment)
  and calls ``advance`` again with the rest of the run.
- State carries between runs: a run continues exactly where the previous one
  stopped (timers, I²t heat, the held current, the inrush window, the peak latch),
  so feeding a run whole, sample by sample (runs of one), or split at any points
  gives the same edges at the same samples and the same state; floating-point
  results agree within 1e-9 relative (the tests hold it against the per-sample
  reference maths kept in ``tests/reference_models.py``).
- :meth:`ProtectionModel.update` is :meth:`~ProtectionModel.advance` on a run of one.
- Bad samples never raise and never corrupt the state: a sample whose value or
  time is NaN/±inf is ignored and counted in ``rejected``; a sample older than the
  latest accepted one (a negative time step: clock stepped back, out-of-order
  frames) is ignored and counted in ``out_of_order``; a repeated timestamp is a
  normal sample (zero time step). A huge time step is taken as it is by the
  threshold models; the models with a ``max_gap_s`` (hysteresis timers, I²t)
  treat a longer gap as stale data (see each model). Mismatched or non-1-D
  arrays raise ValueError naming both shapes.

Models take time as an argument (never from a clock), and report their state at
tick time (``poll``) with a *peak latch*: a trip that happened at any moment
since the previous poll is reported even when the current sample is back to
normal, so a one-frame spike between two ticks is never lost.

Invalid data (no sample, stale, present = false, NaN/inf, out of range) is
tracked by :class:`canguard.protect.staleness.SourceHealth`, not by the models:
the engine feeds models only valid samples (the models' own filter above is the
fail-safe against anything else).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import numpy.typing as npt

from canguard.protect.columns import FloatArray, IndexArray, as_run, in_order, toggles

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


_FIRST_CHUNK = 16
"""With ``until_edge``, a run is scanned in chunks that double from twice the typical distance
at which the previous stops found their edge (a running average; at least this many samples):
chattering edges cost a short scan each, rare ones a few passes over the run."""
_LAST_CHUNK = 1 << 16
"""A long run is scanned in chunks of at most this many samples: the temporary columns
stay in the CPU cache and memory stays flat however long the run."""
_NO_EDGES = np.empty(0, dtype=np.intp)
_NO_EDGES.flags.writeable = False


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


@dataclass(frozen=True)
class Run:
    """What :meth:`ProtectionModel.advance` did with a run of samples.

    ``index``: positions in the run (int) of the samples at which the tripped state
    changed, ascending. ``t``: their times (s). ``tripped``: the state entered at
    each (they alternate). ``taken``: samples consumed from the start of the run
    (all of them unless ``until_edge`` stopped early). ``peak``: the largest |value|
    among the taken samples the model accepted, NaN when none.
    """

    index: IndexArray
    t: FloatArray
    tripped: npt.NDArray[np.bool_]
    taken: int
    peak: float

    @property
    def changed(self) -> bool:
        """True when the run changed the tripped state at least once (an edge: tick the tree)."""
        return bool(self.index.size)


@dataclass
class Scan:
    """A model's pure look at a run of accepted samples (nothing changed yet).

    ``state``: the tripped state right after each sample. ``commit(k)``: take the
    model's own state (timers, heat, ...) as it stands right after sample ``k``.
    """

    state: npt.NDArray[np.bool_]
    commit: Callable[[int], None]


class ProtectionModel(ABC):
    """A pure state machine over one signal's samples."""

    THRESHOLD_UNIT: ClassVar[str | None] = None
    """The unit of :attr:`Snapshot.threshold` when it is not the value's own (I²t: A²s or θ)."""
    SAMPLE_DRIVEN: ClassVar[bool] = False
    """True when the state (and :meth:`poll`'s answer) changes only with samples, never with time alone.

    Read only by the replay engine's quiet-tick shortcut (:mod:`canguard.engine.quiet`).
    Every model here changes state only at samples, so every one sets it True.
    """

    @abstractmethod
    def advance(self, times: npt.ArrayLike, values: npt.ArrayLike, *, until_edge: bool = False) -> Run:
        """Advance over a run of samples (see the module docstring); where the tripped state changed."""

    def update(self, value: float, t: float) -> bool:
        """Feed one sample (a run of one); True when the tripped state changed (an edge)."""
        return self.advance((t,), (value,)).changed

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
    """Bookkeeping every concrete model shares: the run filter, tripped state, edge time, peak latch.

    Subclasses implement :meth:`_scan` (their maths over a run of accepted samples) plus
    :meth:`_threshold_value` and :meth:`_level_pct`. Samples with a non-finite value or
    time, and samples older than the latest one (``t`` < last ``t``), are ignored and
    counted in ``out_of_order`` / ``rejected``; a repeated timestamp is a normal sample.
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
        self._reach = _LAST_CHUNK // 64

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

    # -- the run ------------------------------------------------------------------------

    def advance(self, times: npt.ArrayLike, values: npt.ArrayLike, *, until_edge: bool = False) -> Run:
        """Advance over a run of samples; see :mod:`canguard.protect.base` for the contract."""
        t, v = as_run(times, values)
        size = max(_FIRST_CHUNK, 2 * self._reach) if until_edge else _LAST_CHUNK
        if t.size <= size:
            return self._stopped(self._advance(t, v, until_edge), until_edge)
        parts: list[tuple[int, Run]] = []
        start = 0
        while start < t.size:
            part = self._advance(t[start : start + size], v[start : start + size], until_edge)
            parts.append((start, part))
            start += part.taken
            if until_edge and part.changed:
                self._reach = (self._reach + start) // 2
                break
            size = min(2 * size, _LAST_CHUNK)
        return Run(
            np.concatenate([p.index + at for at, p in parts]),
            np.concatenate([p.t for _, p in parts]),
            np.concatenate([p.tripped for _, p in parts]),
            start,
            float(np.fmax.reduce([p.peak for _, p in parts])),
        )

    def _stopped(self, run: Run, until_edge: bool) -> Run:
        """Remember how far a stop at an edge had to look (averaged: the next scan starts at twice that)."""
        if until_edge and run.changed:
            self._reach = (self._reach + run.taken) // 2
        return run

    def _advance(self, t: FloatArray, v: FloatArray, until_edge: bool) -> Run:
        finite = np.isfinite(v) & np.isfinite(t)
        ok = in_order(t, finite, self._last_t)
        everything = bool(ok.all())
        picked = np.arange(t.size) if everything else ok.nonzero()[0]
        if not picked.size:
            self._count_ignored(finite, ok, t.size)
            return Run(_NO_EDGES, np.empty(0), np.empty(0, dtype=bool), t.size, math.nan)
        ta = t if everything else t[picked]
        a = np.abs(v if everything else v[picked])
        scan = self._scan(ta, a)
        edges = toggles(scan.state, self._tripped)
        last = picked.size - 1
        taken = t.size
        if until_edge and edges.size:
            edges = edges[:1]
            last = int(edges[0])
            taken = int(picked[last]) + 1
        if not everything:
            self._count_ignored(finite, ok, taken)
        entered = scan.state[edges]
        scan.commit(last)
        self._last_t = float(ta[last])
        self._value = float(a[last])
        if edges.size:
            self._tripped = bool(entered[-1])
            self._since = float(ta[edges[-1]])
            self._latch = self._latch or bool(entered.any())
        return Run(picked[edges], ta[edges], entered, taken, float(a[: last + 1].max()))

    def _count_ignored(self, finite: npt.NDArray[np.bool_], ok: npt.NDArray[np.bool_], taken: int) -> None:
        """Count the first ``taken`` samples' ignored ones: not finite, or out of order."""
        self.rejected += int(np.count_nonzero(~finite[:taken]))
        self.out_of_order += int(np.count_nonzero(finite[:taken] & ~ok[:taken]))

    @abstractmethod
    def _scan(self, t: FloatArray, a: FloatArray) -> Scan:
        """The model's maths over accepted samples (times ``t``, |values| ``a``); must not change ``self``."""

    # -- the replay's settle shortcut (kept while the engine still calls it) ------------

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
        self._tripped, self._since, self._latch, self._value, self._last_t = old.running()

    def running(self) -> tuple[bool, float | None, bool, float, float | None]:
        """What a reload carries of every model: (tripped, since, peak latch armed, latest |value|, latest time)."""
        return self._tripped, self._since, self._latch, self._value, self._last_t

    def _set_tripped(self, tripped: bool, t: float | None) -> bool:
        """Enter ``tripped`` outside a run (restore, worst case); True on an edge. A trip edge arms the latch.

        Only the edge arms it: a trip the last poll already reported and that lasted up
        to a recovery must not be reported again after that recovery (every recovery
        would come one tick late).
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
