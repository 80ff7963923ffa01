"""What every protection model is: a pure state machine that advances over runs of samples.

**The run API** (what the engine calls; the only way samples reach a model):

``model.advance(times, values, *, until_edge=False) -> Run``

- A *run* is a stretch of samples of the one signal the model guards, in arrival
  order: two equal-length 1-D columns (lists, tuples, anything ``numpy.asarray`` takes), ``times``
  in seconds (the engine's clock or the log's timestamps) and ``values`` in the
  signal's unit (A, or N·m; signed: the model takes |value|). A run may hold one
  sample (the live bus) or millions (a log); a long one is copied to float64.
- The returned :class:`Run` says where the model's tripped state changed: the
  positions in the run (``index``), their times (``t``), and the state entered at
  each (``tripped``); ``taken`` is how many samples were consumed. With
  ``until_edge=True`` the model stops right after the first
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
- Between runs the engine may :meth:`~ProtectionModel.mark` a model and :meth:`~ProtectionModel.rewind` it
  to that mark: when another source's edge comes before the end of a run this model already took, the
  model goes back and takes the run only up to that edge (the tree must see every model as it stood there).

**One kernel.** Each model's decision logic is one scalar step over Python floats (the
state machine a sample goes through). A short run (up to :data:`SHORT_RUN` samples; lists,
tuples or numpy columns) feeds every sample to it with no numpy call; a long run is first
*screened* with numpy for the few samples where the kernel can change something (a
sample over a limit, a level crossing, the other side of the start current), the kernel
runs on those and on the samples after them while a timer runs, and the quiet stretches
between are taken whole from the screen. A run (short or long) whose samples are all in order,
finite and on the quiet side of the model (:meth:`LatchedModel._quiet_side`: below the limit, no
timer running, no heat to integrate) is taken whole from its last sample, as the screen takes a
quiet stretch. All
ways are the same maths, so they agree by construction; the tests still hold them to the reference.
Importing the models, and feeding them short runs of lists, never imports numpy until the first
edge (a :class:`Run` with an edge holds numpy columns), long run or numpy column.
- Bad samples never raise and never corrupt the state: a sample whose value or
  time is NaN/±inf is ignored and counted in ``rejected``; a sample older than the
  latest accepted one (a negative time step: clock stepped back, out-of-order
  frames) is ignored and counted in ``out_of_order``; a repeated timestamp is a
  normal sample (zero time step). A huge time step is taken as it is by the
  threshold models; the models with a ``max_gap_s`` (hysteresis timers, I²t)
  treat a longer gap as stale data (see each model). Mismatched or non-1-D
  arrays raise ValueError naming both shapes.

**Time moves a model only through samples.** Every model's state (and what
:meth:`ProtectionModel.poll` answers, but for the latch it resets) changes at samples
only, never with time alone: the persistence timers, inrush windows and I²t heat are
measured at samples (the previous current held until the next one). The engine relies on
it to count a grid tick that is proven to repeat the last one instead of running it
(:mod:`canguard.engine.quiet`); ``tests/test_protect_contract.py`` holds every model to it.

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
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, ClassVar

from canguard.protect.columns import (
    NO_EDGES,
    SHORT_RUN,
    Screen,
    alternate,
    as_run,
    in_order,
    no_edges,
    ordered,
    short_run,
    values_span,
)
from canguard.protect.results import Run, Snapshot

if TYPE_CHECKING:
    import numpy.typing as npt

    from canguard.protect.columns import BoolArray, FloatArray

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
"""With ``until_edge``, a long run is screened in chunks that double from twice the typical
distance at which the previous stops found their edge (a running average; at least this many
samples): chattering edges cost a short screen each, rare ones a few passes over the run."""
_LAST_CHUNK = 1 << 16
"""A long run is screened in chunks of at most this many samples: the temporary columns
stay in the CPU cache and memory stays flat however long the run."""


QUIET_RUNS: dict[int, Run] = {}
"""The :class:`Run` of ``n`` samples taken without an edge, by ``n`` (short runs: built once each, shared)."""


def quiet_run(n: int) -> Run:
    """The result of a run of ``n`` samples that changed nothing (shared: a result is only read)."""
    run = QUIET_RUNS.get(n)
    if run is None:
        run = Run(*(NO_EDGES or no_edges())[0], n)
        if n <= SHORT_RUN:
            QUIET_RUNS[n] = run
    return run


class ProtectionModel(ABC):
    """A pure state machine over one signal's samples."""

    THRESHOLD_UNIT: ClassVar[str | None] = None
    """The unit of :attr:`Snapshot.threshold` when it is not the value's own (I²t: A²s or θ)."""
    @abstractmethod
    def advance(self, times: npt.ArrayLike, values: npt.ArrayLike, *, until_edge: bool = False) -> Run:
        """Advance over a run of samples (see the module docstring); where the tripped state changed."""

    @abstractmethod
    def mark(self) -> Any:
        """The running state, to go back to with :meth:`rewind` (opaque; nothing is changed)."""

    @abstractmethod
    def rewind(self, mark: Any) -> None:
        """Go back to the state :meth:`mark` gave, as if the runs taken since had not come."""

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
    #
    # One kernel, two ways to reach it. The model's decision logic is one scalar step
    # (:meth:`_step`, Python floats). A short run feeds every accepted sample to it; a long
    # run is first screened with numpy (:meth:`_screen`) for the few samples where the
    # kernel can change something, the quiet stretches between them taken whole
    # (:meth:`_rest`), so both give the same state and edges at the same samples.

    def advance(self, times: npt.ArrayLike, values: npt.ArrayLike, *, until_edge: bool = False) -> Run:
        """Advance over a run of samples; see :mod:`canguard.protect.base` for the contract."""
        if type(times) is tuple and len(times) == 1 == len(values):  # type: ignore[arg-type]  # a live frame's
            one = float(times[0])  # sample: the kernel, nothing built
            if not self._sample(one, float(values[0])):  # type: ignore[index,arg-type]
                return QUIET_RUNS.get(1) or quiet_run(1)
            return self._one_edge(one)
        few = short_run(times, values, SHORT_RUN)
        if few is not None:
            if few[0] and self._screened(few[0], few[1]):
                return quiet_run(len(few[0]))
            return self._advance_few(few[0], few[1], until_edge)
        import numpy as np

        t, v = as_run(times, values)
        if t.size and self._screened(t, v):
            return quiet_run(t.size)
        size = max(_FIRST_CHUNK, 2 * self._reach) if until_edge else _LAST_CHUNK
        if t.size <= size:
            return self._stopped(self._advance_long(t, v, until_edge), until_edge)
        parts: list[tuple[int, Run]] = []
        start = 0
        while start < t.size:
            part = self._advance_long(t[start : start + size], v[start : start + size], until_edge)
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
        )

    def mark(self) -> Any:
        """The running state (every attribute: parameters are only read back as they were)."""
        return self.__dict__.copy()

    def rewind(self, mark: Any) -> None:
        """Go back to the state :meth:`mark` gave."""
        self.__dict__.update(mark)

    def _screened(self, t: Any, v: Any) -> bool:
        """A run whose samples change nothing but the latest one, taken whole; False: nothing done.

        Every sample is in order (none before the latest, times not going back) and finite, and the
        model's own screen (:meth:`_quiet_side`) finds them all on its quiet side: fed one by one they
        would leave exactly what :meth:`_take_quiet` leaves. Lists or numpy columns
        (:func:`~canguard.protect.columns.ordered`, :func:`~canguard.protect.columns.values_span`).
        """
        if not ordered(t):
            return False
        last = self._last_t
        if last is not None and not float(t[0]) >= last:
            return False
        span = values_span(v)
        if span is None:
            return False
        low, high = span
        high_a = high if high >= -low else -low
        low_a = low if low >= 0.0 else (-high if high <= 0.0 else 0.0)  # values on both sides of 0: at least 0
        if not self._quiet_side(t, low_a, high_a):
            return False
        final_a = abs(float(v[-1]))
        self._take_quiet(final_a)
        self._last_t = float(t[-1])
        self._value = final_a
        return True

    def _quiet_side(self, t: Any, low_a: float, high_a: float) -> bool:
        """True when every sample of a run (times ``t`` in order, after the latest; finite values, every |value|
        at least ``low_a`` and at most ``high_a``) leaves the state as it is but for the latest time and value
        (and what :meth:`_take_quiet` takes); the default says no (every sample to the kernel)."""
        return False

    def _take_quiet(self, final_a: float) -> None:
        """Take a run :meth:`_quiet_side` accepted, but for the latest time and value (the base sets them);
        ``final_a``: the last sample's |value|."""

    def _stopped(self, run: Run, until_edge: bool) -> Run:
        """Remember how far a stop at an edge had to look (averaged: the next scan starts at twice that)."""
        if until_edge and run.changed:
            self._reach = (self._reach + run.taken) // 2
        return run

    def _feed(self, t: float, a: float, tripped: bool) -> bool:
        """Record an accepted sample the kernel left in ``tripped``; True on an edge (time and latch taken)."""
        self._last_t = t
        self._value = a
        if tripped == self._tripped:
            return False
        self._tripped = tripped
        self._since = t
        self._latch = self._latch or tripped
        return True

    def _sample(self, t: float, v: float) -> bool | None:
        """One sample of a short run: None when ignored (counted), else True on an edge."""
        if not (math.isfinite(t) and math.isfinite(v)):
            self.rejected += 1
            return None
        if self._last_t is not None and t < self._last_t:
            self.out_of_order += 1
            return None
        a = abs(v)
        return self._feed(t, a, self._step(t, a))

    def _one_edge(self, t: float) -> Run:
        """The result of a run of one sample, at ``t``, that changed the tripped state."""
        import numpy as np

        return Run(np.zeros(1, dtype=np.intp), np.array([t]), np.array([self._tripped]), 1)

    def _advance_few(self, times: Sequence[float], values: Sequence[float], until_edge: bool) -> Run:
        """A short run: every sample filtered and fed to the kernel, no numpy on the way."""
        index: list[int] = []
        taken = len(times)
        sample = self._sample
        for i in range(taken):
            if sample(times[i], values[i]):
                index.append(i)
                if until_edge:
                    taken = i + 1
                    break
        if not index:
            return quiet_run(taken)
        import numpy as np

        return Run(np.array(index, dtype=np.intp), np.array([times[i] for i in index]),
                   np.array(alternate(self._tripped, len(index))), taken)

    def _advance_long(self, t: FloatArray, v: FloatArray, until_edge: bool) -> Run:
        """A long run: filtered with numpy, screened, the candidates fed to the kernel."""
        import numpy as np

        finite = np.isfinite(v) & np.isfinite(t)
        ok = in_order(t, finite, self._last_t)
        everything = bool(ok.all())
        picked = np.arange(t.size) if everything else ok.nonzero()[0]
        if not picked.size:
            self._count_ignored(finite, ok, t.size)
            return Run(*no_edges()[0], t.size)
        ta = t if everything else t[picked]
        a = np.abs(v if everything else v[picked])
        edges, last = self._walk(ta, a, until_edge)
        taken = int(picked[last]) + 1 if until_edge and edges else t.size
        if not everything:
            self._count_ignored(finite, ok, taken)
        at = np.array(edges, dtype=np.intp)
        return Run(picked[at], ta[at], np.array(alternate(self._tripped, len(edges))), taken)

    def _walk(self, t: FloatArray, a: FloatArray, until_edge: bool) -> tuple[list[int], int]:
        """Feed a long run's candidates to the kernel; the edges' positions and the last sample taken."""
        n = a.size
        screen = self._screen(t, a)
        edges: list[int] = []
        pos = 0
        while pos < n:
            j = screen.next(pos, self._tripped) if self._at_rest() else pos
            if j > pos:
                self._rest(screen, pos, j - 1)
                self._last_t = float(t[j - 1])
                self._value = float(a[j - 1])
            while j < n:
                tj, aj = float(t[j]), float(a[j])
                if self._feed(tj, aj, self._step_at(screen, j, tj, aj)):
                    edges.append(j)
                    if until_edge:
                        self._finish(screen, j)
                        return edges, j
                j += 1
                if self._at_rest():
                    break
            pos = j
        self._finish(screen, n - 1)
        return edges, n - 1

    def _count_ignored(self, finite: BoolArray, ok: BoolArray, taken: int) -> None:
        """Count the first ``taken`` samples' ignored ones: not finite, or out of order."""
        import numpy as np

        self.rejected += int(np.count_nonzero(~finite[:taken]))
        self.out_of_order += int(np.count_nonzero(finite[:taken] & ~ok[:taken]))

    @abstractmethod
    def _step(self, t: float, a: float) -> bool:
        """The kernel: take one accepted sample (|value| ``a`` at ``t``, ``self._last_t`` the previous one).

        Returns the tripped state right after it; the base records edges, time and value.
        """

    def _step_at(self, screen: Screen, j: int, t: float, a: float) -> bool:
        """The kernel on sample ``j`` of a screened run (a model may take columns the screen holds)."""
        return self._step(t, a)

    @abstractmethod
    def _screen(self, t: FloatArray, a: FloatArray) -> Screen:
        """A numpy screen of a long run of accepted samples, from the present state (nothing changed)."""

    def _rest(self, screen: Screen, first: int, last: int) -> None:
        """Take the quiet samples ``first`` .. ``last`` of the screened run (the base sets time and value)."""

    def _finish(self, screen: Screen, last: int) -> None:
        """The walk over a screened run ended right after its sample ``last``: take what the screen still holds."""

    def _at_rest(self) -> bool:
        """True when the screen may take over again: no timer or other state the kernel must follow."""
        return True

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
