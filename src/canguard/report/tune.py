"""``canguard tune``'s maths: the statistics of one log, and the proposal they add up to.

A guard's *ceiling* is the figure at which a fresh copy of its model, advanced over the captured samples, stops
tripping: the model's own maths decides. The proposal's rules: docs/commands.md (``canguard tune``).
"""

from __future__ import annotations

import copy
import math
from array import array
from bisect import bisect_left
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from itertools import accumulate
from typing import TYPE_CHECKING, Any

import numpy as np

from canguard.protect.base import ProtectionModel
from canguard.protect.hysteresis import Hysteresis
from canguard.protect.results import Run, Snapshot
from canguard.protect.threshold import Threshold
from canguard.report.summary import rounded

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
        self._t = array("d")
        self._v = array("d")

    def advance(self, times: Any, values: Any, *, until_edge: bool = False) -> Run:
        """Keep the run and report no edge."""
        if len(times) == 1:  # a frame on its own
            self._t.append(float(times[0]))
            self._v.append(float(values[0]))
        else:
            self._t.frombytes(np.asarray(times, dtype=np.float64).tobytes())
            self._v.frombytes(np.asarray(values, dtype=np.float64).tobytes())
        return Run(*_NO_EDGE, len(times))

    def mark(self) -> Any:
        """How many samples are kept (the engine goes back to it when a run went past another source's edge)."""
        return len(self._t)

    def rewind(self, mark: Any) -> None:
        """Forget the samples kept since :meth:`mark`."""
        del self._t[mark:]
        del self._v[mark:]

    def columns(self) -> tuple[np.ndarray, np.ndarray]:
        """Every sample kept so far, in arrival order: (times, values), finite ones only."""
        t, v = np.array(self._t, dtype=np.float64), np.array(self._v, dtype=np.float64)
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
    samples are scaled instead (an I²t rating scaled by ``s`` trips where the currents divided by ``s`` do)."""

    port: str
    value: float
    set: Callable[[ProtectionModel, float], None] | None = None


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
    if knob.set is None:
        v = v / value
    else:
        knob.set(trial, value)
    run = trial.advance(t, v)
    hit = np.flatnonzero(run.tripped)
    return float(run.t[hit[0]]) if hit.size else None


def ceiling(model: ProtectionModel, knob: Knob, t: np.ndarray, v: np.ndarray) -> tuple[float, float | None]:
    """The knob's value at and above which the model no longer trips on the samples, and the trip time just below;
    ``(0.0, None)``: no trip at all; ``(inf, time)``: a trip whatever the value (another figure trips it)."""
    trips = partial(trip_time, model, knob, t=t, v=v)  # when a copy with the knob at a value first trips
    if knob.set is None:
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
    keys, counts = np.unique(np.floor(np.log(pos) / _LOG_BIN).astype(np.int64), return_counts=True)
    out.update({str(k): int(c) for k, c in zip(keys.tolist(), counts.tolist(), strict=True)})
    return out


def percentile(hist: dict[str, int], q: float) -> float:
    """The ``q``-th percentile of the values a (merged) :func:`histogram` counted, at the upper edge of its bin."""
    keys = sorted(int(k) for k in hist if k != "z")
    seen = list(accumulate([hist.get("z", 0), *(hist[str(k)] for k in keys)]))  # counted up to each bin
    if not seen[-1]:
        return math.nan
    at = bisect_left(seen, q / 100.0 * seen[-1])  # the first bin whose count reaches the rank
    return 0.0 if at == 0 else BIN_RATIO ** (keys[at - 1] + 1)


def gaps(t: np.ndarray) -> tuple[float, float]:
    """(longest, median) time between consecutive samples; NaN with fewer than two."""
    if t.size < 2:
        return math.nan, math.nan
    d = np.diff(np.sort(t))
    return float(d.max()), float(np.median(d))


def tune_stats(engine: Engine, *, tune_i2t: bool = False) -> Callable[[], dict[str, Any]]:
    """Hung on an engine before its log: what, at the end, gives per guard node its knob, and per signal the
    samples' statistics and the ceiling on this log (JSON-able; times from the log's first frame)."""
    captures: dict[tuple[str, str], Capture] = {}
    nodes = [(node, knob_of(node), [(role, copy.deepcopy(model)) for role, model, _kind in node.guarded()])
             for node in engine.guard_nodes]  # the models as the tree built them: each trial starts from a copy
    for node, _knob, fresh in nodes:
        for role, _model in fresh:
            if (node.topic_name, role) not in captures:
                captures[(node.topic_name, role)] = cap = Capture()
                engine.ctx.subscribe(node.topic_name, role, cap)

    def result() -> dict[str, Any]:
        start = engine.first_frame_t if math.isfinite(engine.first_frame_t) else 0.0
        guards = []
        for node, knob, fresh in nodes:
            signals = []
            for role, model in fresh:
                t, v = captures[(node.topic_name, role)].columns()
                a = np.abs(v)
                entry: dict[str, Any] = {"role": role, "samples": int(a.size)}
                if a.size:
                    at = int(np.argmax(a))
                    longest, median = gaps(t)
                    entry.update(peak=float(a[at]), peak_t=float(t[at]) - start, hist=histogram(a),
                                 gap=longest, period=median)
                    if knob is not None and (knob.set is not None or tune_i2t):
                        top, when = ceiling(model, knob, t, v)
                        entry.update(ceiling=top, ceiling_t=None if when is None else when - start)
                    inrush = envelope(model, t, v)
                    if inrush is not None:
                        entry["inrush"] = inrush
                    if getattr(model, "trip_level", None) is not None:
                        entry["heat_pct"] = float(engine.stats.max_level_pct.get(node.name, math.nan))
                signals.append(entry)
            guards.append({
                "node": node.name, "type": type(node).__name__, "source": node.topic_name,
                "port": knob.port if knob is not None else None,
                "value": knob.value if knob is not None and knob.set is not None else None,
                "signals": signals,
            })
        return {"guards": guards}

    return result


GAP_FACTOR = 1.5
"""A proposed ``max_age`` is the longest healthy gap times this."""


@dataclass(frozen=True)
class LogStats:
    """One log's statistics as the replay returned them."""

    name: str
    fault: bool
    tune: dict[str, Any]


