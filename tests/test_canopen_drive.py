"""A CiA 402 drive simulated by the ``canopen`` library guards like any source, live and in replay.

The drive is the canopen library's own ``LocalNode`` built from the same EDS as the
config (tests/data/canopen/cia402_drive.eds), on python-can's virtual bus: it sends
its TPDOs, heartbeat and EMCY and receives canguard's controlword RPDO and NMT
commands. The daemon runs in-process on that channel; a recorder on the channel
writes a candump log of the bus, and ``canguard replay`` of that log must journal
the same source and guard events as the live run.
"""

from __future__ import annotations

import json
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import pytest
import yaml

from canguard.cli.main import main
from canguard.service.daemon import Daemon
from canguard.service.systemd import Notifier
from test_canopen_config import EDS, NODE, TREE
from waitkit import join_or_stacks

WAIT_S = 20.0
"""Upper bound for anything a test waits for (a loaded machine is slow, never this slow)."""
HEARTBEAT_MS = 1000
"""The drive's heartbeat: its 1.5x timeout leaves 0.5 s for a loaded machine's scheduling.

A live daemon judges a heartbeat missing when it has not *received* one in time; the log
only knows when each was sent. A heartbeat stuck in a starved thread past the timeout is a
gap live and none in the log, so the slack must exceed the worst scheduling delay."""
OPERATION_ENABLED = 0x0027
FAULT = 0x0008



def write_config(tmp: Path, channel: str, stop: list[dict[str, Any]]) -> Path:
    """A config guarding the drive's torque (0x6077, in 0.1 % steps) with no DBC at all."""
    (tmp / "tree.xml").write_text(TREE, encoding="utf-8")
    doc = {
        "buses": {"main": {"interface": "virtual", "channel": channel}},
        "canopen": {"left": {"eds": str(EDS), "node": NODE, "bus": "main", "heartbeat": HEARTBEAT_MS / 1000}},
        "sources": {"left_torque": {"kind": "current", "canopen": "left", "object": "0x6077", "scale": 0.1}},
        "tree": {"file": "tree.xml", "tick_hz": 100},
        "task": {"period": 0.02, "frames": [{"canopen": "left", "command": "enable_operation"}]},
        "stop": {"repeat": 0.05, "frames": stop},
        "events": "events.jsonl",
    }
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


@dataclass
class Bench:
    """The simulated drive, the daemon and a recorder of the bus, all on one virtual channel."""

    node: Any
    network: Any
    daemon: Daemon
    recorder: Any
    events: Path
    config: Path
    frames: list[Any]

    @property
    def tpdo(self) -> Any:
        """TPDO2 of the drive: statusword, torque and current actual values."""
        return self.node.tpdo[2]

    def set(self, torque: int | None = None, status: int | None = None) -> None:
        """Change what TPDO2 carries from its next transmission on."""
        if torque is not None:
            self.tpdo["Torque actual value"].raw = torque
        if status is not None:
            self.tpdo["Statusword"].raw = status
        self.tpdo.update()

    def journal(self) -> list[dict[str, Any]]:
        """The daemon's events so far."""
        if not self.events.exists():
            return []
        lines = self.events.read_text(encoding="utf-8").splitlines()
        return [json.loads(line) for line in lines if line.strip()]

    def wait_event(self, pred: Callable[[dict[str, Any]], bool], what: str) -> dict[str, Any]:
        """The first journalled event matching ``pred``; fail naming ``what`` after WAIT_S."""
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            self.drain()
            for event in self.journal():
                if pred(event):
                    return event
            time.sleep(0.02)
        pytest.fail(f"no {what} journalled within {WAIT_S} s")

    def wait_for(self, pred: Callable[[], bool], what: str) -> None:
        """Wait until ``pred()`` holds; fail naming ``what`` after WAIT_S."""
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            self.drain()
            if pred():
                return
            time.sleep(0.02)
        pytest.fail(f"{what} did not happen within {WAIT_S} s")

    def drain(self) -> None:
        """Keep every frame the recorder has seen so far."""
        while (msg := self.recorder.recv(0)) is not None:
            self.frames.append(msg)

    def controlword(self) -> int:
        """The controlword the drive last received in RPDO1."""
        return int(self.node.rpdo[1]["Controlword"].raw)

    def write_log(self, path: Path) -> Path:
        """The recorded bus from the daemon's start on, as a candump -L log.

        The drive runs before the daemon starts; frames from before the start event would
        give the replay a beginning (and a first gap) the live daemon never saw.
        """
        self.drain()
        start = next(e["t"] for e in self.journal() if e["event"] == "start")
        lines = [f"({m.timestamp:.6f}) can0 {m.arbitration_id:03X}#{bytes(m.data).hex().upper()}"
                 for m in self.frames if m.timestamp >= start]
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
        return path


