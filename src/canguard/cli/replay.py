"""``canguard replay``: the daemon's engine over recorded logs.

The same engine as ``canguard run`` on the log's clock, a :class:`~canguard.engine.gate.LogSink` in place of
the buses; the summary and the events depend only on the log and the config (byte-identical runs).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import uuid
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from py_trees.blackboard import Blackboard

from canguard.cli.common import (
    EXIT_BAD_INPUT,
    EXIT_OK,
    EXIT_REGRESSED,
    EXIT_TRIPPED,
    EXIT_UNGUARDED,
    config_path,
    per_log_path,
    subcommand,
)
from canguard.config.loader import load_config
from canguard.config.schema import Config
from canguard.engine.core import Engine
from canguard.engine.gate import LogSink
from canguard.engine.routing import ChannelRouter, parse_map
from canguard.errors import CanguardError, ConfigError, LogFormatError
from canguard.io.bagopts import STAMPS, BagOptions, emits_bag
from canguard.io.clock import ManualClock
from canguard.io.frame import Frame
from canguard.io.logtypes import COMPRESSIONS
from canguard.report.summary import build_summary, diff_baseline, render_text

__all__ = ["ReplayOptions", "replay_one"]


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
    export: Path | None = None  # --export-signals: this log's part file, its rows' log column export_log
    export_log: str = ""
    bag: BagOptions = field(default_factory=BagOptions)
    tune: bool = False  # canguard tune's statistics pass (a "tune" entry in the summary), tune_i2t: --tune-i2t
    tune_i2t: bool = False


def replay_one(cfg: Config, log_path: Path, opts: ReplayOptions) -> dict[str, Any]:
    """Replay one log through a fresh engine; returns the summary (JSON-able, deterministic)."""
    from canguard.io.logs import ReadStats, read_log
    from canguard.protect.state import HeatStore

    # py_trees keeps the blackboard in class-level storage: a log's summary must not depend on its neighbours.
    Blackboard.clear()
    clock = ManualClock()
    with ExitStack() as stack:
        journal = None
        if opts.events is not None:
            from canguard.engine.events import EventJournal

            journal = EventJournal(opts.events)
            stack.callback(journal.close)  # the last to close: after the exports below (LIFO)
        heat = HeatStore(opts.state, cfg.state.on_corrupt) if opts.state is not None else None
        stats = ReadStats()
        router = ChannelRouter(cfg, opts.channel_map)
        frames = read_log(log_path, skip_bad=opts.skip_bad, stats=stats, bag=opts.bag)
        if opts.progress:
            from canguard.io.progress import wrap_progress

            frames = wrap_progress(frames, log_path)  # attaches to the reader: before any wrapping
        # --emit streams each frame to the file as it is sent: memory stays flat in the log's length.
        text_out = opts.emit is not None and not emits_bag(opts.emit)
        out = stack.enter_context(open(opts.emit, "w", encoding="ascii")) if text_out and opts.emit else None
        sink = LogSink(clock.now, cfg.buses, out=out, keep=False)  # kept when an export takes them (_outputs)
        engine = Engine(cfg, clock, sink, events=journal, durable=False, heat=heat, save_heat=False)
        recorder = None
        if opts.plot is not None:
            from canguard.report.plot import Recorder

            recorder = Recorder(engine)
        _outputs(stack, engine, sink, opts, opts.export_log or str(log_path), recorder)
        tuning = None
        if opts.tune:
            from canguard.report.tune import tune_stats

            tuning = tune_stats(engine, tune_i2t=opts.tune_i2t)
        engine.run_log(frames.chunks(), router.table, router.only, router.unmapped,
                       router.channels if router.only is not None else None)
        if engine.stats.frames:
            engine.advance(clock.now())
            engine.finish(reason="end of log", stop=False)
    summary = build_summary(cfg, log_path, engine, stats, router)
    if tuning is not None:
        summary["tune"] = tuning()
    if recorder is not None and opts.plot is not None:
        recorder.save(opts.plot, summary)
    return summary


def _outputs(stack: ExitStack, engine: Engine, sink: LogSink, opts: ReplayOptions, log: str, recorder: Any) -> None:
    """What watches each tick (``--plot``'s recorder, an MCAP export) and the exports a replay writes as it goes
    (``--export-signals``, ``--emit`` as a bag), each closed at the end."""
    watch = _AfterTicks(sink)
    if recorder is not None:
        watch.watchers.append(recorder.publish)
    if opts.export is not None:
        from canguard.report.export import McapExport, SignalExport, is_mcap

        if is_mcap(opts.export):
            mcap = McapExport(engine, opts.export, log)
            stack.callback(mcap.close)
            watch.watchers.append(mcap.publish)
            watch.takers.append(mcap.sent)
        else:
            stack.callback(SignalExport(engine, opts.export, log).close)
    if opts.emit is not None and emits_bag(opts.emit):
        from canguard.io.bagwrite import BagEmit

        emit = BagEmit(opts.emit)
        stack.callback(emit.close)
        watch.takers.append(emit.sent)
    sink.keep = bool(watch.takers)
    if watch.watchers or watch.takers:
        engine.observer = watch
        stack.callback(watch.hand_over)  # the frames sent after the last tick: before the files close (LIFO)


class _AfterTicks:
    """The engine's observer: after every tick that runs, each watcher sees it, then the frames sent go to their
    takers."""

    def __init__(self, sink: LogSink) -> None:
        self.sink = sink
        self.watchers: list[Callable[[Any, float], None]] = []
        self.takers: list[Callable[[list[Frame]], None]] = []

    def publish(self, engine: Any, now: float) -> None:
        """A tick ran."""
        for watcher in self.watchers:
            watcher(engine, now)
        self.hand_over()

    def hand_over(self) -> None:
        """The frames kept since the last call, to each taker."""
        sink = self.sink
        if sink.frames:
            for take in self.takers:
                take(sink.frames)
            sink.frames.clear()
            sink.origins.clear()


FORMAT_SUFFIX = {"candump": ".log", "asc": ".asc", "blf": ".blf", "trc": ".trc", "csv": ".csv", "mf4": ".mf4"}
"""``--format`` names and the file suffix each stands for (``.gz`` is recognised on top)."""
MAGICS = {b"\x1f\x8b": ".gz", b"\xfd7zXZ\x00": ".xz", b"\x28\xb5\x2f\xfd": ".zst"}
"""How a compressed log on stdin starts, and the suffix that tells the readers."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``canguard replay``."""
    p = subcommand(
        sub, "replay", cmd_replay,
        description="What would the daemon have done on this log? Runs the same engine with the log's clock.",
    )
    p.add_argument("logs", nargs="+", type=Path, metavar="LOG",
                   help="candump (-L, -l, plain, -ta), ASC, BLF, TRC, CSV, MF4, optionally .gz, .xz or .zst; a ROS bag "
                        "(rosbag2 directory, .db3, .mcap, ROS 1 .bag); "
                        "'-' reads stdin (with --format); a directory, a quoted glob or @LIST (a file of paths) "
                        "replays every log it names")
    p.add_argument("--topic", action="append", default=[], metavar="NAME",
                   help="ROS bags: read this topic (repeatable; default: every topic of a CAN frame type); each "
                        "topic is a channel named after it")
    p.add_argument("--stamp", choices=STAMPS, default="header",
                   help="ROS bags: a frame's time is its header.stamp (the record time where that is zero; "
                        "default) or the time the bag recorded it")
    p.add_argument("--format", choices=sorted(FORMAT_SUFFIX), default=None,
                   help="the logs' format, instead of telling it by the file suffix (needed for '-')")
    p.add_argument("-c", "--config", type=Path, default=None, help="YAML config (default: as for `canguard run`)")
    p.add_argument("--map", action="append", default=[], metavar="CHANNEL=BUS",
                   help="route a log channel to a configured bus (repeatable)")
    p.add_argument("--events", type=Path, metavar="FILE", help="write the daemon's events (JSON lines)")
    p.add_argument("--emit", type=Path, metavar="FILE",
                   help="write the frames canguard would send: candump -L, or as can_msgs/msg/Frame on /to_can_bus "
                        "for FILE.mcap or a rosbag2 directory (a path without a suffix)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--fail-on-trip", action="store_true",
                   help="exit 1 when any guard tripped, 3 when a configured source got no sample "
                        "(a CI gate that never passes on a log it did not look at)")
    p.add_argument("--baseline", type=Path, metavar="FILE", help="compare with a saved --json summary")
    p.add_argument("--fail-on-regression", action="store_true",
                   help="with --baseline: exit 1 when a log gains or loses a trip, or a margin shrinks by more "
                        "than --margin-tolerance")
    p.add_argument("--margin-tolerance", type=float, default=0.0, metavar="PCT",
                   help="with --fail-on-regression: how far a margin may shrink, in %% of its guard's threshold "
                        "(default 0: not at all)")
    p.add_argument("--skip-bad", action="store_true", help="count and skip malformed lines instead of stopping")
    p.add_argument("--state", type=Path, metavar="FILE",
                   help="start from the heat in this I²t state file, cooled for the time since it was saved "
                        "(default: cold); the file is only read")
    p.add_argument("--plot", type=Path, metavar="FILE",
                   help="plot currents, thresholds, I²t and stops (.png/.svg/.html)")
    p.add_argument("--export-signals", type=Path, metavar="FILE.parquet", default=None,
                   help="write every decoded sample (log, t, bus, source, signal, value, reason) to a Parquet "
                        "file, one for all logs (extra 'fleet'; slower than a plain replay); FILE.mcap: an MCAP file "
                        "per log for Foxglove: samples, guard levels and thresholds, events, frames sent")
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="replay several logs in N processes")
    p.add_argument("--dask", metavar="SCHEDULER", default=None,
                   help="replay the logs on a Dask distributed cluster (tcp://host:8786; extra 'fleet')")
    p.add_argument("--fleet-summary", type=Path, metavar="FILE", default=None,
                   help="one row per log (status, frames, trips, stops, worst margin): JSON lines, or Parquet "
                        "for FILE.parquet")
    p.add_argument("--realtime", nargs="?", type=float, const=1.0, default=None, metavar="SPEED",
                   help="send the log onto a configured bus at its pace (x SPEED) with the engine live on it")
    p.add_argument("--bus", default=None, help="with --realtime: the bus to play onto (default: the only bus)")


