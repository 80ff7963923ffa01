"""``canguard demo``: the simulated robot and the daemon, one command, no hardware.

Both on one private ``virtual`` channel (the robot in a thread); a live view on a terminal, else one line per event.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, TextIO

from canguard.cli.common import TappedSink, add_monitor_options, subcommand
from canguard.config.schema import BusConfig, Config
from canguard.data import data_path
from canguard.errors import ConfigError
from canguard.units import quantity

DEMO_CONFIG = data_path("config", "examples", "robot_guard.yaml")
"""The bundled config the demo runs: the whole robot of dbc/robot.dbc guarded by trees/robot_guard.xml."""

DEMO_SCENARIOS = ("normal", "spike@4", "overload@9", "dropout@18", "garbage@24", "errorburst@27", "inrush@30")
"""What the demo's robot does, in seconds from start (see ``canguard simulate -h``)."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``canguard demo``."""
    p = subcommand(sub, "demo", cmd_demo,
                   description="Run the simulated robot and the daemon together on a private virtual bus with the "
                               "bundled config; walk through the scenarios; print what tripped, when, and how fast "
                               "the stop went out.")
    p.add_argument("-c", "--config", type=Path, default=None,
                   help="YAML config (default: the bundled config/examples/robot_guard.yaml: the whole robot guarded)")
    p.add_argument("--duration", type=float, default=36.0, metavar="S", help="seconds to run (default 36)")
    p.add_argument("--events", type=Path, default=None, metavar="FILE",
                   help="keep the events here (default: a temporary file, removed at the end)")
    p.add_argument("--seed", type=int, default=0, help="the simulated robot's random seed")
    add_monitor_options(p)


def demo_config(cfg: Config, events: Path) -> Config:
    """The config on one private virtual channel, events to ``events``, no I²t state file."""
    channel = f"canguard-demo-{os.getpid()}"
    buses = {name: BusConfig(name, {"interface": "virtual", "channel": channel}) for name in cfg.buses}
    state = dataclasses.replace(cfg.state, file=None)
    return dataclasses.replace(cfg, buses=buses, events=events, state=state)


class LiveView:
    """Per source: value, threshold, I²t level, state; trips; frames/s. Redrawn on a terminal."""

    def __init__(self, daemon: Any, out: TextIO, tty: bool) -> None:
        self.daemon = daemon
        self.out = out
        self.tty = tty
        self.t0 = time.monotonic()
        self._frames = 0
        self._last = self.t0

    def event(self, ev: dict[str, Any]) -> None:
        """One line per event, when not drawing."""
        if self.tty:
            return
        unit = trip_unit(self.daemon.engine, ev)
        fields = " ".join(f"{k}={_fmt(ev[k], unit if k in ('value', 'threshold') else None)}"
                          for k in ("node", "source", "value", "threshold", "reason") if ev.get(k) not in (None, ""))
        print(f"[{time.monotonic() - self.t0:6.2f} s] {ev.get('event')}: {fields}", file=self.out, flush=True)

    def draw(self) -> None:
        """Redraw the view, on a terminal."""
        if not self.tty:
            return
        engine = self.daemon.engine
        now = engine.clock.now()
        mono = time.monotonic()
        fps = (engine.stats.frames - self._frames) / max(1e-3, mono - self._last)
        self._frames, self._last = engine.stats.frames, mono
        lines = [f"canguard demo  t={mono - self.t0:5.1f} s  task: {engine.gate.state:8s}  "
                 f"trips: {engine.stats.trip_count}  stops: {engine.gate.stops}  {fps:7.0f} frames/s", "",
                 f"{'guard':28s} {'source':20s} {'value':>10s} {'threshold':>12s} {'level':>8s}  state"]
        for g in engine.guards():
            health = engine.ctx.health[g.source]
            snap = g.snapshot()
            state = health.reason(now, g.role) or ("TRIPPED" if snap.tripped else "ok")
            where = g.source if g.role == "current" else f"{g.source}:{g.role}"
            lines.append(f"{g.node[:28]:28s} {where[:20]:20s} {_fmt(health.value(g.role), g.unit):>10s} "
                         f"{_fmt(g.threshold() if math.isfinite(g.threshold()) else math.nan, g.threshold_unit):>12s} "
                         f"{_fmt(snap.level_pct, '%'):>8s}  {state}")
        lines.append("")
        for ev in engine.stats.trips[-5:]:
            unit = trip_unit(engine, ev)
            lines.append(f"  trip {ev.get('node')} {ev.get('source')} value={_fmt(ev.get('value'), unit)} "
                         f"threshold={_fmt(ev.get('threshold'), unit)} ({ev.get('reason')})")
        self.out.write("\x1b[H\x1b[2J" + "\n".join(lines) + "\n")
        self.out.flush()


