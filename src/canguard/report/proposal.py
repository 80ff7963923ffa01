"""``canguard tune``'s proposal: each guard's figure between what healthy logs reach and what faults need.

Per guard the healthy ceiling × (1 + margin), rounded up while below what every fault assigned to it needs
(else the midpoint, said; else a conflict); a source's ``max_age`` only where the value in force fails a log.
The rules: docs/commands.md (``canguard tune``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from canguard.report.summary import rounded
from canguard.report.tune import percentile

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
    fails = top.value >= old or any(f.value <= old for f in caught)
    if not fails:
        return AgeProposal(source, old, None, "left", f"fits: longest healthy gap {top.value:.3g} s < max_age",
                           top, period, caught)
    value, note = separate(top.value, [f.value for f in caught], GAP_FACTOR - 1.0)
    if value is None:
        return AgeProposal(source, old, None, "conflict", f"healthy log {top.log} has a gap of {top.value:.3g} s, "
                           "as long as a fault's", top, period, caught)
    return AgeProposal(source, old, max(value, period), "tuned", note, top, period, caught)


def propose(logs: list[LogStats], ages: dict[str, float], expect: dict[str, list[str]] | None, margin: float,
            tune_i2t: bool) -> tuple[list[Proposal], list[AgeProposal]]:
    """Every guard's proposal (tree order) and every guarded source's ``max_age``."""
    nodes = dict.fromkeys(g["node"] for log in logs for g in log.tune["guards"])
    guards = [propose_guard(n, logs, expect, margin, tune_i2t) for n in nodes]
    out = [propose_age(s, ages[s], logs) for s in dict.fromkeys(p.source for p in guards) if s in ages]
    return guards, [a for a in out if a is not None]
