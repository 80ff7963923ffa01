"""``canguard tune``: thresholds proposed from healthy logs and known faults, proven by replay."""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

from canguard.cli.common import EXIT_OK, EXIT_TRIPPED, add_config, config_path, subcommand
from canguard.config.loader import load_config
from canguard.config.schema import Config
from canguard.errors import ConfigError


def add_parser(sub: argparse._SubParsersAction) -> None:
    """``canguard tune``."""
    p = subcommand(sub, "tune", cmd_tune, description=__doc__.split("\n\n")[0])
    p.add_argument("logs", nargs="*", type=Path, metavar="HEALTHY_LOG",
                   help="logs of healthy operation (files, directories, quoted globs, @LIST)")
    add_config(p)
    p.add_argument("--fault", action="append", type=Path, default=[], metavar="LOG",
                   help="a log of a fault the guards must trip on (repeatable)")
    p.add_argument("--expect", type=Path, metavar="FILE",
                   help="YAML: per log, `healthy: true` or the guards that must trip and by when")
    p.add_argument("--margin", type=float, default=10.0, metavar="PCT",
                   help="head room above the healthy logs' ceiling (default 10)")
    p.add_argument("--tune-i2t", action="store_true",
                   help="also propose I²t ratings (else the motor's datasheet values are kept and reported)")
    p.add_argument("--out", type=Path, metavar="DIR", help="write the tuned config and tree here")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--plot", type=Path, metavar="FILE", help="the healthy values per guard with old/new thresholds")
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="replay the logs in N processes")
    p.add_argument("--dask", metavar="SCHEDULER", default=None, help="replay the logs on a Dask cluster")


def load_expect(path: Path) -> dict[str, dict[str, Any]]:
    """``--expect``: per log name, ``{"healthy": True}`` or ``{"trips": [(guard, by_s | None), ...]}``."""
    from canguard.config.yamlsrc import load_yaml

    try:
        doc = load_yaml(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"--expect {path}: cannot read: {exc}") from None
    except Exception as exc:  # yaml's errors: the file's own words, with line
        raise ConfigError(f"--expect {path}: not YAML: {exc}") from None
    if not isinstance(doc, list):
        raise ConfigError(f"--expect {path}: expected a list of {{log: NAME, healthy: true}} or "
                          f"{{log: NAME, trips: [{{guard: NODE, by: SECONDS}}]}}")
    out: dict[str, dict[str, Any]] = {}
    for i, item in enumerate(doc):
        where = f"--expect {path}: item {i + 1}"
        if not isinstance(item, dict) or not isinstance(item.get("log"), str):
            raise ConfigError(f"{where}: expected a mapping with a `log:` name")
        unknown = set(item) - {"log", "healthy", "trips"}
        if unknown:
            raise ConfigError(f"{where}: unknown key {sorted(unknown)[0]!r} (expected log, healthy, trips)")
        if item.get("healthy") is True:
            out[item["log"]] = {"healthy": True}
            continue
        trips = item.get("trips")
        if not isinstance(trips, list) or not trips:
            raise ConfigError(f"{where}: expected `healthy: true` or a non-empty `trips:` list")
        parsed = []
        for trip in trips:
            if not isinstance(trip, dict) or not isinstance(trip.get("guard"), str):
                raise ConfigError(f"{where}: a trip is {{guard: NODE, by: SECONDS}}")
            by = trip.get("by")
            if by is not None and not (isinstance(by, (int, float)) and math.isfinite(by) and by >= 0):
                raise ConfigError(f"{where}: by: expected seconds from the log's first frame, found {by!r}")
            parsed.append((trip["guard"], None if by is None else float(by)))
        out[item["log"]] = {"trips": parsed}
    return out


def _replay_all(args: argparse.Namespace, cfg: Config, cfg_path: Path, logs: list[Path], *,
                tune: bool) -> list[dict[str, Any]]:
    """Every log's replay summary (the statistics with ``tune``); ConfigError naming a log that failed."""
    from canguard.cli.replay import ReplayOptions, run_jobs

    opts = ReplayOptions(tune=tune, tune_i2t=args.tune_i2t)
    out = []
    for (summary, err), log in zip(run_jobs(args, cfg, cfg_path, [(log, opts) for log in logs]), logs, strict=True):
        if summary is None:
            raise ConfigError(f"tune: {log}: {err}")
        out.append(summary)
    return out