@dataclass(frozen=True)
class ConfigRef:
    """The config of one ``canguard replay`` run as a --jobs / --dask worker gets it; ``run`` tells one run from
    the next on a long-lived Dask worker, so a config edited between two runs is read again."""

    path: Path
    run: str


_CONFIGS: dict[ConfigRef, Config] = {}
"""This process's config of the current run (at most one): see :func:`_config_of`."""


def _config_of(ref: ConfigRef) -> Config:
    """The Config ``ref`` names: loaded once per process and run (inherited from the parent by a forked pool)."""
    cfg = _CONFIGS.get(ref)
    if cfg is None:
        cfg = load_config(ref.path)
        _CONFIGS.clear()  # a long-lived Dask worker keeps one run's config, not every run's
        _CONFIGS[ref] = cfg
    return cfg


def _job(args: tuple[ConfigRef, Path, ReplayOptions]) -> tuple[dict[str, Any] | None, str]:
    """Replay one log (freed memory kept until it ends) with the config its reference names."""
    from canguard.cli.heap import keep_freed_memory

    ref, log, opts = args
    try:
        with keep_freed_memory():
            return replay_one(_config_of(ref), log, opts), ""
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


def _as_format(log: Path, fmt: str | None, tmp: Path) -> Path:
    """The path to read ``log`` from: ``-`` spooled from stdin; with ``--format``, a link in ``tmp`` with that
    format's suffix (the readers choose by suffix)."""
    if str(log) == "-":
        if fmt is None:
            raise ConfigError("replay -: reading a log from stdin needs --format "
                              f"({', '.join(FORMAT_SUFFIX)}): a pipe has no file name to tell it by")
        head = sys.stdin.buffer.read(6)
        gz = next((suffix for magic, suffix in MAGICS.items() if head.startswith(magic)), "")
        spooled = tmp / f"stdin{FORMAT_SUFFIX[fmt]}{gz}"
        with open(spooled, "wb") as out:
            out.write(head)
            shutil.copyfileobj(sys.stdin.buffer, out)
        return spooled
    if fmt is None or not log.exists():
        return log  # a missing file: the reader names it as the user wrote it
    gz = log.suffix.lower() if log.suffix.lower() in COMPRESSIONS else ""
    link = tmp / f"{len(list(tmp.iterdir()))}-{log.stem}{FORMAT_SUFFIX[fmt]}{gz}"
    link.symlink_to(log.resolve())
    return link


