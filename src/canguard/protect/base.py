"""What every protection model is: a pure state machine that advances over runs of samples.

``advance`` is the only way samples reach a model: a run fed whole or split anywhere gives the same edges and
state. Time moves a model only through samples (:mod:`canguard.engine.quiet` relies on it).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import TYPE_CHECKING, Any, ClassVar

from canguard.protect.columns import SHORT_RUN, as_run, ordered, short_run, values_span
from canguard.protect.results import Run, Snapshot, edges, quiet_cached, quiet_run

if TYPE_CHECKING:
    from collections.abc import Iterable

    import numpy.typing as npt

# Reasons a guard is not satisfied, as they appear in snapshots and events.
REASON_OK = ""
REASON_OVERCURRENT = "overcurrent"
REASON_I2T = "i2t"
REASON_NO_DATA = "no_data"
REASON_STALE = "stale"
REASON_NOT_PRESENT = "not_present"

TIME_EPS_S = 1e-9
"""Tolerance of duration comparisons: ``21 * 0.01`` carries float rounding, candump resolves microseconds."""


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
        """Advance over a run of samples: ``times`` (s) and ``values`` (the signal's unit; |value| is taken), two
        equal-length 1-D columns in arrival order (ValueError naming both shapes otherwise). The :class:`Run` says
        where the tripped state changed and how many samples were taken (``until_edge``: up to the first edge).
        A sample not finite, or older than the latest, is ignored; a repeated time is a normal sample. Fed whole or
        split anywhere: the same edges and state."""

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


CHUNK = 1024
"""A long run is screened this many samples at a time: a quiet stretch inside a busy run is still taken whole, and an
edge found early leaves the rest unread (the screen's numpy cost is a few µs, a sample's walk about 0.3 µs)."""


class LatchedModel(ProtectionModel):
    """What every concrete model shares: the run filter, tripped state, edge time, peak latch, snapshots. One kernel,
    :meth:`_step`, decides; a quiet run (:meth:`_quiet`) is taken whole, any other sample by sample."""

    reason_tripped: str = REASON_OVERCURRENT
    """The snapshot reason while tripped."""

    def __init__(self) -> None:
        self._tripped = False
        self._latch = False
        self.since: float | None = None
        """Time of the last trip / recover edge, None if never."""
        self._value = math.nan
        self.last_t: float | None = None
        """Time of the latest accepted sample, None before any."""

    @property
    def tripped(self) -> bool:
        return self._tripped

    def advance(self, times: npt.ArrayLike, values: npt.ArrayLike, *, until_edge: bool = False) -> Run:
        """Advance over a run of samples (the contract: :meth:`ProtectionModel.advance`)."""
        if type(times) is tuple and len(times) == 1 == len(values):  # type: ignore[arg-type]  # a live frame's
            one = float(times[0])  # sample: the kernel, nothing built
            if not self._sample(one, float(values[0])):  # type: ignore[index,arg-type]
                return quiet_cached(1) or quiet_run(1)
            return edges((0,), (one,), (self._tripped,), 1)
        few = short_run(times, values, SHORT_RUN)
        if few is not None:
            if few[0] and self._screened(*few):
                return quiet_run(len(few[0]))
            parts: Iterable[tuple[int, Iterable[tuple[float, float]]]] = [(0, zip(*few, strict=True))]
            taken = len(few[0])
        else:  # a long run: a chunk at a time, each screened as numpy columns, else walked as floats
            ta, va = as_run(times, values)
            taken = ta.size
            parts = ((at, zip(map(float, ta[at:at + CHUNK]), map(float, va[at:at + CHUNK]), strict=True))
                     for at in range(0, taken, CHUNK) if not self._screened(ta[at:at + CHUNK], va[at:at + CHUNK]))
        index: list[int] = []
        stamps: list[float] = []
        after: list[bool] = []
        sample = self._sample
        for at, rows in parts:
            for i, (t, v) in enumerate(rows, at):
                if sample(t, v):
                    index.append(i)
                    stamps.append(t)
                    after.append(self._tripped)
                    if until_edge:
                        return edges(index, stamps, after, i + 1)
        if not index:
            return quiet_run(taken)
        return edges(index, stamps, after, taken)

    def mark(self) -> Any:
        """The running state (every attribute: parameters are only read back as they were)."""
        return self.__dict__.copy()

    def rewind(self, mark: Any) -> None:
        self.__dict__.update(mark)

    def _screened(self, t: Any, v: Any) -> bool:
        """Take a run in order, finite and on the quiet side (:meth:`_quiet`) whole; False: nothing done."""
        if not ordered(t):
            return False
        last = self.last_t
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
        self.last_t = float(t[-1])
        self._value = final_a
        return True

    def _quiet(self, t: Any, low_a: float, high_a: float, final_a: float) -> bool:
        """Take an ordered run with every |value| in [``low_a``, ``high_a``] when its samples would change nothing
        but the latest time and value (the base sets those); False: nothing taken."""
        return False

    def _sample(self, t: float, v: float) -> bool | None:
        """One sample: None when ignored, else True on an edge (its time and the latch taken)."""
        if not (math.isfinite(t) and math.isfinite(v)) or (self.last_t is not None and t < self.last_t):
            return None  # not finite, or older than the latest: ignored
        a = abs(v)
        tripped = self._step(t, a)
        self.last_t = t
        self._value = a
        if tripped == self._tripped:
            return False
        self._tripped = tripped
        self.since = t
        self._latch = self._latch or tripped
        return True

    @abstractmethod
    def _step(self, t: float, a: float) -> bool:
        """The kernel: the tripped state after one accepted sample (the base records edges, time and value)."""

    def carry_from(self, old: ProtectionModel) -> None:
        """Take over the running state of the model this one replaces (config reload; its own parameters kept): a
        reload never clears a trip; a model of another kind carries only this base part."""
        if isinstance(old, LatchedModel):
            self._tripped, self.since, self._latch, self._value, self.last_t = old.running()

    def running(self) -> tuple[bool, float | None, bool, float, float | None]:
        """What a reload carries of every model: (tripped, since, peak latch armed, latest |value|, latest time)."""
        return self._tripped, self.since, self._latch, self._value, self.last_t

    @abstractmethod
    def _levels(self) -> tuple[float, float]:
        """The trip threshold in force (in the snapshot's unit) and how close to tripping (% of the trip level)."""

    def _make_snapshot(self, tripped: bool) -> Snapshot:
        threshold, level = self._levels()
        reason = self.reason_tripped if tripped else REASON_OK
        return Snapshot(self._value, threshold, level, tripped, self.since, reason)

    def poll(self, now: float) -> Snapshot:
        """The state at tick time ``now``: tripped if tripped now or if a trip began since the last poll. The latch
        is then cleared: a spike already over is reported exactly once."""
        snap = self._make_snapshot(self._tripped or self._latch)
        self._latch = False
        return snap

    def snapshot(self) -> Snapshot:
        return self._make_snapshot(self._tripped)
