"""A watched daemon for the monitor tests: the demo's robot and config on a private virtual bus.

:func:`watched_daemon` runs :class:`~canguard.service.daemon.Daemon` in a thread with the status
page and/or Groot2's monitor on ephemeral loopback ports, and the simulated robot in another
thread, as ``canguard demo`` does; a peer bus on the same channel lets a test inject a trip.
Nothing here reads the monitors' own code: the tests speak HTTP and ZeroMQ to them.
"""

from __future__ import annotations

import contextlib
import json
import re
import threading
import time
import urllib.request
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import cantools
import py_trees
import pytest
import yaml

from canguard.service.daemon import Daemon
from canguard.service.systemd import Notifier
from checkout import REPO
from waitkit import join_or_stacks

DEMO = REPO / "config" / "examples" / "robot_guard.yaml"
DBC = REPO / "dbc" / "robot.dbc"
TREE = REPO / "config" / "trees" / "robot_guard.xml"
BMS_ID = 0x18FF50E5
ESTOP_IDS = {node << 5 | 0x02 for node in range(4)}
ROBOT_RATES_HZ = {"Get_Iq": 50.0, "Get_Torques": 50.0, "Get_Encoder_Estimates": 20.0}
"""The simulated robot's axis streams at a fifth of the demo's rates (650 frames a second, not 2,570): its
sources stay fresh (max_age 0.5 s), its values move every tick or two and the task runs, for ~40 % less CPU
a second than the demo's robot; the BMS keeps its 50 Hz (a test's trip competes with it as in the demo).
``busy=True`` runs the demo's rates, for a test whose subject is a busy robot."""
WAIT_S = 20.0
"""Upper bound for anything a test waits for (a loaded machine is slow, never this slow)."""

DEMO_GUARDS = ("PackCurrent", "JointEfforts", "Axis0Current", "Axis0I2t", "Axis1Current", "Axis1I2t",
               "Axis2Current", "Axis2I2t", "Axis3Current", "Axis3I2t")
"""The guard nodes of the demo's tree (config/trees/robot_guard.xml)."""


def write_demo_config(tmp: Path, channel: str, monitor: dict[str, Any] | None = None, min_stop_s: float = 3.0) -> Path:
    """The demo's config on ``channel``: absolute paths, events in ``tmp``, no state file, stops held ``min_stop_s``."""
    doc = yaml.safe_load(DEMO.read_text(encoding="utf-8"))
    doc["dbc"] = [str(DBC)]
    doc["tree"]["file"] = str((DEMO.parent / doc["tree"]["file"]).resolve())
    doc["buses"] = {"main": {"interface": "virtual", "channel": channel}}
    doc["events"] = str(tmp / "events.jsonl")
    doc.pop("state", None)
    doc["stop"]["min_stop"] = min_stop_s  # a stop stays on the page long enough to be seen
    if monitor:
        doc["monitor"] = monitor
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc, allow_unicode=True), encoding="utf-8")
    return path