def start_bench(tmp_path: Path, stop: list[dict[str, Any]]) -> tuple[Bench, threading.Thread, list[int]]:
    import canopen  # here, not at module level: only the worker running these tests pays for it at collection

    channel = f"canguard-canopen-{uuid.uuid4().hex[:12]}"
    config = write_config(tmp_path, channel, stop)
    recorder = can.Bus(interface="virtual", channel=channel)
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    node = canopen.LocalNode(NODE, str(EDS))
    network.add_node(node)
    node.tpdo.read(from_od=True)
    node.rpdo.read(from_od=True)
    node.nmt.state = "OPERATIONAL"
    node.nmt.start_heartbeat(HEARTBEAT_MS)
    bench = Bench(node, network, Daemon(config, notifier=Notifier(env={})), recorder,
                  tmp_path / "events.jsonl", config, [])
    bench.set(torque=100, status=OPERATION_ENABLED)  # 10.0 (% of rated torque, scale 0.1)
    bench.tpdo.start(0.02)
    result: list[int] = []
    thread = threading.Thread(target=lambda: result.append(bench.daemon.run()), name="daemon", daemon=True)
    thread.start()
    return bench, thread, result


@pytest.fixture
def bench_factory(tmp_path: Path) -> Iterator[Callable[[list[dict[str, Any]]], Bench]]:
    """Starts a drive, a daemon and a recorder; everything is stopped and joined at teardown."""
    started: list[tuple[Bench, threading.Thread, list[int]]] = []

    def make(stop: list[dict[str, Any]]) -> Bench:
        started.append(start_bench(tmp_path, stop))
        return started[-1][0]

    yield make
    for bench, thread, result in started:
        bench.daemon.request_stop("test over")
        hung = join_or_stacks(thread)
        bench.tpdo.stop()
        bench.node.nmt.stop_heartbeat()
        bench.network.disconnect()
        bench.recorder.shutdown()
        assert not hung, f"Daemon.run did not return after request_stop: {hung}"
        assert result == [0]


QUICK_STOP = [{"canopen": "left", "command": "quick_stop"}]


def compared(events: list[dict[str, Any]]) -> list[tuple[Any, ...]]:
    """What the live run and its replay must agree on: source, guard and EMCY events in order."""
    keep = ("stale", "fresh", "trip", "recover", "emcy")
    return [(e["event"], e.get("source"), e.get("reason"), e.get("code"), e.get("error_register"))
            for e in events if e["event"] in keep]


def is_stale(reason: str) -> Callable[[dict[str, Any]], bool]:
    return lambda e: e["event"] == "stale" and e.get("reason") == reason


def is_fresh(reason: str) -> Callable[[dict[str, Any]], bool]:
    return lambda e: e["event"] == "fresh" and e.get("reason") == f"{reason} cleared"