def cmd_tune(args: argparse.Namespace) -> int:
    """Statistics, proposal, proving replay, files: exit 0, 1 (no separation / proof failed) or 2."""
    from canguard.cli.fleet import expand_logs
    from canguard.report.tune import LogStats, propose

    cfg_path = config_path(args)
    cfg = load_config(cfg_path)
    if not math.isfinite(args.margin) or args.margin < 0:
        raise ConfigError(f"--margin: expected a percentage >= 0, found {args.margin!r}")
    healthy = expand_logs(args.logs) if args.logs else []
    faults = expand_logs(args.fault) if args.fault else []
    if not healthy:
        raise ConfigError("tune: name at least one healthy log (the thresholds are set above what they reach)")
    expect = load_expect(args.expect) if args.expect is not None else {}
    _check_out(args.out, cfg)
    if args.plot is not None:
        from canguard.io.outputs import check_output
        from canguard.report.plot import require_matplotlib

        require_matplotlib()
        check_output(args.plot, "--plot", expected="a file name such as tune.png in a writable directory")
    logs = healthy + faults
    wanted = [expect.get(str(log), expect.get(log.name)) for log in logs]
    is_fault = [i >= len(healthy) if w is None else "trips" in w for i, w in enumerate(wanted)]
    before = _replay_all(args, cfg, cfg_path, logs, tune=True)
    stats = [LogStats(str(log), fault, s["tune"]) for log, fault, s in zip(logs, is_fault, before, strict=True)]
    needs = {str(log): [g for g, _by in (w or {}).get("trips", [])] for log, w in zip(logs, wanted, strict=True)}
    ages = {name: src.max_age_s for name, src in cfg.sources.items()}
    guards, age_props = propose(stats, ages, needs if args.expect is not None else None, args.margin / 100.0,
                                args.tune_i2t)
    report: dict[str, Any] = {"config": str(cfg_path), "margin_pct": args.margin,
                              "max_age": [a.as_json() for a in age_props]}
    conflicts = any(g.status == "conflict" for g in guards) or any(a.status == "conflict" for a in age_props)
    report["result"] = "conflict" if conflicts else "refused"
    if not conflicts:
        with tempfile.TemporaryDirectory(prefix="canguard-tune-") as tmp:
            tuned_cfg = _write_tuned(cfg, cfg_path, guards, age_props, Path(tmp))
            after = _replay_all(args, load_config(tuned_cfg), tuned_cfg, logs, tune=False)
            report["proof"] = _prove(logs, is_fault, wanted, before, after)
            if all(p["ok"] for p in report["proof"]):
                report["result"] = "proven"
                if args.out is not None:
                    shutil.copytree(tmp, args.out, dirs_exist_ok=True)
                    report["written"] = sorted(str(args.out / f.name) for f in Path(tmp).iterdir())
    report["guards"] = [g.as_json() for g in guards]  # as written: a port read from the blackboard is left
    if args.plot is not None:
        from canguard.report.plot import plot_tune

        plot_tune(args.plot, guards)
    print(json.dumps(report, indent=2, sort_keys=True) if args.json else render(report))
    if report["result"] == "proven":
        return EXIT_OK
    print("canguard tune: nothing written: " + ("no value separates the healthy logs from a fault"
                                               if conflicts else "the tuned config failed the proving replay"),
          file=sys.stderr)
    return EXIT_TRIPPED  # exit 1, as a gate that failed: nothing written


def _check_out(out: Path | None, cfg: Config) -> None:
    """``--out``: a directory that is not where the config or its tree live (written beside, never over)."""
    if out is None:
        return
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: expected a directory, found a file")
    homes = {cfg.path.resolve().parent, *([cfg.tree.file.resolve().parent] if cfg.tree is not None else [])}
    if out.resolve() in homes:
        raise ConfigError(f"--out {out}: the original config or tree lives there; tune writes beside, never over")


def _write_tuned(cfg: Config, cfg_path: Path, guards: list[Any], ages: list[Any], out: Path) -> Path:
    """The tuned config and tree in ``out``, under the originals' names; the tuned config's path."""
    from canguard.report.tunefiles import set_attributes, tuned_config

    assert cfg.tree is not None
    tree_path = cfg.tree.file
    tree_text = tree_path.read_text(encoding="utf-8")
    for g in guards:
        values = _attributes(g, tree_text) if g.status == "tuned" and g.new is not None else {}
        if values:
            tree_text = set_attributes(tree_text, g.node, values, str(tree_path))
    (out / tree_path.name).write_text(tree_text, encoding="utf-8")
    ages_new = {a.source: a.new for a in ages if a.status == "tuned" and a.new is not None}
    target = out / cfg_path.name
    target.write_text(tuned_config(cfg_path.read_text(encoding="utf-8"), cfg_path.resolve().parent, tree_path.name,
                                   ages_new), encoding="utf-8")
    return target


def _attributes(g: Any, tree_text: str) -> dict[str, float]:
    """The XML attributes a tuned guard gets (a port wired to a blackboard key is left, and said)."""
    from canguard.report.tunefiles import port_text

    written = port_text(tree_text, g.node, g.port)
    if written is not None and written.strip().startswith("{"):
        g.status, g.new = "left", None
        g.why = f"{g.port} reads the blackboard ({written}): set where that key is written"
        return {}
    if g.type == "IsCurrentSafe":
        over = float(port_text(tree_text, g.node, "overcurrent_threshold") or g.old)
        rec = float(port_text(tree_text, g.node, "recovery_threshold") or 25.0)
        # the recovery keeps its ratio to the trip threshold, to four digits and never above it
        values = {"overcurrent_threshold": g.new,
                  "recovery_threshold": min(float(f"{g.new * rec / over:.4g}"), g.new) if over else g.new}
        if g.inrush is not None and g.inrush.get("new") is not None:
            values["inrush_time"] = g.inrush["new"]
        return values
    if g.type == "IsI2tSafe":
        cont = float(port_text(tree_text, g.node, "continuous_current") or "nan")
        values = {"continuous_current": float(f"{cont * g.new:.4g}")}
        peak = port_text(tree_text, g.node, "peak_current")
        if peak is not None:  # the rating's currents scale together: its I²t trips where the proposal was proven
            values["peak_current"] = float(peak) * values["continuous_current"] / cont
        return values
    return {g.port: g.new}