def _as_named(text: str, read: list[Path], names: list[Path]) -> str:
    """``text`` speaking of each log by the name the user gave (``-`` for stdin), not the spool file or link read."""
    for path, name in zip(read, names, strict=True):
        text = text.replace(str(path), str(name))
    return text


def _check_args(args: argparse.Namespace) -> None:
    """Every option and file of the replay tried before the first log is read (ConfigError: one line, exit 2)."""
    from canguard.io.outputs import check_output
    from canguard.protect.state import readable_problem

    why = readable_problem(args.state) if args.state is not None else ""
    if why:  # --state is only read
        raise ConfigError(f"--state {args.state}: cannot be read ({why}): expected an I²t state file saved by "
                          "`canguard run` (its state.file); leave --state out to start cold")
    many = len(args.logs) > 1
    for log in args.logs:
        check_output(per_log_path(args.events, log, many), "--events", beside=True, makes_dirs=True)
        check_output(per_log_path(args.emit, log, many), "--emit")
        check_output(per_log_path(args.plot, log, many), "--plot")
    check_output(args.fleet_summary, "--fleet-summary")
    if args.export_signals is not None and args.realtime is None:
        from canguard.report.export import check_export

        check_export(args.export_signals, dask=args.dask is not None)
    if args.dask is not None and args.realtime is not None:
        raise ConfigError("replay: --dask and --realtime do not go together (a realtime replay plays one log live)")
    if args.logs.count(Path("-")) > 1:
        raise ConfigError("replay: '-' (stdin) can be given once")
    if args.fail_on_regression and args.baseline is None:
        raise ConfigError("replay: --fail-on-regression needs --baseline FILE (a saved `canguard replay --json`)")
    tol = args.margin_tolerance
    if not (math.isfinite(tol) and tol >= 0):
        raise ConfigError(f"--margin-tolerance {tol}: expected a percentage of the threshold >= 0")


