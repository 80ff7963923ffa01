"""Safety table row H2b: a daemon that falls behind its buses stops the task and says so.

When the loop cannot keep up (CPU starvation, a slow reload), frames wait in canguard's
receive queue; the loop still ticks on time, so the watchdog sees nothing, and the
models would judge data older than the sources' ``max_age`` as fresh. A frame that
waited longer than the shortest ``max_age`` holds the task stopped (inhibit ``overrun``,
an ``overrun`` event) until frames wait less than half of it again.
"""

from __future__ import annotations

import time
from pathlib import Path

import can
import yaml

from canguard.config.loader import load_config
from canguard.engine.gate import TaskGate
from canguard.service.daemon import OVERRUN_FLOOR_S, overrun_limit
from test_daemon import (
    BMS_ID,
    BmsFeeder,
    InProcess,
    bms_data,
    inproc,  # noqa: F401  (the fixture)
    is_stop,
    is_task,
    read_events,
    write_config,
)
from waitkit import receive_until, wait_until


def overruns(path: Path) -> list[str]:
    """The reasons of the ``overrun`` events written so far."""
    return [e["reason"] for e in read_events(path) if e["event"] == "overrun"]


class TestOverrun:
    """The daemon's loop, behind and caught up again, as the bus and the journal see it."""

    def test_frames_that_waited_too_long_stop_the_task_until_caught_up(self, inproc: InProcess) -> None:  # noqa: F811
        """A frame that waited longer than the shortest max_age stops the motors and says why; fresh frames resume."""
        daemon, peer = inproc.daemon, inproc.peer
        limit = daemon.overrun_limit_s
        with BmsFeeder(peer):
            receive_until(peer, is_task, "task frame")
            late = can.Message(timestamp=daemon.clock.now(), arbitration_id=BMS_ID, data=bms_data(10.0))
            daemon.reader.queue.put(("main", late, time.monotonic() - 2 * limit))  # waited twice the limit
            receive_until(peer, is_stop, "Estop once the daemon is behind")
            wait_until(lambda: len(overruns(inproc.events)) >= 2, what="the overrun event and its caught-up one")
            receive_until(peer, is_task, "task frame once caught up")
        first, second = overruns(inproc.events)[:2]
        assert first.startswith("frames waited ") and f"(limit {limit:.3f} s)" in first
        assert "the daemon is behind its buses" in first
        assert second.startswith("caught up: frames wait ")
        stops = [e for e in read_events(inproc.events) if e["event"] == "stop"]
        assert any("behind its buses" in e["reason"] for e in stops)

    def test_no_overrun_while_keeping_up(self, inproc: InProcess) -> None:  # noqa: F811
        """A daemon that keeps up with its bus never reports an overrun."""
        with BmsFeeder(inproc.peer):
            receive_until(inproc.peer, is_task, "task frame")
            stats = inproc.daemon.engine.stats
            read = stats.frames
            wait_until(lambda: stats.frames >= read + 100, what="the daemon to read 100 more frames")
        assert overruns(inproc.events) == []
        assert inproc.daemon.engine.gate.state == TaskGate.RUNNING


class TestLimit:
    """The limit is the config's own word for too old: the shortest max_age, never below a floor."""

    def test_the_shortest_max_age(self, tmp_path: Path) -> None:
        """The bundled config's shortest source max_age is the limit."""
        cfg = load_config(write_config(tmp_path, {"interface": "virtual", "channel": "x"}))
        assert overrun_limit(cfg) == min(s.max_age_s for s in cfg.sources.values())

    def test_never_below_the_floor(self, tmp_path: Path) -> None:
        """A source with a 1 ms max_age does not make scheduling jitter an overrun."""
        def tiny(doc: dict) -> None:
            doc["sources"]["/battery_state"]["max_age"] = 0.001

        path = write_config(tmp_path, {"interface": "virtual", "channel": "x"}, edit=tiny)
        assert yaml.safe_load(path.read_text())["sources"]["/battery_state"]["max_age"] == 0.001
        assert overrun_limit(load_config(path)) == OVERRUN_FLOOR_S