def _first_trip(summary: dict[str, Any], guard: str | None = None) -> float | None:
    times = [t["t"] for t in summary["trips"] if guard is None or t["node"] == guard]
    first = summary.get("first_t")
    return min(times) - (first if isinstance(first, (int, float)) else 0.0) if times else None


def _prove(logs: list[Path], is_fault: list[bool], wanted: list[dict[str, Any] | None],
           before: list[dict[str, Any]], after: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per log: what the proving replay showed, and whether that is what the log asks."""
    out = []
    for log, fault, want, old, new in zip(logs, is_fault, wanted, before, after, strict=True):
        count = new["trip_count"]
        if not fault:
            why = "" if count == 0 else "a healthy log trips: " + ", ".join(
                sorted({f"{t['node']} ({t['reason']})" for t in new["trips"]}))
        elif want is not None and "trips" in want:
            misses = []
            for guard, by in want["trips"]:
                at = _first_trip(new, guard)
                if at is None or (by is not None and at > by + 1e-9):
                    misses.append(f"{guard} " + ("does not trip" if at is None else f"trips at {at:.3f} s > {by} s"))
            why = "; ".join(misses)
        else:
            why = "" if count > 0 else "the fault trips no guard"
        out.append({"log": str(log), "fault": fault, "trips_before": old["trip_count"], "trips_after": count,
                    "first_trip_before": _first_trip(old), "first_trip_after": _first_trip(new), "ok": not why,
                    "why": why})
    return out


def _fmt(x: Any) -> str:
    return "-" if x is None else f"{x:.4g}" if isinstance(x, float) else str(x)


def _why(row: dict[str, Any]) -> str:
    return f" ({row['why']})" if row["why"] else ""


def render(report: dict[str, Any]) -> str:
    """The report as text: a line per guard and source, then the proving replay per log."""
    lines = [f"canguard tune: {report['config']} (margin {report['margin_pct']:g} %)", "guards:"]
    for g in report["guards"]:
        old = "rating x 1" if g["rating_scale"] else f"{g['port']} {_fmt(g['old'])}"
        what = f"{old} -> {_fmt(g['new'])}"
        lines.append(f"  {g['node']} ({g['type']} on {g['source']}): "
                     f"{what if g['status'] == 'tuned' else g['status']}{_why(g)}")
        ceil, peak = g["healthy_ceiling"], g["healthy_peak"]
        if peak is not None:
            lines.append(f"      healthy: peak {_fmt(peak['value'])} ({peak['log']} t={_fmt(peak['t'])}), "
                         f"p99 {_fmt(g['healthy_p99'])}, p99.9 {_fmt(g['healthy_p99_9'])}"
                         + (f", no trip from {_fmt(ceil['value'])} ({ceil['log']})" if ceil is not None else ""))
        if g["inrush"]:
            i = g["inrush"]
            window = f"inrush_time {_fmt(i['old'])} -> {_fmt(i['new'])} s" if i["new"] is not None else "inrush window"
            lines.append(f"      {window}: {i['starts']} healthy starts, highest |I| in a window {_fmt(i['peak'])}"
                         f" ({i['why']})")
        lines += [f"      fault {f['log']}: trips below {_fmt(f['value'])} (t={_fmt(f['t'])})" for f in g["faults"]]
        lines += [f"      heat {h['log']}: {_fmt(h['value'])} % of the trip level" for h in g["heat_pct"]]
    lines += ["max_age:"] if report["max_age"] else []
    for a in report["max_age"]:
        gap = a["healthy_gap"]
        state = f"max_age {_fmt(a['old'])} -> {_fmt(a['new'])} s" if a["status"] == "tuned" else a["status"]
        gap_text = f"; longest healthy gap {_fmt(gap['value'])} s ({gap['log']}), period {_fmt(a['period'])} s"
        lines.append(f"  {a['source']}: {state}{_why(a)}{gap_text if gap else ''}")
    lines += ["proving replay with the tuned config:"] if report.get("proof") else []
    for p in report.get("proof", []):
        lines.append(f"  {'ok  ' if p['ok'] else 'FAIL'} {'fault  ' if p['fault'] else 'healthy'} {p['log']}: trips "
                     f"{p['trips_before']} -> {p['trips_after']}, first trip {_fmt(p['first_trip_before'])} -> "
                     f"{_fmt(p['first_trip_after'])} s{_why(p)}")
    written = f"; written: {', '.join(report['written'])}" if report.get("written") else ""
    return "\n".join([*lines, f"result: {report['result']}{written}"])