@dataclass(frozen=True)
class Need:
    """What one log asks of a figure: a value (ceiling or gap) and when it happened."""

    log: str
    value: float
    t: float | None


def _need(n: Need | None) -> dict[str, Any] | None:
    return None if n is None else {"log": n.log, "value": rounded(n.value), "t": rounded(n.t)}


@dataclass
class Proposal:
    """One guard's figure: old -> new, and why."""

    node: str
    type: str
    source: str
    port: str | None
    old: float | None
    new: float | None = None
    status: str = "left"
    """``tuned``, ``left`` or ``conflict``."""
    why: str = ""
    healthy: Need | None = None
    peak: Need | None = None
    p99: float = math.nan
    p999: float = math.nan
    faults: list[Need] = field(default_factory=list)
    heat: list[Need] = field(default_factory=list)
    """I²t: the highest level each log reached (% of the trip level)."""
    hist: dict[str, int] = field(default_factory=dict)
    """The healthy logs' |values| in :func:`~canguard.report.tune.histogram` bins (``--plot``)."""
    inrush: dict[str, Any] | None = None
    """An inrush-blanked guard: the healthy starts (count, peak, window old -> new and why)."""
    scale: bool = False
    """The figure is a factor on an I²t rating (continuous and peak current scale together)."""

    def as_json(self) -> dict[str, Any]:
        """The proposal as plain data (``--json``)."""
        return {
            "node": self.node, "type": self.type, "source": self.source, "port": self.port,
            "old": rounded(self.old), "new": rounded(self.new), "status": self.status, "why": self.why,
            "healthy_ceiling": _need(self.healthy), "healthy_peak": _need(self.peak),
            "healthy_p99": rounded(self.p99), "healthy_p99_9": rounded(self.p999),
            "faults": [_need(f) for f in self.faults], "heat_pct": [_need(h) for h in self.heat],
            "rating_scale": self.scale, "inrush": self.inrush,
        }


