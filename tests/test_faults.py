"""Bus-level faults met by the daemon through its own bus code.

The daemon runs in a thread on a virtual channel; its buses are wrapped by
:class:`FaultyBus` (bus-off, refused sends, error frames, lost
frames), and a peer on the same channel plays the BMS and watches what canguard sends.
"""

from __future__ import annotations

import functools
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can
import pytest

import canguard.service.daemon as daemon_mod
from canguard.config.schema import BusConfig
from canguard.engine.gate import TaskGate
from canguard.io.bus import BusReader
from canguard.service.daemon import Daemon
from canguard.service.systemd import Notifier
from test_daemon import BMS_ID, BmsFeeder, is_stop, is_task, read_events, write_config
from waitkit import receive_until, wait_until


@dataclass
class Faults:
    """What the wrapped buses do wrong right now; the tests flip these while the daemon runs."""

    bus_off: bool = False  # receive, send and opening the bus again raise CanOperationError
    fail_sends: int = 0  # sends that raise (a full transmit queue); -1: every send until set back to 0
    drop_ids: set[int] = field(default_factory=set)  # frames with these ids are lost on receive
    error_frames: int = 0  # error frames still to deliver on receive
    refused_sends: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def take_send_failure(self) -> bool:
        with self.lock:
            fail = self.bus_off or self.fail_sends != 0
            if self.fail_sends > 0:
                self.fail_sends -= 1
            self.refused_sends += fail
            return fail

    def take_error_frame(self) -> bool:
        with self.lock:
            if self.error_frames <= 0:
                return False
            self.error_frames -= 1
            return True


class FaultyBus(can.BusABC):
    """A python-can bus that passes everything to ``inner`` except what :class:`Faults` says."""

    def __init__(self, inner: can.BusABC, faults: Faults) -> None:
        self.inner, self.faults, self.channel_info = inner, faults, f"faulty({inner.channel_info})"
        super().__init__(channel=str(getattr(inner, "channel", "faulty")))

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self.faults.bus_off:
            raise can.CanOperationError("bus-off (injected)")
        if self.faults.take_error_frame():  # a controller problem (CAN_ERR_FLAG | CAN_ERR_CRTL)
            return can.Message(arbitration_id=0x20000004, is_error_frame=True, is_extended_id=True,
                               data=bytes([0, 0x04, 0, 0, 0, 0, 0, 0]), timestamp=time.time()), False
        msg = self.inner.recv(timeout)
        return (None if msg is None or msg.arbitration_id in self.faults.drop_ids else msg), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.faults.take_send_failure():
            raise can.CanOperationError("transmit refused (injected: bus-off or full TX queue)")
        self.inner.send(msg, timeout)

    def shutdown(self) -> None:
        self.inner.shutdown()
        super().shutdown()


def faulty_opener(faults: Faults) -> Callable[[BusConfig], can.BusABC]:
    """A BusReader ``opener``: each bus wrapped in a FaultyBus; no reopening while bus-off."""

    def opener(cfg: BusConfig) -> can.BusABC:
        if faults.bus_off:
            raise can.CanOperationError(f"bus {cfg.name}: interface down (injected bus-off)")
        return FaultyBus(can.Bus(**dict(cfg.kwargs)), faults)

    return opener


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
            receive_until(rig.peer, is_task, "task frame before the fault")
            rig.faults.bus_off = True
            wait_until(lambda: any("bus-off" in str(e["reason"]) for e in events(rig, "bus_error")),
                       what="a bus_error event naming bus-off")
            wait_until(lambda: rig.daemon.engine.gate.state == TaskGate.STOPPED, what="the task gate stopped")
            rig.faults.bus_off = False
            wait_until(lambda: any(e["reason"] == "reopened" for e in events(rig, "bus_error")),
                       what="the bus reopened")
            wait_until(lambda: rig.daemon.engine.gate.state != TaskGate.STOPPED, what="the task resumed")
            drain(rig.peer)
            receive_until(rig.peer, is_task, "task frame after the bus came back")


class TestRefusedSends:
    """Our own stop frames are refused (full TX queue): they are retried until the bus takes them."""

    def test_stop_frames_refused_then_delivered(self, rig: Rig) -> None:
        with BmsFeeder(rig.peer) as feeder:
            receive_until(rig.peer, is_task, "task frame before the fault")
            rig.faults.fail_sends = -1
            feeder.current_a = 40.0  # overcurrent: the tree stops the task
            wait_until(lambda: events(rig, "trip"), what="a trip")
            wait_until(lambda: rig.faults.refused_sends >= 4, what="refused stop frames")
            wait_until(lambda: any("send refused" in str(e["reason"]) and "(stop)" in str(e["reason"])
                                   for e in events(rig, "bus_error")), what="the refusal journalled")
            drain(rig.peer)
            refused = rig.faults.refused_sends

            def refused_again() -> bool:
                msg = rig.peer.recv(0.01)
                assert msg is None or not is_stop(msg), "a refused stop frame reached the bus"
                return rig.faults.refused_sends >= refused + 8

            wait_until(refused_again, what="two more rounds of stop frames refused")
            rig.faults.fail_sends = 0
            receive_until(rig.peer, is_stop, "a stop frame once the bus takes frames again")


class TestErrorFramesAndLoss:
    """Error frames are counted, not decoded; lost frames of a source make it stale and stop the task."""

    def test_error_frames_counted_task_goes_on(self, rig: Rig) -> None:
        with BmsFeeder(rig.peer):
            receive_until(rig.peer, is_task, "task frame")
            rig.faults.error_frames = 32
            wait_until(lambda: rig.daemon.engine.decoder.error_frames >= 32, what="32 error frames counted")
            drain(rig.peer)
            receive_until(rig.peer, is_task, "task frame after the error burst")
        assert not events(rig, "trip")

    def test_lost_bms_frames_go_stale_and_stop(self, rig: Rig) -> None:
        with BmsFeeder(rig.peer):
            receive_until(rig.peer, is_task, "task frame")
            rig.faults.drop_ids = {BMS_ID}
            wait_until(lambda: any(e["source"] == "/battery_state" for e in events(rig, "stale")),
                       what="/battery_state stale")
            wait_until(lambda: rig.daemon.engine.gate.state == TaskGate.STOPPED, what="the task gate stopped")
            rig.faults.drop_ids = set()
            wait_until(lambda: any(e["source"] == "/battery_state" for e in events(rig, "fresh")), what="fresh again")
            wait_until(lambda: rig.daemon.engine.gate.state != TaskGate.STOPPED, what="the task resumed")
            drain(rig.peer)
            receive_until(rig.peer, is_task, "task frame after the source is fresh again")
