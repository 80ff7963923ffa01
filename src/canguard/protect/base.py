"""What every protection model is: a pure state machine that advances over runs of samples.

The run API, ``model.advance(times, values, *, until_edge=False) -> Run`` over two equal-length 1-D columns
(a sample is a run of one), is the only way samples reach a model (docs/protection.md): a run fed whole or
split anywhere gives the same edges and state. Time moves a model only through samples
(:mod:`canguard.engine.quiet` relies on it).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, ClassVar, Generic, TypeVar

from canguard.protect.columns import SHORT_RUN, Screen, as_run, in_order, ordered, short_run, values_span
from canguard.protect.results import Run, Snapshot, alternate, edges, quiet_cached, quiet_run

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
"""Tolerance of duration comparisons: ``21 * 0.01`` carries float rounding, candump resolves microseconds."""

_FIRST_CHUNK = 16
"""With ``until_edge``, chunks double from twice the running average distance to the edge (at least this)."""
_LAST_CHUNK = 1 << 16
"""The largest chunk screened at once: its temporary columns stay in cache, memory stays flat."""


def check_limit(name: str, value: float, *, positive: bool = False) -> float:
    """``value`` as float; ValueError naming ``name`` when it is not finite, negative, or (``positive``) 0."""
    v = float(value)
    if not math.isfinite(v) or v < 0 or (positive and v == 0):
        raise ValueError(f"{name} must be a finite number {'>' if positive else '>='} 0, got {value!r}")
    return v


def check_gap(value: float) -> float:
    """A ``max_gap_s`` as float (inf: no limit); ValueError unless it is > 0."""
    v = float(value)
    if math.isnan(v) or v <= 0:
        raise ValueError(f"max_gap_s must be > 0 (inf: no limit), got {value!r}")
    return v


class ProtectionModel(ABC):
    """A pure state machine over one signal's samples."""

    THRESHOLD_UNIT: ClassVar[str | None] = None
    """The unit of :attr:`Snapshot.threshold` when it is not the value's own (I²t: A²s or θ)."""

    @abstractmethod
    def advance(self, times: npt.ArrayLike, values: npt.ArrayLike, *, until_edge: bool = False) -> Run:
        """Advance over a run of samples (see the module docstring); where the tripped state changed.

        With ``until_edge`` the model stops right after the first edge (the engine ticks the tree there).
        """

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


S = TypeVar("S", bound=Screen)