@dataclass
class AgeProposal:
    """One source's ``max_age``: old -> new, and why."""

    source: str
    old: float
    new: float | None
    status: str
    why: str
    gap: Need | None
    period: float
    faults: list[Need] = field(default_factory=list)

    def as_json(self) -> dict[str, Any]:
        """The proposal as plain data (``--json``)."""
        return {"source": self.source, "old": rounded(self.old), "new": rounded(self.new), "status": self.status,
                "why": self.why, "period": rounded(self.period), "healthy_gap": _need(self.gap),
                "faults": [{"log": f.log, "value": rounded(f.value)} for f in self.faults]}


def nice_up(x: float, below: float = math.inf) -> float:
    """``x`` rounded up to three significant digits, unless that reaches ``below``."""
    if x <= 0 or not math.isfinite(x):
        return x
    step = 10.0 ** (math.floor(math.log10(x)) - 2)
    up = round(math.ceil(x / step - 1e-9) * step, 12)
    return up if up < below else x


def separate(healthy: float, needs: list[float], margin: float) -> tuple[float | None, str]:
    """A value at or above ``healthy`` × (1 + margin) and below every need; (None, why) when none exists."""
    low = healthy * (1.0 + margin)
    need = min(needs, default=math.inf)
    if low < need:
        return nice_up(low, need), ""
    if healthy < need:
        mid = 0.5 * (healthy + need)
        return mid, f"margin reduced to {100.0 * (mid / healthy - 1.0):.1f} % (a fault needs less than {need:.6g})"
    return None, ""


def _signals(log: LogStats, node: str) -> list[dict[str, Any]]:
    return next((g["signals"] for g in log.tune["guards"] if g["node"] == node), [])


def _best(needs: list[Need]) -> Need | None:
    return max(needs, key=lambda n: n.value) if needs else None


def propose_guard(node: str, logs: list[LogStats], expect: dict[str, list[str]] | None, margin: float,
                  tune_i2t: bool) -> Proposal:
    """The proposal for one guard node of the tree (see the module docstring)."""
    head = next(g for log in logs for g in log.tune["guards"] if g["node"] == node)
    is_i2t = head["type"] == "IsI2tSafe"
    prop = Proposal(node, head["type"], head["source"], head["port"], head["value"], scale=is_i2t)
    ceilings: list[Need] = []
    peaks: list[Need] = []
    faults: list[Need] = []
    for log in logs:
        mine = [s for s in _signals(log, node) if s.get("samples")]
        if not mine:
            continue
        if is_i2t:
            prop.heat.append(Need(log.name, max(s.get("heat_pct", math.nan) for s in mine), None))
        top = max(mine, key=lambda s: s.get("ceiling", -math.inf))
        ceiling = [Need(log.name, top["ceiling"], top.get("ceiling_t"))] if "ceiling" in top else []
        if log.fault:
            faults += ceiling
            continue
        peak = max(mine, key=lambda s: s["peak"])
        peaks.append(Need(log.name, peak["peak"], peak["peak_t"]))
        for k, c in ((k, c) for s in mine for k, c in s["hist"].items()):
            prop.hist[k] = prop.hist.get(k, 0) + c
        ceilings += ceiling
    prop.peak, prop.healthy = _best(peaks), _best(ceilings)
    starts = [s["inrush"] for log in logs if not log.fault for s in _signals(log, node) if s.get("inrush")]
    prop.p99, prop.p999 = percentile(prop.hist, 99.0), percentile(prop.hist, 99.9)
    if expect is not None:
        prop.faults = [f for f in faults if node in expect.get(f.log, [])]
    else:  # a fault the guard clearly sees: beyond the healthy ceiling by more than the margin
        floor = prop.healthy.value * (1.0 + margin) if prop.healthy is not None else 0.0
        prop.faults = [f for f in faults if math.isfinite(f.value) and f.value > floor]
    _decide(prop, margin, tune_i2t)
    if starts:
        prop.inrush = _inrush(starts, prop.new, margin)
    return prop


