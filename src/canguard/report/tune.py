"""``canguard tune``'s statistics of one log: what each guard of the tree would need to trip on it.

A :class:`Capture` keeps every sample a guard's models get; at the end of the log a fresh copy of each
model is advanced over them with its tunable figure (:class:`Knob`) moved, searching the figure at which it
stops tripping: its *ceiling*. The model's own maths decides: nothing restates a guard's semantics.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from canguard.protect.base import ProtectionModel
from canguard.protect.hysteresis import Hysteresis
from canguard.protect.results import Run, Snapshot
from canguard.protect.threshold import Threshold

if TYPE_CHECKING:
    from canguard.bt.nodes.current import GuardNode
    from canguard.engine.core import Engine

BIN_RATIO = 1.01
"""Histogram bins of |value| are 1 % wide (log-spaced): percentiles merge across logs and workers exactly."""
_LOG_BIN = math.log(BIN_RATIO)
SEARCH_STEPS = 40
"""Bisection steps of a ceiling search, which stops once the bracket is :data:`SEARCH_REL` of its upper end."""
SEARCH_REL = 1e-5
_EMPTY = np.empty(0)
_NO_EDGE = (np.empty(0, dtype=np.intp), _EMPTY, np.empty(0, dtype=bool))


class Capture(ProtectionModel):
    """A model that never trips: it keeps every sample the engine feeds it, as the guards' models get them."""

    def __init__(self) -> None:
        self._runs: list[tuple[np.ndarray, np.ndarray]] = []
        self._t: list[float] = []
        self._v: list[float] = []

    def advance(self, times: Any, values: Any, *, until_edge: bool = False) -> Run:
        """Keep the run (copied; a run of one kept as plain floats) and report no edge."""
        if len(times) == 1:  # a frame on its own
            self._t.append(float(times[0]))
            self._v.append(float(values[0]))
            return Run(*_NO_EDGE, 1)
        self._spill()
        self._runs.append((np.array(times, dtype=np.float64), np.array(values, dtype=np.float64)))
        return Run(*_NO_EDGE, len(times))

    def mark(self) -> Any:
        """How many samples are kept (the engine goes back to it when a run went past another source's edge)."""
        self._spill()
        return len(self._runs)

    def rewind(self, mark: Any) -> None:
        """Forget the runs kept since :meth:`mark`."""
        self._spill()
        del self._runs[mark:]

    def _spill(self) -> None:
        if self._t:
            self._runs.append((np.array(self._t, dtype=np.float64), np.array(self._v, dtype=np.float64)))
            self._t, self._v = [], []

    def columns(self) -> tuple[np.ndarray, np.ndarray]:
        """Every sample kept so far, in arrival order: (times, values), finite ones only."""
        self._spill()
        if not self._runs:
            return np.empty(0), np.empty(0)
        t = np.concatenate([r[0] for r in self._runs])
        v = np.concatenate([r[1] for r in self._runs])
        self._runs = [(t, v)]
        ok = np.isfinite(t) & np.isfinite(v)
        return (t, v) if ok.all() else (t[ok], v[ok])

    def poll(self, now: float) -> Snapshot:
        """Never tripped."""
        return self.snapshot()

    def snapshot(self) -> Snapshot:
        """Never tripped."""
        return Snapshot(math.nan, math.nan, 0.0, False, None, "")

    @property
    def tripped(self) -> bool:
        """Never."""
        return False


@dataclass(frozen=True)
class Knob:
    """One figure of a guard that tune can move: ``set`` puts a value into a copy of the model; without it the
    samples are scaled instead (I²t: a rating scaled by ``s`` trips where the currents divided by ``s`` trip
    the rated model, every figure of the rating being a current)."""

    port: str
    value: float
    set: Callable[[ProtectionModel, float], None] | None = None

    @property
    def scale(self) -> bool:
        """True when tried by scaling the samples (the value is a factor on the rating)."""
        return self.set is None


def _set_max(model: ProtectionModel, value: float) -> None:
    assert isinstance(model, Threshold)
    model.set_max(value)