class LatchedModel(ProtectionModel, Generic[S]):
    """What every concrete model shares: the run filter, tripped state, edge time, peak latch, snapshots.

    One kernel, :meth:`_step`, decides; a quiet run (:meth:`_quiet`) is taken whole, a short one sample by
    sample, a long one screened with numpy (:meth:`_screen`) and the kernel run only where it can act.
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
        """Samples ignored as older than the latest one."""
        self.rejected = 0
        """Samples ignored as not finite."""
        self._reach = _LAST_CHUNK // 64

    @property
    def tripped(self) -> bool:
        return self._tripped

    @property
    def last_t(self) -> float | None:
        """Time of the latest accepted sample, None before any."""
        return self._last_t

    @property
    def since(self) -> float | None:
        """Time of the last trip / recover edge, None if never."""
        return self._since

    def advance(self, times: npt.ArrayLike, values: npt.ArrayLike, *, until_edge: bool = False) -> Run:
        """Advance over a run of samples; see :mod:`canguard.protect.base` for the contract."""
        if type(times) is tuple and len(times) == 1 == len(values):  # type: ignore[arg-type]  # a live frame's
            one = float(times[0])  # sample: the kernel, nothing built
            if not self._sample(one, float(values[0])):  # type: ignore[index,arg-type]
                return quiet_cached(1) or quiet_run(1)
            return edges((0,), (one,), (self._tripped,), 1)
        few = short_run(times, values, SHORT_RUN)
        if few is not None:
            if few[0] and self._screened(few[0], few[1]):
                return quiet_run(len(few[0]))
            return self._advance_few(few[0], few[1], until_edge)
        t, v = as_run(times, values)
        if t.size and self._screened(t, v):
            return quiet_run(t.size)
        size = max(_FIRST_CHUNK, 2 * self._reach) if until_edge else _LAST_CHUNK
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
        if len(parts) <= 1:
            return parts[0][1] if parts else quiet_run(0)
        import numpy as np

        return Run(np.concatenate([p.index + at for at, p in parts]), np.concatenate([p.t for _, p in parts]),
                   np.concatenate([p.tripped for _, p in parts]), start)

    def mark(self) -> Any:
        """The running state (every attribute: parameters are only read back as they were)."""
        return self.__dict__.copy()

    def rewind(self, mark: Any) -> None:
        self.__dict__.update(mark)

    def _screened(self, t: Any, v: Any) -> bool:
        """Take a run in order, finite and on the quiet side (:meth:`_quiet`) whole; False: nothing done."""
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
        final_a = abs(float(v[-1]))
        if not self._quiet(t, low_a, high_a, final_a):
            return False
        self._last_t = float(t[-1])
        self._value = final_a
        return True

    def _quiet(self, t: Any, low_a: float, high_a: float, final_a: float) -> bool:
        """Take an ordered run with every |value| in [``low_a``, ``high_a``] when its samples would change nothing
        but the latest time and value (the base sets those); False: nothing taken."""
        return False

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
        """One sample: None when ignored (counted), else True on an edge."""
        if not (math.isfinite(t) and math.isfinite(v)):
            self.rejected += 1
            return None
        if self._last_t is not None and t < self._last_t:
            self.out_of_order += 1
            return None
        a = abs(v)
        return self._feed(t, a, self._step(t, a))

    def _advance_few(self, times: Sequence[float], values: Sequence[float], until_edge: bool) -> Run:
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
        return edges(index, [times[i] for i in index], alternate(self._tripped, len(index)), taken)

    def _advance_long(self, t: FloatArray, v: FloatArray, until_edge: bool) -> Run:
        import numpy as np

        finite = np.isfinite(v) & np.isfinite(t)
        ok = in_order(t, finite, self._last_t)
        everything = bool(ok.all())
        picked = np.arange(t.size) if everything else ok.nonzero()[0]
        if not picked.size:
            self._count_ignored(finite, ok, t.size)
            return quiet_run(t.size)
        ta = t if everything else t[picked]
        a = np.abs(v if everything else v[picked])
        found, last = self._walk(ta, a, until_edge)
        taken = int(picked[last]) + 1 if until_edge and found else t.size
        if not everything:
            self._count_ignored(finite, ok, taken)
        at = np.array(found, dtype=np.intp)
        return edges(picked[at], ta[at], alternate(self._tripped, len(found)), taken)

    def _walk(self, t: FloatArray, a: FloatArray, until_edge: bool) -> tuple[list[int], int]:
        """Feed a long run's candidates to the kernel; the edges' positions and the last sample taken."""
        n = a.size
        screen = self._screen(t, a)
        found: list[int] = []
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
                    found.append(j)
                    if until_edge:
                        self._finish(screen, j)
                        return found, j
                j += 1
                if self._at_rest():
                    break
            pos = j
        self._finish(screen, n - 1)
        return found, n - 1

    def _count_ignored(self, finite: BoolArray, ok: BoolArray, taken: int) -> None:
        import numpy as np

        self.rejected += int(np.count_nonzero(~finite[:taken]))
        self.out_of_order += int(np.count_nonzero(finite[:taken] & ~ok[:taken]))

    @abstractmethod
    def _step(self, t: float, a: float) -> bool:
        """The kernel: the tripped state after one accepted sample (the base records edges, time and value)."""

    def _step_at(self, screen: S, j: int, t: float, a: float) -> bool:
        """The kernel on sample ``j`` of a screened run (a model may take columns the screen holds)."""
        return self._step(t, a)

    @abstractmethod
    def _screen(self, t: FloatArray, a: FloatArray) -> S:
        """A numpy screen of a long run of accepted samples, from the present state (nothing changed)."""

    def _rest(self, screen: S, first: int, last: int) -> None:
        """Take the quiet samples ``first`` .. ``last`` of the screened run (the base sets time and value)."""

    def _finish(self, screen: S, last: int) -> None:
        """The walk ended right after sample ``last``: take what the screen still holds."""

    def _at_rest(self) -> bool:
        """True when the screen may take over again (no timer the kernel must follow)."""
        return True

    def carry_from(self, old: ProtectionModel) -> None:
        """Take over the running state of the model this one replaces (config reload; its own parameters kept).

        A reload never clears a trip; a model of another kind carries only this base part.
        """
        if isinstance(old, LatchedModel):
            self._tripped, self._since, self._latch, self._value, self._last_t = old.running()

    def running(self) -> tuple[bool, float | None, bool, float, float | None]:
        """What a reload carries of every model: (tripped, since, peak latch armed, latest |value|, latest time)."""
        return self._tripped, self._since, self._latch, self._value, self._last_t

    @abstractmethod
    def _levels(self) -> tuple[float, float]:
        """The trip threshold in force (in the snapshot's unit) and how close to tripping (% of the trip level)."""

    def _make_snapshot(self, tripped: bool) -> Snapshot:
        threshold, level = self._levels()
        reason = self.reason_tripped if tripped else REASON_OK
        return Snapshot(self._value, threshold, level, tripped, self._since, reason)

    def poll(self, now: float) -> Snapshot:
        """The state at tick time ``now``: tripped if tripped now or if a trip began since the last poll.

        The latch is then cleared: a spike already over is reported exactly once.
        """
        snap = self._make_snapshot(self._tripped or self._latch)
        self._latch = False
        return snap

    def snapshot(self) -> Snapshot:
        return self._make_snapshot(self._tripped)
