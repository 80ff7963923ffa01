"""Bus-level faults met by the daemon through its own bus code (issue 17 item 2).

The daemon runs in a thread on a virtual channel; its buses are wrapped by
:class:`canguard.sim.faults.FaultyBus` (bus-off, refused sends, error frames, lost
frames), and a peer on the same channel plays the BMS and watches what canguard sends.
"""

from __future__ import annotations

import functools
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import can
import pytest

import canguard.service.daemon as daemon_mod
from canguard.engine.gate import TaskGate
from canguard.io.bus import BusReader
from canguard.service.daemon import Daemon
from canguard.service.systemd import Notifier
from canguard.sim.faults import Faults, faulty_opener
from test_daemon import BMS_ID, WAIT_S, BmsFeeder, is_stop, is_task, read_events, write_config


@dataclass
class Rig:
    daemon: Daemon
    peer: can.BusABC
    faults: Faults
    events: Path


@pytest.fixture
def rig(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Rig]:
    """Daemon.run in a thread, its bus wrapped in a FaultyBus; a clean peer on the same virtual channel."""
    channel = f"canguard-faults-{uuid.uuid4().hex[:12]}"
    faults = Faults()
    monkeypatch.setattr(daemon_mod, "BusReader", functools.partial(BusReader, opener=faulty_opener(faults),
                                                                    backoff_min_s=0.05, backoff_max_s=0.2))
    daemon = Daemon(write_config(tmp_path, {"interface": "virtual", "channel": channel}), notifier=Notifier(env={}))
    peer = can.Bus(interface="virtual", channel=channel)
    result: list[int] = []
    thread = threading.Thread(target=lambda: result.append(daemon.run()), daemon=True)
    thread.start()
    try:
        yield Rig(daemon, peer, faults, tmp_path / "events.jsonl")
    finally:
        faults.bus_off = False
        faults.fail_sends = 0
        daemon.request_stop("test over")
        thread.join(10)
        peer.shutdown()
    assert result == [0]


def until(what: str, cond: Callable[[], object]) -> None:
    deadline = time.monotonic() + WAIT_S
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"not within {WAIT_S} s: {what}")
        time.sleep(0.01)


def receive(bus: can.BusABC, pred: Callable[[can.Message], bool], what: str) -> can.Message:
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        msg = bus.recv(0.1)
        if msg is not None and pred(msg):
            return msg
    pytest.fail(f"no {what} within {WAIT_S} s")


def drain(bus: can.BusABC) -> None:
    """Forget what the peer received so far: the next frame it reads is a new one."""
    while bus.recv(0) is not None:
        pass


def events(rig: Rig, name: str) -> list[dict[str, object]]:
    return [e for e in read_events(rig.events) if e["event"] == name]


class TestBusOff:
    """The controller goes bus-off: the task stops with a bus_error event; it resumes once the bus is back."""

    def test_bus_off_stops_and_recovery_releases(self, rig: Rig) -> None:
        with BmsFeeder(rig.peer):
            receive(rig.peer, is_task, "task frame before the fault")
            rig.faults.bus_off = True
            until("a bus_error event naming bus-off", lambda: any("bus-off" in str(e["reason"])
                                                                  for e in events(rig, "bus_error")))
            until("the task gate stopped", lambda: rig.daemon.engine.gate.state == TaskGate.STOPPED)
            rig.faults.bus_off = False
            until("the bus reopened", lambda: any(e["reason"] == "reopened" for e in events(rig, "bus_error")))
            until("the task resumed", lambda: rig.daemon.engine.gate.state != TaskGate.STOPPED)
            drain(rig.peer)
            receive(rig.peer, is_task, "task frame after the bus came back")


class TestRefusedSends:
    """Our own stop frames are refused (full TX queue): they are retried until the bus takes them."""

    def test_stop_frames_refused_then_delivered(self, rig: Rig) -> None:
        with BmsFeeder(rig.peer) as feeder:
            receive(rig.peer, is_task, "task frame before the fault")
            rig.faults.fail_sends = -1
            feeder.current_a = 40.0  # overcurrent: the tree stops the task
            until("a trip", lambda: events(rig, "trip"))
            until("refused stop frames", lambda: rig.faults.refused_sends >= 4 and rig.daemon.sink.failed >= 4)
            until("the refusal journalled", lambda: any("send refused" in str(e["reason"]) and "(stop)" in
                                                        str(e["reason"]) for e in events(rig, "bus_error")))
            drain(rig.peer)
            quiet_until = time.monotonic() + 0.3
            while time.monotonic() < quiet_until:  # refused frames do not reach the bus
                msg = rig.peer.recv(0.05)
                assert msg is None or not is_stop(msg)
            rig.faults.fail_sends = 0
            receive(rig.peer, is_stop, "a stop frame once the bus takes frames again")


class TestErrorFramesAndLoss:
    """Error frames are counted, not decoded; lost frames of a source make it stale and stop the task."""

    def test_error_frames_counted_task_goes_on(self, rig: Rig) -> None:
        with BmsFeeder(rig.peer):
            receive(rig.peer, is_task, "task frame")
            rig.faults.error_frames = 32
            until("32 error frames counted", lambda: rig.daemon.engine.decoder.error_frames >= 32)
            drain(rig.peer)
            receive(rig.peer, is_task, "task frame after the error burst")
        assert not events(rig, "trip")

    def test_lost_bms_frames_go_stale_and_stop(self, rig: Rig) -> None:
        with BmsFeeder(rig.peer):
            receive(rig.peer, is_task, "task frame")
            rig.faults.drop_ids = {BMS_ID}
            until("/battery_state stale", lambda: any(e["source"] == "/battery_state" for e in events(rig, "stale")))
            until("the task gate stopped", lambda: rig.daemon.engine.gate.state == TaskGate.STOPPED)
            rig.faults.drop_ids = set()
            until("fresh again", lambda: any(e["source"] == "/battery_state" for e in events(rig, "fresh")))
            until("the task resumed", lambda: rig.daemon.engine.gate.state != TaskGate.STOPPED)
            drain(rig.peer)
            receive(rig.peer, is_task, "task frame after the source is fresh again")