def knob_of(node: GuardNode) -> Knob | None:
    """The tunable figure of a guard node, None for a guard tune does not know."""
    from canguard.bt.nodes.current import IsCurrentNormal, IsCurrentSafe, IsI2tSafe, IsJointEffortNormal

    if isinstance(node, IsCurrentNormal):
        return Knob("max_current", node.model.max_value, _set_max)
    if isinstance(node, IsJointEffortNormal):
        limit = node.port("max_effort")
        return Knob("max_effort", float(limit) if limit is not None else math.nan, _set_max)
    if isinstance(node, IsCurrentSafe):
        model = node.model
        ratio = model.recovery_a / model.overcurrent_a if model.overcurrent_a else 1.0

        def set_hysteresis(m: ProtectionModel, value: float) -> None:
            assert isinstance(m, Hysteresis)
            m.set_thresholds(value, value * ratio)

        return Knob("overcurrent_threshold", model.overcurrent_a, set_hysteresis)
    if isinstance(node, IsI2tSafe):
        return Knob("continuous_current", 1.0)
    return None


def trip_time(model: ProtectionModel, knob: Knob, value: float, t: np.ndarray, v: np.ndarray) -> float | None:
    """When a fresh copy of ``model`` with the knob at ``value`` first trips over the samples; None: never."""
    trial = copy.deepcopy(model)
    if knob.scale:
        v = v / value
    else:
        assert knob.set is not None
        knob.set(trial, value)
    run = trial.advance(t, v)
    hit = np.flatnonzero(run.tripped)
    return float(run.t[hit[0]]) if hit.size else None


def ceiling(model: ProtectionModel, knob: Knob, t: np.ndarray, v: np.ndarray) -> tuple[float, float | None]:
    """The knob's value at and above which the model no longer trips on the samples, and the trip time just below.

    ``(0.0, None)``: no trip even at the smallest value; ``(inf, time)``: a trip whatever the value (another
    figure, an inrush threshold or a stale gap, trips it).
    """
    def trips(value: float) -> float | None:
        return trip_time(model, knob, value, t, v)

    if knob.scale:
        lo, hi = 1e-3, 1.0
        while trips(hi) is not None:
            lo, hi = hi, hi * 2.0
            if hi > 1e6:
                return math.inf, trips(lo)
    else:
        if not v.size or not np.any(v):
            return 0.0, None
        lo, hi = 0.0, float(np.max(np.abs(v))) * (1.0 + 1e-9) + 1e-12
        if trips(hi) is not None:
            return math.inf, trips(hi)
    if trips(lo) is None:
        return lo, None
    for _ in range(SEARCH_STEPS):
        if hi - lo <= SEARCH_REL * hi:
            break
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if trips(mid) is None else (mid, hi)
    return hi, trips(lo)


INRUSH_HORIZON = 4.0
"""A start's envelope follows its samples for this many inrush windows (or up to the next start)."""


def staircase(dt: np.ndarray, a: np.ndarray) -> list[list[float]]:
    """The points (time since a start, |I|) no later point reaches: the longest time above each level."""
    if not dt.size:
        return []
    order = np.argsort(-dt, kind="stable")
    dt, a = dt[order], a[order]
    before = np.concatenate(([-np.inf], np.maximum.accumulate(a)[:-1]))
    keep = a > before
    return [[float(x), float(y)] for x, y in zip(dt[keep].tolist(), a[keep].tolist(), strict=True)]


def envelope(model: ProtectionModel, t: np.ndarray, v: np.ndarray) -> dict[str, Any] | None:
    """An inrush-blanked guard's motor starts, as its own start detection finds them: how many, the highest |I| in
    a window, the staircase; None for a guard without inrush blanking."""
    inrush = getattr(model, "inrush", None)
    if inrush is None or not t.size:
        return None
    window = float(inrush.inrush_time_s)
    a = np.abs(v)
    starts = np.flatnonzero(copy.deepcopy(inrush).advance(t, a))
    since: list[np.ndarray] = [_EMPTY]
    seen: list[np.ndarray] = [_EMPTY]
    for i, s in enumerate(starts.tolist()):
        stop = int(starts[i + 1]) if i + 1 < starts.size else t.size
        stop = min(stop, int(np.searchsorted(t, t[s] + INRUSH_HORIZON * window, side="right")))
        since.append(t[s:stop] - t[s])
        seen.append(a[s:stop])
    dt, level = np.concatenate(since), np.concatenate(seen)
    inside = level[dt < window]
    return {"starts": int(starts.size), "peak": float(inside.max()) if inside.size else 0.0, "window": window,
            "envelope": staircase(dt, level)}