def _inrush(starts: list[dict[str, Any]], threshold: float | None, margin: float) -> dict[str, Any]:
    """The healthy motor starts of an inrush-blanked guard, and its window: the longest healthy start (above the
    tuned threshold) × (1 + margin); kept when no start rises above the threshold, or none was seen."""
    window = starts[0]["window"]
    count = sum(s["starts"] for s in starts)
    out: dict[str, Any] = {"starts": count, "peak": max(s["peak"] for s in starts), "old": window, "new": None}
    if threshold is None or not count:
        out["why"] = "no healthy start seen: window kept" if not count else "threshold not tuned: window kept"
        return out
    longest = max((p[0] for s in starts for p in s["envelope"] if p[1] >= threshold), default=0.0)
    out["longest_s"] = longest
    if longest <= 0.0:
        out["why"] = "no healthy start rises above the new threshold: window kept"
        return out
    out["new"] = nice_up(longest * (1.0 + margin))
    out["why"] = f"the longest healthy start stays above {threshold:.4g} for {longest:.4g} s"
    return out


def _decide(prop: Proposal, margin: float, tune_i2t: bool) -> None:
    if prop.port is None:
        prop.why = "tune knows no figure of this node type"
        return
    if prop.scale and not tune_i2t:
        prop.why = "an I²t rating is the motor's datasheet value: reported, proposed only with --tune-i2t"
        return
    healthy = prop.healthy
    if healthy is None or (prop.peak is not None and prop.peak.value == 0.0):
        prop.why = "no healthy log exercises it: left as it is"
        return
    if not math.isfinite(healthy.value):
        prop.status = "conflict"
        prop.why = (f"healthy log {healthy.log} trips it whatever its {prop.port}"
                    f"{_at(healthy.t)} (another figure of the guard trips it)")
        return
    value, note = separate(healthy.value, [f.value for f in prop.faults], margin)
    if value is None:
        worst = min(prop.faults, key=lambda f: f.value)
        prop.status = "conflict"
        prop.why = (f"healthy log {healthy.log} needs {prop.port} >= {healthy.value:.6g}{_at(healthy.t)}, "
                    f"fault log {worst.log} trips only below {worst.value:.6g}{_at(worst.t)}")
        return
    prop.status = "tuned"
    prop.new = value
    prop.why = note


def _at(t: float | None) -> str:
    return "" if t is None or not math.isfinite(t) else f" (at t={t:.3f} s)"


def propose_age(source: str, old: float, logs: list[LogStats]) -> AgeProposal | None:
    """``max_age`` of one source, or None when no log has two samples of it."""
    healthy: list[Need] = []
    periods: list[float] = []
    faults: list[Need] = []
    for log in logs:
        gaps = [(s["gap"], s["period"]) for g in log.tune["guards"] if g["source"] == source
                for s in g["signals"] if s.get("samples", 0) >= 2]
        if not gaps:
            continue
        gap = max(g for g, _p in gaps)
        if log.fault:
            faults.append(Need(log.name, gap, None))
        else:
            healthy.append(Need(log.name, gap, None))
            periods.extend(p for _g, p in gaps)
    top = _best(healthy)
    if top is None:
        return None
    period = sorted(periods)[len(periods) // 2]
    caught = [f for f in faults if f.value > top.value * GAP_FACTOR]  # a dropout, not jitter
    value, note = separate(top.value, [f.value for f in caught], GAP_FACTOR - 1.0)
    if top.value < old and all(f.value > old for f in caught):
        value, status, note = None, "left", f"fits: longest healthy gap {top.value:.3g} s < max_age"
    elif value is None:
        status, note = "conflict", f"healthy log {top.log} has a gap of {top.value:.3g} s, as long as a fault's"
    else:
        value, status = max(value, period), "tuned"
    return AgeProposal(source, old, value, status, note, top, period, caught)


def propose(logs: list[LogStats], ages: dict[str, float], expect: dict[str, list[str]] | None, margin: float,
            tune_i2t: bool) -> tuple[list[Proposal], list[AgeProposal]]:
    """Every guard's proposal (tree order) and every guarded source's ``max_age``."""
    nodes = dict.fromkeys(g["node"] for log in logs for g in log.tune["guards"])
    guards = [propose_guard(n, logs, expect, margin, tune_i2t) for n in nodes]
    out = [propose_age(s, ages[s], logs) for s in dict.fromkeys(p.source for p in guards) if s in ages]
    return guards, [a for a in out if a is not None]
