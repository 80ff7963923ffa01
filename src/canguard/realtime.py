"""``canguard replay --realtime [SPEED]``: a bench test through the real daemon path.

The log's frames are sent onto a configured bus at the log's pace (like
can-utils' canplayer; SPEED 2 plays twice as fast) from a second connection to
that bus, while a :class:`~canguard.daemon.Daemon` runs live on the same bus: the
frames take the same way as on the robot (bus -> receive thread -> engine -> bus).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from typing import Any

from .config import Config
from .errors import ConfigError


def replay_realtime(cfg: Config, args: argparse.Namespace) -> int:
    """Play each log onto the bus while the daemon runs; print the daemon's summary; exit code as replay."""
    import can

    from .daemon import Daemon
    from .replay import ReadStats, read_log
    from .replay_cmd import ChannelRouter, build_summary, render_text

    speed = float(args.realtime)
    if speed <= 0:
        raise ConfigError(f"--realtime {speed}: expected a speed > 0 (1 = the log's own pace)")
    bus_name = args.bus or (next(iter(cfg.buses)) if len(cfg.buses) == 1 else None)
    if bus_name is None:
        raise ConfigError(f"--realtime: several buses are configured ({', '.join(cfg.buses)}): "
                          "name the one to play onto with --bus")
    if bus_name not in cfg.buses:
        raise ConfigError(f"--bus {args.bus!r}: expected one of the configured buses: {', '.join(cfg.buses)}")
    tripped = False
    for log_path in args.logs:
        daemon = Daemon(cfg.path)
        player = can.Bus(**dict(cfg.buses[bus_name].kwargs))
        stats = ReadStats()
        done = threading.Event()

        def play(log_path: Any = log_path, stats: ReadStats = stats, player: Any = player,
                 done: threading.Event = done, daemon: Daemon = daemon) -> None:
            try:
                start_wall = time.monotonic()
                start_log = None
                for frame in read_log(log_path, skip_bad=args.skip_bad, stats=stats):
                    if frame.is_error_frame:
                        continue
                    if start_log is None:
                        start_log = frame.t
                    due = start_wall + (frame.t - start_log) / speed
                    delay = due - time.monotonic()
                    if delay > 0.0005:
                        time.sleep(delay)
                    player.send(can.Message(
                        arbitration_id=frame.arbitration_id, data=frame.data, is_extended_id=frame.is_extended_id,
                        is_fd=frame.is_fd, is_remote_frame=frame.is_remote_frame,
                        bitrate_switch=frame.bitrate_switch))
            finally:
                time.sleep(0.2)  # let the last frames reach the daemon
                done.set()
                daemon.request_stop("end of log")

        thread = threading.Thread(target=play, name="canguard-player", daemon=True)
        thread.start()
        try:
            daemon.run()
        finally:
            done.wait(5)
            player.shutdown()
        summary = build_summary(daemon.cfg, log_path, daemon.engine, stats, ChannelRouter(daemon.cfg, {}))
        summary["realtime_speed"] = speed
        tripped = tripped or bool(summary["trips"])
        print(json.dumps(summary, indent=2, sort_keys=True) if args.json else render_text(summary))
    if args.fail_on_trip and tripped:
        return 1
    print("note: --realtime runs the live daemon; its times follow the wall clock, not the log", file=sys.stderr)
    return 0