def histogram(a: np.ndarray) -> dict[str, int]:
    """|value| counted in 1 % bins (the key is the bin's index as text; ``"z"`` counts zeros): JSON-able."""
    zero = int(np.count_nonzero(a == 0))
    pos = a[a > 0]
    out: dict[str, int] = {"z": zero} if zero else {}
    if pos.size:
        keys, counts = np.unique(np.floor(np.log(pos) / _LOG_BIN).astype(np.int64), return_counts=True)
        out.update({str(k): int(c) for k, c in zip(keys.tolist(), counts.tolist(), strict=True)})
    return out


def percentile(hist: dict[str, int], q: float) -> float:
    """The ``q``-th percentile of the values a (merged) :func:`histogram` counted, at the upper edge of its bin."""
    total = sum(hist.values())
    if not total:
        return math.nan
    rank = q / 100.0 * total
    seen = hist.get("z", 0)
    if seen >= rank:
        return 0.0
    for key in sorted(int(k) for k in hist if k != "z"):
        seen += hist[str(key)]
        if seen >= rank:
            return BIN_RATIO ** (key + 1)
    return math.nan


def gaps(t: np.ndarray) -> tuple[float, float]:
    """(longest, median) time between consecutive samples; NaN with fewer than two."""
    if t.size < 2:
        return math.nan, math.nan
    d = np.diff(np.sort(t))
    return float(d.max()), float(np.median(d))


class TuneStats:
    """Hung on an engine before its log: at the end, each guard's ceiling and the statistics of its signals."""

    def __init__(self, engine: Engine, *, tune_i2t: bool = False) -> None:
        self.engine = engine
        self.tune_i2t = tune_i2t
        self._captures: dict[tuple[str, str], Capture] = {}
        self._guards: list[tuple[GuardNode, Knob | None, list[tuple[str, ProtectionModel]]]] = []
        for node in engine.guard_nodes:
            knob = knob_of(node)
            # The models as the tree built them, before any sample: each trial starts from a copy.
            fresh = [(role, copy.deepcopy(model)) for role, model, _kind in node.guarded()]
            self._guards.append((node, knob, fresh))
            for role, _model in fresh:
                key = (node.topic_name, role)
                if key not in self._captures:
                    cap = self._captures[key] = Capture()
                    engine.ctx.subscribe(node.topic_name, role, cap)

    def result(self) -> dict[str, Any]:
        """Per guard node: its knob, and per signal the samples' statistics and the ceiling on this log (small and
        JSON-able: it travels in the replay summary). Times are seconds from the log's first frame."""
        start = self.engine.first_frame_t
        start = start if math.isfinite(start) else 0.0
        guards = []
        for node, knob, fresh in self._guards:
            signals = []
            for role, model in fresh:
                t, v = self._captures[(node.topic_name, role)].columns()
                a = np.abs(v)
                entry: dict[str, Any] = {"role": role, "samples": int(a.size)}
                if a.size:
                    at = int(np.argmax(a))
                    longest, median = gaps(t)
                    entry.update(peak=float(a[at]), peak_t=float(t[at]) - start, hist=histogram(a),
                                 gap=longest, period=median)
                    if knob is not None and (not knob.scale or self.tune_i2t):
                        top, when = ceiling(model, knob, t, v)
                        entry.update(ceiling=top, ceiling_t=None if when is None else when - start)
                    inrush = envelope(model, t, v)
                    if inrush is not None:
                        entry["inrush"] = inrush
                    heat = getattr(model, "trip_level", None)
                    if heat is not None:
                        entry["heat_pct"] = float(self.engine.stats.max_level_pct.get(node.name, math.nan))
                signals.append(entry)
            guards.append({
                "node": node.name, "type": type(node).__name__, "source": node.topic_name,
                "port": knob.port if knob is not None else None,
                "value": knob.value if knob is not None and not knob.scale else None,
                "signals": signals,
            })
        return {"guards": guards}