def _report_baseline(args: argparse.Namespace, base: Any, summaries: list[dict[str, Any]]) -> bool:
    """Print on stderr what changed per log against ``base`` (paired in order; a count that differs is itself a
    regression); True when anything is a regression."""
    base_list = base if isinstance(base, list) else [base]
    regressed = len(base_list) != len(summaries)
    if regressed:
        print(f"baseline {args.baseline}: {len(base_list)} summaries, this run {len(summaries)}: "
              "logs are paired in order; the unpaired are not compared", file=sys.stderr)
    for old, new in zip(base_list, summaries, strict=False):
        changes = diff_baseline(old, new, args.margin_tolerance)
        print(f"baseline {args.baseline} vs {new['log']}: " + ("no change" if not changes else ""),
              file=sys.stderr)
        for c in changes:
            print(f"  {c.text}" + (" (regression)" if c.regression and args.fail_on_regression else ""),
                  file=sys.stderr)
        regressed = regressed or any(c.regression for c in changes)
    return regressed


def cmd_replay(args: argparse.Namespace) -> int:
    """Replay every log; print summaries in input order; exit 0, 1 (a trip, or a regression), 3 (unguarded) or 2."""
    import tempfile

    cfg_path = config_path(args)
    cfg = load_config(cfg_path)
    from canguard.cli.fleet import expand_logs

    args.logs = expand_logs(args.logs)
    _check_args(args)
    with tempfile.TemporaryDirectory(prefix="canguard-replay-") as tmp:
        names = list(args.logs)
        args.logs = [_as_format(log, args.format, Path(tmp)) for log in names]
        if args.realtime is not None:
            from canguard.cli.realtime import replay_realtime

            try:
                live: list[tuple[dict[str, Any] | None, str]] = [*replay_realtime(cfg, args, names)]
            except LogFormatError as exc:  # named as the user named the log (`-`), not as the spool file
                raise LogFormatError(_as_named(str(exc), args.logs, names)) from None
            code = _report(args, live, names, None, len(names) > 1)
            if code == EXIT_OK:
                print("note: --realtime runs the live daemon; its times follow the wall clock, not the log",
                      file=sys.stderr)
            return code
        return _replay_offline(cfg, cfg_path, args, names)