@pytest.mark.slow
def test_drive_trips_stops_goes_stale_fails_on_emcy_and_recovers_live_and_in_replay(
    bench_factory: Callable[[list[dict[str, Any]]], Bench], tmp_path: Path
) -> None:
    """Torque trip sends the quick stop; heartbeat loss, EMCY and the Fault bit fail the guard; replay agrees."""
    bench = bench_factory(QUICK_STOP)
    bench.wait_for(lambda: bench.controlword() == 0x000F, "enable operation received by the drive")

    bench.set(torque=400)  # 40 % > 35: trip
    bench.wait_event(lambda e: e["event"] == "trip", "a torque trip")
    bench.wait_for(lambda: bench.controlword() == 0x0002, "the quick stop received by the drive")
    bench.set(torque=100)
    bench.wait_event(lambda e: e["event"] == "recover", "the guard's recovery")
    bench.wait_for(lambda: bench.controlword() == 0x000F, "enable operation again")

    bench.node.nmt.stop_heartbeat()  # the drive's heartbeat goes missing: stale no_heartbeat
    stale = bench.wait_event(is_stale("no_heartbeat"), "a no_heartbeat source")
    bench.wait_for(lambda: bench.controlword() == 0x0002, "the quick stop on heartbeat loss")
    # The heartbeat stays missing for a few ticks more: a replay's tick grid starts at its first frame, not at
    # the daemon's start, so a gap that ended within one tick period of the live verdict may hold no replay tick.
    bench.wait_for(lambda: bench.frames[-1].timestamp > stale["t"] + 0.05, "50 ms of traffic past the verdict")
    bench.node.nmt.start_heartbeat(HEARTBEAT_MS)
    bench.wait_event(is_fresh("no_heartbeat"), "the heartbeat back")

    bench.node.emcy.send(0x2310, 0x01, b"\x01\x02\x03\x04\x05")  # current error, generic error register bit
    emcy = bench.wait_event(lambda e: e["event"] == "emcy", "an emcy event")
    assert (emcy["code"], emcy["error_register"], emcy["manufacturer"]) == ("0x2310", 1, "0102030405")
    bench.wait_event(is_stale("emcy"), "the source invalid on the EMCY")
    bench.node.emcy.reset()
    bench.wait_event(is_fresh("emcy"), "the EMCY error reset")

    bench.set(status=OPERATION_ENABLED | FAULT)
    bench.wait_event(is_stale("drive_fault"), "the statusword Fault bit")
    bench.set(status=OPERATION_ENABLED)
    bench.wait_event(is_fresh("drive_fault"), "the Fault bit cleared")
    bench.wait_for(lambda: bench.controlword() == 0x000F, "enable operation after the fault")

    bench.daemon.request_stop("test over")
    bench.wait_event(lambda e: e["event"] == "exit", "the daemon's exit")
    live = compared(bench.journal())
    log = bench.write_log(tmp_path / "drive.log")
    replayed_events = tmp_path / "replay.jsonl"
    assert main(["replay", str(log), "-c", str(bench.config), "--events", str(replayed_events)]) == 0
    replayed = compared([json.loads(x) for x in replayed_events.read_text(encoding="utf-8").splitlines() if x])
    assert live == replayed
    assert ("emcy", "left_torque", None, "0x0000", 0) in live  # the reset is journalled too


@pytest.mark.slow
def test_nmt_stop_reaches_the_drive_and_its_stopped_state_keeps_the_source_unusable(
    bench_factory: Callable[[list[dict[str, Any]]], Bench],
) -> None:
    """A stop with ``nmt: stop`` stops the drive; its heartbeat then says STOPPED and the source is ``not_present``."""
    bench = bench_factory([*QUICK_STOP, {"canopen": "left", "nmt": "stop"}])
    bench.wait_for(lambda: bench.controlword() == 0x000F, "enable operation received by the drive")
    bench.set(torque=400)
    bench.wait_for(lambda: bench.node.nmt.state == "STOPPED", "the drive stopped by NMT")
    bench.wait_event(is_stale("not_present"), "a not_present source")
    bench.set(torque=100)  # the torque is fine again, the drive still stopped: the task stays stopped
    seen = len(bench.frames)
    bench.wait_for(lambda: sum(1 for m in bench.frames[seen:] if m.arbitration_id == 0x700 + NODE) >= 3,
                   "three more heartbeats of the stopped drive")
    assert [m.data[0] for m in bench.frames[seen:] if m.arbitration_id == 0x700 + NODE][-1] == 0x04
    assert not [e for e in bench.journal() if e["event"] == "resume"]
