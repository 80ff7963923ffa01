"""``canguard replay --realtime [SPEED]``: a bench test through the real daemon path.

The log is played onto a configured bus at its pace from a second connection while the daemon runs live on it.
"""

from __future__ import annotations

import argparse
import dataclasses
import threading
import time
from collections import Counter
from collections.abc import Iterable
from contextlib import ExitStack
from pathlib import Path
from typing import Any, TextIO

import can

from canguard.cli.common import TappedSink, per_log_path
from canguard.config.schema import Config
from canguard.engine.core import Engine
from canguard.engine.gate import LogSink
from canguard.errors import ConfigError
from canguard.io.frame import Frame
from canguard.service.daemon import Daemon

DRAIN_S = 10.0
"""Longest wait, after the last frame was played, for the daemon to have fed every frame."""


class _ReplayDaemon(Daemon):
    """The daemon with replay's promises: heat only read from ``--state``, ``--emit``, the bench's bus allowed."""

    refuse_virtual = False
    watch = False
    filters = False  # the summary counts every frame played, and the player waits until each was fed

    def __init__(self, cfg: Config, *, state: Path | None, emit: TextIO | None) -> None:
        self._state_path = state
        self._emit = emit
        super().__init__(cfg.path, cfg=cfg)

    def build_engine(self, cfg: Config, previous: Engine | None = None) -> Engine:
        from canguard.io.clock import BootClock
        from canguard.protect.state import HeatStore

        if self._emit is not None and not isinstance(self.sink, TappedSink):  # every frame handed to it: --emit
            self.sink = TappedSink(self.sink, LogSink(self.clock.now, cfg.buses, out=self._emit, keep=False).send)
        engine = super().build_engine(cfg, previous)
        engine.heat = (HeatStore(self._state_path, cfg.state.on_corrupt, clock=BootClock())
                       if self._state_path is not None else None)
        engine.save_heat = False
        return engine


def _refuse_unsupported(args: argparse.Namespace) -> None:
    """Exit 2 (ConfigError) on the replay flags --realtime cannot honour, rather than ignoring them."""
    refused = [flag for flag, given in (
        ("--plot", args.plot is not None), ("--export-signals", args.export_signals is not None),
        ("--baseline", args.baseline is not None), ("--jobs", args.jobs > 1),
        ("--map (--realtime plays every frame onto --bus)", bool(args.map))) if given]
    if refused:
        raise ConfigError(f"--realtime cannot be combined with {', '.join(refused)}: "
                          "run the offline replay (without --realtime) for that")


def _play_bus(cfg: Config, args: argparse.Namespace) -> str:
    """The configured bus the log is played onto (``--bus``, or the only one)."""
    bus_name = args.bus or (next(iter(cfg.buses)) if len(cfg.buses) == 1 else None)
    if bus_name is None:
        raise ConfigError(f"--realtime: several buses are configured ({', '.join(cfg.buses)}): "
                          "name the one to play onto with --bus")
    if bus_name not in cfg.buses:
        raise ConfigError(f"--bus {args.bus!r}: expected one of the configured buses: {', '.join(cfg.buses)}")
    return str(bus_name)


def replay_realtime(cfg: Config, args: argparse.Namespace, names: list[Path]) -> list[tuple[dict[str, Any], str]]:
    """Play each log onto the bus while the daemon runs; each log's (summary, ""). ``names``: as the user gave them."""
    from canguard.engine.routing import ChannelRouter
    from canguard.io.logs import ReadStats, read_log
    from canguard.report.summary import build_summary

    _refuse_unsupported(args)
    speed = float(args.realtime)
    if speed <= 0:
        raise ConfigError(f"--realtime {speed}: expected a speed > 0 (1 = the log's own pace)")
    bus_name = _play_bus(cfg, args)
    many = len(args.logs) > 1
    results = []
    for log_path, name in zip(args.logs, names, strict=True):
        run_cfg = dataclasses.replace(cfg, events=per_log_path(args.events, name, many),
                                      state=dataclasses.replace(cfg.state, file=None))
        emit_path = per_log_path(args.emit, name, many)
        stats = ReadStats()
        frames = read_log(log_path, skip_bad=args.skip_bad, stats=stats)  # a missing file fails here, first
        channels: Counter[str] = Counter()  # frames played per channel
        failed: list[Exception] = []
        with ExitStack() as stack:
            emit = stack.enter_context(open(emit_path, "w", encoding="ascii")) if emit_path is not None else None
            daemon = _ReplayDaemon(run_cfg, state=args.state, emit=emit)
            player = can.Bus(**dict(cfg.buses[bus_name].kwargs))
            done = threading.Event()
            threading.Thread(target=_play, args=(frames, speed, player, daemon, channels, failed, done),
                             name="canguard-player", daemon=True).start()
            try:
                daemon.run()
            finally:
                done.wait(5)
                player.shutdown()
        if failed:
            raise failed[0]
        router = ChannelRouter(daemon.cfg, {})
        summary = build_summary(daemon.cfg, name, daemon.engine, stats, router)
        if len(channels) > 1:  # every channel of the log went onto the one bus
            summary["merged_channels"] = dict(sorted(channels.items()))
            summary["merged_into"] = bus_name
        summary["realtime_speed"] = speed
        results.append((summary, ""))
    return results


def _play(frames: Iterable[Frame], speed: float, player: can.BusABC, daemon: Daemon, channels: Counter[str],
          failed: list[Exception], done: threading.Event) -> None:
    """Send the log's frames at its pace x ``speed``, then stop the daemon once it has fed them all."""
    from canguard.sim.io import to_message

    try:
        # python-can's virtual bus delivers only to the buses open when a frame is sent
        ready_by = time.monotonic() + DRAIN_S
        while not all(daemon.reader.alive().values()) and time.monotonic() < ready_by:
            time.sleep(0.005)
        start_wall, start_log = time.monotonic(), None
        for frame in frames:
            if frame.is_error_frame:
                continue
            start_log = frame.t if start_log is None else start_log
            delay = start_wall + (frame.t - start_log) / speed - time.monotonic()
            if delay > 0.0005:
                time.sleep(delay)
            player.send(to_message(frame))
            channels[frame.channel] += 1
    except Exception as exc:  # a bad line: reported by the main thread, not as a thread traceback
        failed.append(exc)
    finally:
        deadline = time.monotonic() + DRAIN_S  # give up waiting after DRAIN_S
        while daemon.engine.stats.frames < channels.total() and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.05)  # the tick that follows the last frame
        done.set()
        daemon.request_stop("end of log")