def cmd_demo(args: argparse.Namespace) -> int:
    """Run the demo; exit 0 when it ran to its end."""
    import can

    from canguard.config.loader import load_config
    from canguard.io.outputs import check_output
    from canguard.service.daemon import Daemon
    from canguard.sim import run_on_bus

    if args.duration <= 0:
        raise ConfigError(f"--duration {args.duration}: expected seconds > 0")
    check_output(args.events, "--events", beside=True, makes_dirs=True)
    cfg_path = args.config if args.config is not None else DEMO_CONFIG
    tmp = tempfile.TemporaryDirectory(prefix="canguard-demo-")
    events = args.events if args.events is not None else Path(tmp.name) / "events.jsonl"
    cfg = demo_config(load_config(cfg_path), events)
    daemon = Daemon(cfg_path, cfg=cfg, http=args.http, groot2=args.groot2)
    stop_walls: list[float] = []  # the wall time the first stop frame of each stop went out
    in_stop = False

    def stopwatch(_frames: Any, origin: str) -> None:
        nonlocal in_stop
        if origin == "stop" and not in_stop:
            stop_walls.append(time.time())
        in_stop = origin == "stop" or (in_stop and origin != "task")

    daemon.sink = TappedSink(daemon.sink, stopwatch)
    daemon.engine = daemon.build_engine(cfg)
    out = sys.stdout
    view = LiveView(daemon, out, tty=out.isatty())
    daemon.engine.listen(view.event)
    robot_bus = can.Bus(**dict(next(iter(cfg.buses.values())).kwargs))
    stop = threading.Event()
    scenarios = tuple(s for s in DEMO_SCENARIOS if float(s.partition("@")[2] or 0) < args.duration)
    robot = threading.Thread(target=run_on_bus, name="canguard-demo-robot", daemon=True,
                             kwargs={"bus": robot_bus, "duration_s": args.duration + 1.0, "stop_event": stop,
                                     "db": cfg.database, "scenarios": scenarios, "seed": args.seed,
                                     "start_t": time.time()})
    print(f"canguard demo: {cfg_path.name}, tree {cfg.tree.main if cfg.tree else '-'}, scenarios "
          f"{', '.join(scenarios)}; {args.duration:g} s", file=out, flush=True)

    def drawer() -> None:
        while not stop.wait(0.25):
            view.draw()

    draw_thread = threading.Thread(target=drawer, name="canguard-demo-view", daemon=True)
    robot.start()
    draw_thread.start()
    try:
        code = daemon.run(duration_s=args.duration)
    finally:
        stop.set()
        robot.join(5)
        draw_thread.join(2)
        robot_bus.shutdown()
    print(summary_text(daemon.engine, stop_walls, events if args.events else None), file=out)
    tmp.cleanup()
    return code


def _fmt(value: Any, unit: str | None = None) -> str:
    """Numbers to 4 significant digits, with their unit, for the terminal; the journal keeps full precision."""
    return quantity(value, unit, 4) if isinstance(value, float) else str(value)


def trip_unit(engine: Any, ev: dict[str, Any]) -> str:
    """The unit of a trip event's value and threshold: its guard's threshold unit (A, Nm, A²s, θ)."""
    for g in engine.guards():
        if (g.node, g.role) == (ev.get("node"), ev.get("signal")):
            return str(g.threshold_unit)
    return ""


def summary_text(engine: Any, stop_walls: list[float], events: Path | None) -> str:
    """What tripped (the engine's trips), when, and how fast the stop went out."""
    first = engine.first_frame_t
    lines = ["", "canguard demo summary",
             f"  frames {engine.stats.frames}, decoded {engine.decoder.decoded}, invalid {engine.decoder.invalid}, "
             f"error frames {engine.decoder.error_frames}; ticks {engine.stats.ticks}",
             f"  trips: {engine.stats.trip_count}; stops: {engine.gate.stops}; stopped "
             f"{engine.gate.stopped_total(engine.clock.now()):.2f} s; escalations "
             f"{engine.events_seen['escalate']}, confirmations {engine.events_seen['confirmed']}"]
    for ev in engine.stats.trips:
        t = float(ev.get("t", math.nan))  # the triggering frame's bus time: wall time, as the stop's send
        after = next((s for s in stop_walls if s >= t - 0.001), None)  # the stop leaves before the trip is recorded
        latency = "no new stop (already stopped)" if after is None else \
            f"stop frames out {1000 * (after - t):.2f} ms after the trip's time"
        unit = trip_unit(engine, ev)
        lines.append(f"  t={t - first:7.3f} s  {ev.get('node')}  {ev.get('source')}  "
                     f"value={_fmt(ev.get('value'), unit)}  threshold={_fmt(ev.get('threshold'), unit)}  "
                     f"({ev.get('reason')}): {latency}")
    if events is not None:
        lines.append(f"  events: {events}")
    return "\n".join(lines)
