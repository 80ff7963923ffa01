"""The summary of one replay: counters, trips, stops, margins and what went unguarded.

Deterministic: the same log and config give byte-identical JSON (``--baseline`` compares saved ones).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, NamedTuple

from canguard.config.schema import Config
from canguard.engine.core import Engine
from canguard.engine.routing import ChannelRouter
from canguard.units import I2T_LIMIT_PCT, quantity

SUMMARY_VERSION = 1


def rounded(x: float | None, nd: int = 6) -> float | None:
    """Round for a stable summary; None, NaN and inf become None so the JSON stays valid."""
    return None if x is None or not math.isfinite(x) else round(x, nd)


def build_summary(cfg: Config, log_path: Path, engine: Engine, stats: Any, router: ChannelRouter) -> dict[str, Any]:
    """The summary of one replay: counters, trips, time stopped and the lowest margin to each threshold."""
    d = engine.decoder
    es = engine.stats
    end = engine.clock.now()
    guards = engine.guards()
    units = {(g.node, g.role): g.threshold_unit for g in guards}
    trips = [
        {**{k: (rounded(v) if isinstance(v, float) else v) for k, v in ev.items()
            if k in ("t", "node", "source", "value", "threshold", "reason")},
         "unit": units.get((str(ev.get("node")), str(ev.get("signal"))), "")}
        for ev in es.trips
    ]
    margins = []
    for guard in guards:
        peak = es.max_abs.get((guard.source, guard.role), math.nan) if guard.kind == "threshold" else \
            es.max_level_pct.get(guard.node, math.nan)
        threshold = guard.threshold() if guard.kind == "threshold" else 100.0
        margins.append({
            "node": guard.node, "source": guard.source, "signal": guard.role, "kind": guard.kind,
            "threshold": rounded(threshold), "peak": rounded(peak), "unit": guard.margin_unit,
            "margin": rounded(threshold - peak) if math.isfinite(peak) else None,
            "margin_pct": rounded(100.0 * (threshold - peak) / threshold, 2)
            if math.isfinite(peak) and threshold else None,
        })
    unmapped = dict(sorted(router.unmapped.items()))
    merged = router.merged()
    summary: dict[str, Any] = {
        "version": SUMMARY_VERSION,
        "log": str(log_path),
        "config": str(cfg.path),
        "frames": {
            "read": stats.frames, "decoded": d.decoded, "invalid": d.invalid, "skipped": d.skipped,
            "unmapped": sum(unmapped.values()), "error_frames": d.error_frames,
            "remote_frames": d.remote_frames, "bad_lines": stats.bad_lines,
            "backward_timestamps": stats.backwards_timestamps, "repeated_timestamps": stats.repeated_timestamps,
        },
        "unmapped_channels": unmapped,
        "samples": dict(sorted(es.samples.items())),
        "unguarded_sources": sorted(n for n in cfg.sources if not es.samples.get(n)),  # their guards judged nothing
        "ticks": es.ticks, "edge_ticks": es.edge_ticks, "tick_errors": es.tick_errors,
        "trips": trips,
        "trip_count": es.trip_count,
        "stops": engine.gate.stops,
        "stopped_s": rounded(engine.gate.stopped_total(end), 4),
        "escalations": engine.events_seen["escalate"],
        "confirmations": engine.events_seen["confirmed"],
        "margins": margins,
        "first_t": rounded(engine.first_frame_t), "last_t": rounded(end),
        "frames_sent": getattr(engine.sink, "sent", 0),
    }
    if getattr(stats, "stamps", None):  # a ROS bag: which times its frames took
        summary["stamps"] = dict(sorted(stats.stamps.items()))
    if merged:  # only then: summaries of logs without a merge keep their shape (committed examples)
        summary["merged_channels"] = merged
        summary["merged_into"] = router.only
    return summary


def render_text(s: dict[str, Any]) -> str:
    """The human summary printed on stdout."""
    f = s["frames"]
    lines = [
        f"replay of {s['log']} with {s['config']}",
        f"  frames: {f['read']} read, {f['decoded']} decoded, {f['invalid']} invalid, {f['skipped']} skipped"
        f" (not configured), {f['unmapped']} on unmapped channels, {f['error_frames']} error frames,"
        f" {f['bad_lines']} bad lines, {f['backward_timestamps']} backward timestamps",
        "  samples: " + (", ".join(f"{k} {v}" for k, v in s["samples"].items()) or "none"),
        f"  ticks: {s['ticks']} ({s['edge_ticks']} on protection edges)",
        f"  trips: {s['trip_count']}" + (f" (the first {len(s['trips'])} listed)"
                                          if s["trip_count"] > len(s["trips"]) else ""),
    ]
    for t in s["trips"]:
        unit = t.get("unit")
        lines.append(f"    t={t.get('t')} {t.get('node')} source={t.get('source')}"
                     f" value={quantity(t.get('value'), unit)} threshold={quantity(t.get('threshold'), unit)}"
                     f" reason={t.get('reason')}")
    if s.get("stamps"):
        st = s["stamps"]
        lines.append(f"  times: header.stamp of {st.get('header', 0)} frames, record time of {st.get('record', 0)}")
    lines.append(f"  stops: {s['stops']}, stopped {s['stopped_s']} s; frames canguard would send: "
                 f"{s['frames_sent']}; stop confirmations {s['confirmations']}, escalations {s['escalations']}")
    lines.append("  lowest margin to each threshold:")
    for m in s["margins"]:  # every figure with its unit (``peak 31.6 A vs threshold 35 A: ...``)
        unit = m.get("unit")
        pct = "" if unit == I2T_LIMIT_PCT else f" ({m.get('margin_pct')} % of the threshold)"
        text = "no data" if m.get("margin") is None else (
            f"peak {quantity(m['peak'], unit)} vs threshold {quantity(m['threshold'], unit)}: "
            f"margin {quantity(m['margin'], unit)}{pct}")
        lines.append(f"    {m['node']} ({m['source']} {m['signal']}): {text}")
    if s["unmapped_channels"]:
        lines.append("  warning: frames on channels no bus takes (use --map CHANNEL=BUS): "
                     + ", ".join(f"{k} ({v})" for k, v in s["unmapped_channels"].items()))
    if s.get("merged_channels"):
        hint = ("--realtime plays every channel onto one bus: split the log by channel to choose"
                if "realtime_speed" in s else "use --map CHANNEL=BUS to choose what each bus takes")
        lines.append(f"  warning: frames of several channels were merged into bus {s.get('merged_into')} ({hint}): "
                     + ", ".join(f"{k} ({v})" for k, v in s["merged_channels"].items()))
    if s.get("unguarded_sources"):
        lines.append("  warning: no sample of " + ", ".join(s["unguarded_sources"])
                     + ": their guards judged nothing on this log")
    if f["read"] and not f["decoded"]:
        lines.append("  warning: no frame of this log matches a configured message")
    return "\n".join(lines)


class Change(NamedTuple):
    """One difference from a saved summary; ``regression`` when ``--fail-on-regression`` fails on it."""

    text: str
    regression: bool


def diff_baseline(base: dict[str, Any], new: dict[str, Any], margin_tolerance_pct: float = 0.0) -> list[Change]:
    """What changed against a saved --json summary: trips gained or lost and margins that shrank by more than
    ``margin_tolerance_pct`` % of their threshold (regressions), stop counts (reported only)."""

    def key(t: dict[str, Any]) -> tuple[str, str, str]:
        return (str(t.get("node")), str(t.get("source")), str(t.get("reason")))

    out: list[Change] = []
    old_trips = [key(t) for t in base.get("trips", [])]
    new_trips = [key(t) for t in new.get("trips", [])]
    for k in sorted(set(new_trips) | set(old_trips)):
        n_old, n_new = old_trips.count(k), new_trips.count(k)
        if n_new != n_old:
            what = "new trip" if n_new > n_old else "lost trip"
            out.append(Change(f"{what}: {k[0]} on {k[1]} ({k[2]}): {n_old} -> {n_new}", True))
    old_m = {(m["node"], m["signal"]): m for m in base.get("margins", [])}
    for m in new.get("margins", []):
        o = old_m.get((m["node"], m["signal"]))
        if o is None or o.get("margin") is None or m.get("margin") is None:
            continue
        shrink = o["margin"] - m["margin"]
        if shrink > 1e-9:
            threshold = abs(m.get("threshold") or 0.0)
            pct = 100.0 * shrink / threshold if threshold else math.inf
            unit = m.get("unit")
            out.append(Change(f"margin shrank: {m['node']} ({m['source']} {m['signal']}): "
                              f"{quantity(o['margin'], unit)} -> {quantity(m['margin'], unit)} "
                              f"({pct:.4g} % of the threshold)", pct > margin_tolerance_pct))
    if base.get("stops") != new.get("stops"):
        out.append(Change(f"stops: {base.get('stops')} -> {new.get('stops')}", False))
    return out
