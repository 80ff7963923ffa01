"""``canguard replay``: the daemon's engine over recorded logs.

The same :class:`~canguard.engine.core.Engine` as ``canguard run``, with a
:class:`~canguard.engine.clock.ManualClock` driven by the log's timestamps and a
:class:`~canguard.engine.gate.LogSink` in place of the buses: the answer to "what
would the daemon have done on this log?". The summary and the events depend
only on the log and the config, so two runs give byte-identical output.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterator, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from py_trees.blackboard import Blackboard

from canguard.config.loader import Config, load_config
from canguard.engine.clock import ManualClock
from canguard.engine.core import Engine
from canguard.engine.gate import LogSink
from canguard.errors import CanguardError, ConfigError
from canguard.io.frame import Frame

SUMMARY_VERSION = 1


@dataclass
class ReplayOptions:
    """What one replay of one log does besides the summary."""

    channel_map: dict[str, str] = field(default_factory=dict)
    events: Path | None = None
    emit: Path | None = None
    skip_bad: bool = False
    state: Path | None = None
    plot: Path | None = None
    progress: bool = False


def parse_map(items: Sequence[str], cfg: Config) -> dict[str, str]:
    """``--map can0=main`` items -> {channel: bus}; errors name the item and the configured buses."""
    out: dict[str, str] = {}
    for item in items:
        chan, sep, bus = item.partition("=")
        if not sep or not chan or not bus:
            raise ConfigError(f"--map {item!r}: expected CHANNEL=BUS, e.g. can0=main")
        if bus not in cfg.buses:
            raise ConfigError(f"--map {item!r}: unknown bus {bus!r}; configured buses: {', '.join(cfg.buses)}")
        out[chan] = bus
    return out


class ChannelRouter:
    """Maps a log's channel names to the config's buses: --map, then bus names and channels, then the only bus.

    The only-bus fallback (one configured bus, no --map) lets a single-channel log on
    any channel name replay without a map; when it makes that bus take the frames of
    several channels, :meth:`merged` reports them (a log of can0 and can1 is not one bus).
    With --map the routing is explicit: a channel neither --map nor a bus names is unmapped.
    """

    def __init__(self, cfg: Config, overrides: dict[str, str]) -> None:
        self.table: dict[str, str] = {b.channel: name for name, b in cfg.buses.items() if b.channel}
        self.table.update({name: name for name in cfg.buses})
        self.table.update(overrides)
        self.only = next(iter(cfg.buses)) if len(cfg.buses) == 1 and not overrides else None
        self.unmapped: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        """Frames per channel while the only-bus fallback is on (counted by the engine's run_log)."""

    def merged(self) -> dict[str, int]:
        """Frames per channel when the fallback merged several channels into the only bus, else {}."""
        if len(self.channels) < 2 or all(c in self.table for c in self.channels):
            return {}
        return dict(sorted(self.channels.items()))


def replay_one(cfg: Config, log_path: Path, opts: ReplayOptions) -> dict[str, Any]:
    """Replay one log through a fresh engine; returns the summary (JSON-able, deterministic)."""
    from canguard.engine.events import EventJournal
    from canguard.io.logs import ReadStats, read_log
    from canguard.protect.state import HeatStore

    # Every log starts from a clean state: py_trees keeps the blackboard in class-level
    # storage, so keys a previous log's tree wrote (a cooldown's last run, a recorded
    # time) would otherwise be read by this one (issue 12: a log's summary never
    # depends on its neighbours or on --jobs).
    Blackboard.storage.clear()
    Blackboard.metadata.clear()
    Blackboard.clients.clear()
    clock = ManualClock()
    journal = EventJournal(opts.events) if opts.events is not None else None
    heat = HeatStore(opts.state, cfg.state.on_corrupt) if opts.state is not None else None
    stats = ReadStats()
    router = ChannelRouter(cfg, opts.channel_map)
    frames: Iterator[Frame] = read_log(log_path, skip_bad=opts.skip_bad, stats=stats)
    if opts.progress:
        from canguard.report.progress import wrap_progress

        frames = wrap_progress(frames, log_path)  # attaches to the reader: before any wrapping
    with ExitStack() as stack:
        # --emit streams each frame to the file as it is sent: memory stays flat in the log's length.
        out = stack.enter_context(open(opts.emit, "w", encoding="ascii")) if opts.emit is not None else None
        sink = LogSink(clock.now, cfg.buses, out=out, keep=False)
        engine = Engine(cfg, clock, sink, events=journal, durable=False, heat=heat, save_heat=False)
        recorder = None
        if opts.plot is not None:
            from canguard.report.plot import Recorder

            recorder = Recorder(engine)
        try:
            engine.run_log(frames, router.table, router.only, router.unmapped,
                           router.channels if router.only is not None else None)
            if engine.stats.frames:
                engine.advance(clock.now())
                engine.finish(reason="end of log", stop=False)
        finally:
            if journal is not None:
                journal.close()
    summary = build_summary(cfg, log_path, engine, stats, router)
    if recorder is not None and opts.plot is not None:
        recorder.save(opts.plot, summary)
    return summary


def _r(x: float, nd: int = 6) -> float | None:
    """Round for a stable summary; NaN/inf become None so the JSON stays valid."""
    return None if not math.isfinite(x) else round(x, nd)


def build_summary(cfg: Config, log_path: Path, engine: Engine, stats: Any, router: ChannelRouter) -> dict[str, Any]:
    """The summary of one replay: counters, trips, time stopped and the lowest margin to each threshold."""
    d = engine.decoder
    es = engine.stats
    end = engine.clock.now()
    trips = [
        {k: (_r(v) if isinstance(v, float) else v) for k, v in ev.items()
         if k in ("t", "node", "source", "value", "threshold", "reason")}
        for ev in es.trips
    ]
    margins = []
    for guard in engine.guards():
        peak = es.max_abs.get((guard.source, guard.role), math.nan) if guard.kind == "threshold" else \
            es.max_level_pct.get(guard.node, math.nan)
        threshold = guard.threshold() if guard.kind == "threshold" else 100.0
        margins.append({
            "node": guard.node, "source": guard.source, "signal": guard.role, "kind": guard.kind,
            "threshold": _r(threshold), "peak": _r(peak),
            "margin": _r(threshold - peak) if math.isfinite(peak) else None,
            "margin_pct": _r(100.0 * (threshold - peak) / threshold, 2)
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
            "backward_timestamps": stats.backward, "repeated_timestamps": stats.repeated,
        },
        "unmapped_channels": unmapped,
        "samples": dict(sorted(es.samples.items())),
        "ticks": es.ticks, "edge_ticks": es.edge_ticks, "tick_errors": es.tick_errors,
        "trips": trips,
        "trip_count": es.trip_count,
        "stops": engine.gate.stops,
        "stopped_s": _r(engine.gate.stopped_total(end), 4),
        "escalations": engine.events_seen["escalate"],
        "confirmations": engine.events_seen["confirmed"],
        "margins": margins,
        "first_t": _r(engine.first_frame_t), "last_t": _r(end),
        "frames_sent": getattr(engine.sink, "sent", 0),
    }
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
        lines.append(f"    t={t.get('t')} {t.get('node')} source={t.get('source')} value={t.get('value')}"
                     f" threshold={t.get('threshold')} reason={t.get('reason')}")
    lines.append(f"  stops: {s['stops']}, stopped {s['stopped_s']} s; frames canguard would send: "
                 f"{s['frames_sent']}; stop confirmations {s['confirmations']}, escalations {s['escalations']}")
    lines.append("  lowest margin to each threshold:")
    for m in s["margins"]:
        if m["margin"] is None:
            lines.append(f"    {m['node']} ({m['source']} {m['signal']}): no data")
        else:
            unit = "% of trip level" if m["kind"] == "i2t" else ""
            lines.append(f"    {m['node']} ({m['source']} {m['signal']}): peak {m['peak']} vs threshold "
                         f"{m['threshold']}{unit}: margin {m['margin']} ({m['margin_pct']} %)")
    if s["unmapped_channels"]:
        lines.append("  warning: frames on channels no bus takes (use --map CHANNEL=BUS): "
                     + ", ".join(f"{k} ({v})" for k, v in s["unmapped_channels"].items()))
    if s.get("merged_channels"):
        hint = ("--realtime plays every channel onto one bus: split the log by channel to choose"
                if "realtime_speed" in s else "use --map CHANNEL=BUS to choose what each bus takes")
        lines.append(f"  warning: frames of several channels were merged into bus {s.get('merged_into')} ({hint}): "
                     + ", ".join(f"{k} ({v})" for k, v in s["merged_channels"].items()))
    if f["read"] and not f["decoded"]:
        lines.append("  warning: no frame of this log matches a configured message")
    return "\n".join(lines)


def compare_baseline(base: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """What changed against a saved --json summary: new trips, lost trips, margins that shrank."""

    def key(t: dict[str, Any]) -> tuple[str, str, str]:
        return (str(t.get("node")), str(t.get("source")), str(t.get("reason")))

    out: list[str] = []
    old_trips = [key(t) for t in base.get("trips", [])]
    new_trips = [key(t) for t in new.get("trips", [])]
    for k in sorted(set(new_trips) | set(old_trips)):
        n_old, n_new = old_trips.count(k), new_trips.count(k)
        if n_new > n_old:
            out.append(f"new trip: {k[0]} on {k[1]} ({k[2]}): {n_old} -> {n_new}")
        elif n_new < n_old:
            out.append(f"lost trip: {k[0]} on {k[1]} ({k[2]}): {n_old} -> {n_new}")
    old_m = {(m["node"], m["signal"]): m for m in base.get("margins", [])}
    for m in new.get("margins", []):
        o = old_m.get((m["node"], m["signal"]))
        if o is None or o.get("margin") is None or m.get("margin") is None:
            continue
        if m["margin"] < o["margin"] - 1e-9:
            out.append(f"margin shrank: {m['node']} ({m['source']} {m['signal']}): {o['margin']} -> {m['margin']}")
    if base.get("stops") != new.get("stops"):
        out.append(f"stops: {base.get('stops')} -> {new.get('stops')}")
    return out


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``canguard replay``."""
    p = sub.add_parser(
        "replay", help="run the daemon's engine over recorded logs (candump, ASC, BLF, TRC, CSV, MF4, .gz)",
        description="What would the daemon have done on this log? Runs the same engine with the log's clock.",
    )
    p.add_argument("logs", nargs="+", type=Path, metavar="LOG")
    p.add_argument("-c", "--config", type=Path, default=None, help="YAML config (default: as for `canguard run`)")
    p.add_argument("--map", action="append", default=[], metavar="CHANNEL=BUS",
                   help="route a log channel to a configured bus (repeatable)")
    p.add_argument("--events", type=Path, metavar="FILE", help="write the daemon's events (JSON lines)")
    p.add_argument("--emit", type=Path, metavar="FILE", help="write the frames canguard would send (candump -L)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--fail-on-trip", action="store_true", help="exit 1 when any guard tripped (a CI gate)")
    p.add_argument("--baseline", type=Path, metavar="FILE", help="compare with a saved --json summary")
    p.add_argument("--skip-bad", action="store_true", help="count and skip malformed lines instead of stopping")
    p.add_argument("--state", type=Path, metavar="FILE",
                   help="start from the heat in this I²t state file, cooled for the time since it was saved "
                        "(default: cold); the file is only read")
    p.add_argument("--plot", type=Path, metavar="FILE",
                   help="plot currents, thresholds, I²t and stops (.png/.svg/.html)")
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="replay several logs in N processes")
    p.add_argument("--realtime", nargs="?", type=float, const=1.0, default=None, metavar="SPEED",
                   help="send the log onto a configured bus at its pace (x SPEED) with the engine live on it")
    p.add_argument("--bus", default=None, help="with --realtime: the bus to play onto (default: the only bus)")
    p.set_defaults(func=cmd_replay)


def _events_path(base: Path | None, log: Path, many: bool) -> Path | None:
    if base is None or not many:
        return base
    return base.with_name(f"{base.stem}.{log.name}{base.suffix}")


def _job(args: tuple[Config | Path, Path, ReplayOptions]) -> tuple[dict[str, Any] | None, str]:
    """Replay one log: with the config loaded by :func:`cmd_replay`, or (a --jobs worker) its path."""
    cfg, log, opts = args
    try:
        return replay_one(cfg if isinstance(cfg, Config) else load_config(cfg), log, opts), ""
    except CanguardError as exc:
        return None, str(exc)


def _load_baseline(path: Path) -> Any:
    """A saved --json summary (one object, or a list for several logs); a clear error otherwise."""
    try:
        base = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"--baseline {path}: not a saved `canguard replay --json` summary: {exc}") from None
    if not isinstance(base, (dict, list)):
        raise ConfigError(f"--baseline {path}: expected a saved `canguard replay --json` summary (an object)")
    return base


def cmd_replay(args: argparse.Namespace) -> int:
    """Replay every log; print summaries in input order; exit 0, 1 (--fail-on-trip and a trip) or 2."""
    from canguard.cli.main import default_config

    cfg_path = args.config if args.config is not None else default_config()
    cfg = load_config(cfg_path)
    if args.realtime is not None:
        from canguard.cli.realtime import replay_realtime

        return replay_realtime(cfg, args)
    channel_map = parse_map(args.map, cfg)
    many = len(args.logs) > 1
    base = _load_baseline(args.baseline) if args.baseline else None
    pool = args.jobs > 1 and many
    # In this process the config loaded above serves every log; --jobs workers load their own
    # copy from the path (a Config with its cantools database is not sent to each of them).
    job_cfg: Config | Path = cfg_path if pool else cfg
    jobs: list[tuple[Config | Path, Path, ReplayOptions]] = []
    for log in args.logs:
        opts = ReplayOptions(
            channel_map=channel_map, events=_events_path(args.events, log, many),
            emit=_events_path(args.emit, log, many), skip_bad=args.skip_bad, state=args.state,
            plot=_events_path(args.plot, log, many), progress=sys.stderr.isatty() and args.jobs <= 1,
        )
        jobs.append((job_cfg, log, opts))
    if pool:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=args.jobs) as executor:
            results = list(executor.map(_job, jobs))
    else:
        results = [_job(j) for j in jobs]
    summaries = []
    errors = 0
    for summary, err in results:
        if summary is None:
            print(f"canguard replay: error:\n{err}", file=sys.stderr)
            errors += 1
            continue
        summaries.append(summary)
        if not args.json:
            print(render_text(summary))
    if args.json:
        out: Any = summaries[0] if len(summaries) == 1 and not many else summaries
        print(json.dumps(out, indent=2, sort_keys=True))
    if base is not None and summaries:
        base_list = base if isinstance(base, list) else [base]
        for old, new in zip(base_list, summaries, strict=False):
            changes = compare_baseline(old, new)
            print(f"baseline {args.baseline} vs {new['log']}: " + ("no change" if not changes else ""),
                  file=sys.stderr)
            for c in changes:
                print(f"  {c}", file=sys.stderr)
    if errors:
        return 2
    if args.fail_on_trip and any(s["trips"] for s in summaries):
        return 1
    return 0