def run_jobs(args: argparse.Namespace, cfg: Config, cfg_path: Path,
             logs: list[tuple[Path, ReplayOptions]]) -> list[tuple[dict[str, Any] | None, str]]:
    """Every log's (summary, error), in input order: on Dask, in ``--jobs`` processes (largest first) or here."""
    ref = ConfigRef(cfg_path, uuid.uuid4().hex)
    _CONFIGS.clear()
    _CONFIGS[ref] = cfg  # here and in forked workers: neither reads the config again
    try:
        if not ((args.jobs > 1 and len(logs) > 1) or args.dask is not None):
            return [_job((ref, log, opts)) for log, opts in logs]
        order = sorted(range(len(logs)), key=lambda i: -_size(logs[i][0]))
        todo = [(ref, *logs[i]) for i in order]
        if args.dask is not None:
            from canguard.cli.fleet import run_dask

            done = run_dask(args.dask, _job, todo)
        else:
            from canguard.cli.fleet import run_processes

            done = run_processes(args.jobs, _job, todo, warm=_WORKER_MODULES)
    finally:
        _CONFIGS.clear()
    placed = dict(zip(order, done, strict=True))
    return [placed[i] for i in range(len(logs))]


def _size(log: Path) -> int:
    """Bytes of ``log`` (0 when it cannot be read: its worker names the problem)."""
    try:
        return log.stat().st_size
    except OSError:
        return 0


_WORKER_MODULES = ("canguard.engine.events", "canguard.io.logs", "canguard.protect.state", "canguard.bt.checks")
"""What :func:`replay_one` imports on a first log: imported once before a forked pool, not in every worker."""


def _report(args: argparse.Namespace, results: list[tuple[dict[str, Any] | None, str]], names: list[Path], base: Any,
            many: bool) -> int:
    """Print each log's summary (or error), the baseline's changes; the exit code."""
    summaries = []
    errors = 0
    for (summary, err), name, log in zip(results, names, args.logs, strict=True):
        if summary is None:
            print(f"canguard replay: error:\n{_as_named(err, [log], [name])}", file=sys.stderr)
            errors += 1
            continue
        if args.format is not None or str(name) == "-":
            summary["log"] = str(name)  # the name the user gave, not the spool file or link
        summaries.append(summary)
        for source in summary["unguarded_sources"]:
            print(f"canguard replay: warning: {name}: source {source!r} got no sample (no frame of its message "
                  "on a channel a bus takes): its guards judged nothing on this log", file=sys.stderr)
        if not args.json:
            print(render_text(summary))
    if args.json:
        out: Any = summaries[0] if len(summaries) == 1 and not many else summaries
        print(json.dumps(out, indent=2, sort_keys=True))
    regressed = base is not None and summaries and _report_baseline(args, base, summaries)
    if errors:
        return EXIT_BAD_INPUT
    if args.fail_on_regression and regressed:
        return EXIT_REGRESSED
    if args.fail_on_trip and any(s["trips"] for s in summaries):
        return EXIT_TRIPPED
    if args.fail_on_trip and any(s["unguarded_sources"] for s in summaries):
        return EXIT_UNGUARDED
    return EXIT_OK


def _replay_offline(cfg: Config, cfg_path: Path, args: argparse.Namespace, names: list[Path]) -> int:
    channel_map = parse_map(args.map, cfg)
    out = args.export_signals
    parts: list[Path] = []  # --export-signals FILE.parquet: a part file per log (else FILE.mcap: a file per log)
    if out is not None:
        from canguard.report import export

        parts = [] if export.is_mcap(out) else [out.with_name(f".{out.name}.part{i}") for i in range(len(args.logs))]
    many = len(args.logs) > 1
    base = _load_baseline(args.baseline) if args.baseline else None
    jobs: list[tuple[Path, ReplayOptions]] = []
    for log, name in zip(args.logs, names, strict=True):
        opts = ReplayOptions(
            channel_map=channel_map, events=per_log_path(args.events, name, many),
            emit=per_log_path(args.emit, name, many), skip_bad=args.skip_bad, state=args.state,
            plot=per_log_path(args.plot, name, many),
            progress=sys.stderr.isatty() and args.jobs <= 1 and args.dask is None,
            export=parts[len(jobs)] if parts else per_log_path(out, name, many),
            export_log=str(name), bag=BagOptions(tuple(args.topic), args.stamp),
        )
        jobs.append((log, opts))
    try:
        results = run_jobs(args, cfg, cfg_path, jobs)
    except BaseException:
        if parts:
            export.discard_parts(parts)
        raise
    if parts:  # in input order; a log that failed contributes no rows (its part may be cut short)
        export.combine_parts(out, parts, [summary is not None for summary, _ in results])
    if args.fleet_summary is not None:
        from canguard.report.export import fleet_row, write_fleet_summary

        write_fleet_summary(args.fleet_summary, [fleet_row(str(name), summary, err)
                                                 for (summary, err), name in zip(results, names, strict=True)])
    return _report(args, results, names, base, many)