def wait_for(what: str, predicate: Callable[[], Any], timeout_s: float = WAIT_S) -> Any:
    """Poll ``predicate`` until it returns something truthy; fail naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.01)


@dataclass
class Watched:
    """A running daemon with its monitors, the robot, and a peer on the bus."""

    daemon: Daemon
    peer: can.BusABC
    config: Path
    events: Path
    http: str
    """``http://127.0.0.1:PORT`` of the status page ('' when not served)."""
    groot2: int
    """The Groot2 REP port (0 when not served)."""
    robot_stop: threading.Event
    """Set it and the robot falls silent: every source goes stale, every guard fails and stays failed."""

    def get(self, path: str, headers: dict[str, str] | None = None, timeout_s: float = 5.0) -> Any:
        """GET ``path`` from the page's server: the parsed JSON of a JSON answer, else the text."""
        req = urllib.request.Request(self.http + path, headers=headers or {})
        with urllib.request.urlopen(req, timeout=timeout_s) as resp:
            body = resp.read().decode()
            return json.loads(body) if resp.headers.get_content_type() == "application/json" else body

    def status(self) -> dict[str, Any]:
        """``GET /api/status``."""
        doc: dict[str, Any] = self.get("/api/status")
        return doc

    def trip_until_estop(self, within_s: float) -> can.Message | None:
        """Trip (:meth:`trip`), the peer listening for Estop frames only: the first within ``within_s``, or None."""
        peer = self.peer
        peer.set_filters([{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in ESTOP_IDS])
        while peer.recv(0) is not None:  # Estops of earlier stops: not this trip's
            pass
        self.wait_running()
        sent = time.monotonic()
        self.trip()
        msg = peer.recv(0.05)  # the Estop of a trip that took longer than within_s still counts as late, below
        while msg is None and time.monotonic() - sent < within_s:
            msg = peer.recv(0.05)
        return msg if msg is not None and msg.timestamp - peer_time(sent) <= within_s else None

    def wait_running(self) -> None:
        """Wait until the task runs: the start window is over, and no other stop holds it."""
        wait_for("the task to run", lambda: self.daemon.engine.gate.state == self.daemon.engine.gate.RUNNING)

    def trip(self, current_a: float = 60.0) -> None:
        """A BMS frame far over PackCurrent's 35 A threshold, from the peer, once the task runs; again until it stops.

        In the start window a failing tree holds the task idle rather than stopping it, so the frame
        goes once the task runs. And the simulated robot sends its own BMS frames on the same virtual
        channel from another thread: python-can stamps a frame before it queues it, so the peer's frame
        can arrive after a newer one of the robot's and be an out-of-order sample, which changes nothing
        (the daemon is right to ignore it). So the frame is sent again until the task has stopped.
        """
        self.wait_running()
        msg = _db().get_message_by_name("BMS_Status")
        data = msg.encode({"Pack_Current": current_a, "Pack_Voltage": 48.0, "State_Of_Charge": 80.0,
                           "Present": 1, "Fault": 0, "Alive_Counter": 0})
        frame = can.Message(arbitration_id=BMS_ID, data=data, is_extended_id=True)
        deadline = time.monotonic() + WAIT_S
        while True:
            self.peer.send(frame)
            if wait_stopped(self.daemon, 0.25) or time.monotonic() > deadline:
                return


def peer_time(mono: float) -> float:
    """A ``time.monotonic()`` reading on the wall-clock base python-can's virtual bus stamps frames with."""
    return time.time() - (time.monotonic() - mono)


def wait_stopped(daemon: Daemon, timeout_s: float) -> bool:
    """True once the daemon's task is stopped, waiting at most ``timeout_s``."""
    gate = daemon.engine.gate
    deadline = time.monotonic() + timeout_s
    while gate.state != gate.STOPPED:
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


_DB: list[Any] = []


def _db() -> Any:
    if not _DB:
        _DB.append(cantools.database.load_file(str(DBC)))
    return _DB[0]


def _logged_port(messages: list[str], label: str) -> int:
    for text in messages:
        m = re.search(label + r" on (?:http://)?127\.0\.0\.1:(\d+)", text)
        if m:
            return int(m.group(1))
    return 0


@contextlib.contextmanager
def watched_daemon(tmp: Path, *, http: bool = True, groot2: bool = False, token: str | None = None,
                   robot: bool = True, busy: bool = False) -> Iterator[Watched]:
    """The demo's daemon in a thread with its monitors on ephemeral loopback ports; stopped at exit.

    The robot sends its axis streams at :data:`ROBOT_RATES_HZ`, or at the demo's rates when ``busy``.

    py_trees' blackboard is global: it is cleared before the daemon builds its tree and after it stops,
    so a daemon shared by a module's tests (:func:`shared_daemon`) holds it alone while it runs.
    """
    import logging

    from canguard.sim import run_on_bus

    channel = f"canguard-monitor-{uuid.uuid4().hex[:12]}"
    monitor: dict[str, Any] = {}
    if http:
        monitor["http"] = "127.0.0.1:0"
    if groot2:
        monitor["groot2"] = "127.0.0.1:0"
    if token:
        monitor["token"] = token
    config = write_demo_config(tmp, channel, monitor)
    records: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: records.append(record.getMessage())  # type: ignore[method-assign]
    logger = logging.getLogger("canguard.service.monitor")
    logger.addHandler(handler)
    py_trees.blackboard.Blackboard.clear()
    daemon = Daemon(config, notifier=Notifier(env={}))
    peer = can.Bus(interface="virtual", channel=channel)
    robot_bus = can.Bus(interface="virtual", channel=channel)
    stop = threading.Event()
    sim = threading.Thread(target=run_on_bus, name="robot", daemon=True,
                           kwargs={"bus": robot_bus, "duration_s": 600.0, "stop_event": stop, "db": _db(),
                                   "scenarios": ("normal",), "seed": 1, "start_t": time.time(),
                                   "rates_hz": None if busy else ROBOT_RATES_HZ})
    result: list[int] = []
    thread = threading.Thread(target=lambda: result.append(daemon.run()), name="daemon", daemon=True)
    thread.start()
    if robot:
        sim.start()
    try:
        http_port = wait_for("the status page's address", lambda: _logged_port(records, "status page")) if http else 0
        groot2_port = wait_for("the Groot2 address", lambda: _logged_port(records, "Groot2 monitor")) if groot2 else 0
        yield Watched(daemon, peer, config, tmp / "events.jsonl", f"http://127.0.0.1:{http_port}" if http else "",
                      groot2_port, stop)
    finally:
        logger.removeHandler(handler)
        daemon.request_stop("test over")
        hung = join_or_stacks(thread)
        stop.set()
        if robot:
            sim.join(5)
        peer.shutdown()
        robot_bus.shutdown()
        py_trees.blackboard.Blackboard.clear()
    assert not hung, f"Daemon.run did not return after request_stop: {hung}"
    assert result == [0]


def running(watched: Watched) -> bool:
    """True once the task runs (every source fresh, the tree asked for the task)."""
    task = watched.status().get("task")
    return bool(task) and task["state"] == "running"


@contextlib.contextmanager
def real_signals(daemon: Daemon) -> Iterator[None]:
    """The daemon's own SIGTERM/SIGINT/SIGHUP handlers in this (main) thread, the previous ones back at exit."""
    import signal

    old = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)}
    daemon.install_signals()
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def sighup_with_threshold(watched: Watched, tmp: Path, threshold: str) -> None:
    """Point the config at a copy of the tree with PackCurrent's threshold changed, then SIGHUP this process."""
    import os
    import signal

    tree = tmp / "robot_guard_reloaded.xml"
    tree.write_text(TREE.read_text(encoding="utf-8").replace('overcurrent_threshold="35.0"',
                                                             f'overcurrent_threshold="{threshold}"'), encoding="utf-8")
    doc = yaml.safe_load(watched.config.read_text(encoding="utf-8"))
    doc["tree"]["file"] = str(tree)
    watched.config.write_text(yaml.safe_dump(doc, allow_unicode=True), encoding="utf-8")
    os.kill(os.getpid(), signal.SIGHUP)


@contextlib.contextmanager
def shared_daemon(factory: pytest.TempPathFactory, **monitors: Any) -> Iterator[Watched]:
    """One :func:`watched_daemon`, its task running, for the tests of a module that only read it.

    Starting a daemon with its monitor process costs more CPU than such a test. A module that shares
    one overrides conftest's autouse ``_clean_blackboard`` with one that does nothing: clearing py_trees'
    global blackboard between its tests would clear the running tree's; :func:`watched_daemon` clears it
    around each daemon instead.
    """
    with watched_daemon(factory.mktemp("shared-daemon"), **monitors) as w:
        wait_for("the task to run", lambda: running(w))
        yield w
