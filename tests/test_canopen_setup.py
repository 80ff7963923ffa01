"""``configure: true``: canguard configures a drive over SDO, and a drive that refuses stays unusable.

The drive is the canopen library's ``LocalNode`` (an SDO server) built from
tests/data/canopen/vendor_defaults.eds at its defaults: TPDO2 disabled and empty,
heartbeat 0, pre-operational. A small "firmware" (:class:`Firmware`) does what a drive does
and the library's ``LocalNode`` does not: on NMT start it sends the TPDOs its dictionary
makes valid, every event timer; on a reboot it forgets what it was told and sends its
boot-up message. Everything runs in-process on python-can's virtual bus.
"""

from __future__ import annotations

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

from canguard.config.loader import load_config
from canguard.config.schema import Config
from canguard.service.canopen_setup import DriveSetup
from canguard.service.daemon import Daemon
from canguard.service.systemd import Notifier
from test_canopen_config import TREE
from test_canopen_drive import OPERATION_ENABLED, WAIT_S, Bench
from test_canopen_vendor import VENDOR

NODE = 5
CYCLE_S = 0.05
"""The canopen library's receive threads wait this long per read: a network disconnects that fast."""
HEARTBEAT_S = 1.0
"""The heartbeat canguard tells the drive: 1.5 s of timeout is slack enough for a loaded machine."""


def write_config(tmp: Path, channel: str) -> Path:
    """Drive ``left`` configured by canguard: TPDO2 maps the statusword and the torque; torque guarded at 35 %."""
    (tmp / "tree.xml").write_text(TREE, encoding="utf-8")
    doc = {
        "buses": {"main": {"interface": "virtual", "channel": channel}},
        "canopen": {"left": {"eds": str(VENDOR), "node": NODE, "heartbeat": HEARTBEAT_S, "configure": True,
                             "pdo": {"TPDO2": ["0x6041", "0x6077", "0x6078"]}}},
        "sources": {"left_torque": {"kind": "current", "canopen": "left", "object": "0x6077", "scale": 0.1}},
        "tree": {"file": "tree.xml", "tick_hz": 100},
        "task": {"period": 0.02, "frames": [{"canopen": "left", "command": "enable_operation"}]},
        "stop": {"repeat": 0.05, "frames": [{"canopen": "left", "command": "quick_stop"}]},
        "events": "events.jsonl",
    }
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


class Firmware:
    """A ``LocalNode`` from the EDS at its defaults, with what a drive's firmware adds (see the module docstring)."""

    def __init__(self, channel: str) -> None:
        import canopen

        from canguard.config.canopen import Eds

        self.network = canopen.Network()
        self.network.NOTIFIER_CYCLE = CYCLE_S
        self.network.connect(interface="virtual", channel=channel)
        self.node = canopen.LocalNode(NODE, Eds(VENDOR, NODE).od)  # the EDS as canguard reads it (Lines1=)
        self.network.add_node(self.node)
        self.node.rpdo.read(from_od=True)
        self.node.nmt.state = "PRE-OPERATIONAL"
        self.network.subscribe(0x000, self.on_nmt)
        self.sending: list[Any] = []

    def on_nmt(self, _cob: int, data: bytearray, _t: float) -> None:
        """NMT start: send every valid TPDO at its event timer (the library's node only answers SDO)."""
        if data[0] == 0x01 and data[1] in (0, NODE):
            self.node.tpdo.read(from_od=False)  # what canguard wrote, through the node's own SDO server
            for pdo in self.node.tpdo.map.values():
                if pdo.enabled and pdo.event_timer:
                    for var in pdo.map:
                        var.raw = 0x27 if var.name == "Statusword" else 100
                    pdo.start(pdo.event_timer / 1000)
                    self.sending.append(pdo)
        elif data[0] == 0x80:
            self.stop_pdos()

    def stop_pdos(self) -> None:
        for pdo in self.sending:
            pdo.stop()
        self.sending.clear()

    def reboot(self) -> None:
        """Power cycle: everything written is forgotten, the heartbeat stops, boot-up, pre-operational."""
        self.stop_pdos()
        self.node.nmt.stop_heartbeat()
        self.node.data_store.clear()
        self.node.nmt.state = "PRE-OPERATIONAL"
        self.network.send_message(0x700 + NODE, [0x00])

    def close(self) -> None:
        self.stop_pdos()
        self.node.nmt.stop_heartbeat()
        self.network.disconnect()


@dataclass
class Setup:
    """The config, the drive at its defaults and an SDO client of it (as the daemon's) on one virtual channel."""

    cfg: Config
    drive: Firmware
    client: Any

    def configure(self, prepare: Callable[[Any], None] = lambda node: None) -> dict[str, Any]:
        """Run the setup once (``prepare`` first changes how the node answers): its event."""
        prepare(self.drive.node)
        return DriveSetup.configure(self.cfg.canopen["left"], self.client)


@pytest.fixture
def setup(tmp_path: Path) -> Iterator[Setup]:
    """A :class:`Setup` on a fresh channel; both networks disconnected at teardown."""
    import canopen

    channel = f"canguard-setup-{uuid.uuid4().hex[:12]}"
    cfg = load_config(write_config(tmp_path, channel))
    drive = Firmware(channel)
    network = canopen.Network()
    network.NOTIFIER_CYCLE = CYCLE_S
    network.connect(interface="virtual", channel=channel)
    client = canopen.RemoteNode(NODE, canopen.ObjectDictionary())
    network.add_node(client)
    yield Setup(cfg, drive, client)
    network.disconnect()
    drive.close()


class TestConfigure:
    """One configuration against the node: written, read back, started; or refused and left pre-operational."""

    def test_defaults_become_what_the_config_expects(self, setup: Setup) -> None:
        """TPDO2 valid at 0x285 with the statusword, torque and current every 10 ms; heartbeat 1000 ms; started."""
        drive = setup.drive
        event = setup.configure()
        assert event["event"] == "configure" and "started" in event["reason"]
        deadline = time.monotonic() + WAIT_S
        while drive.node.nmt.state != "OPERATIONAL" and time.monotonic() < deadline:  # NMT has no answer
            time.sleep(0.005)
        assert drive.node.nmt.state == "OPERATIONAL"
        sdo = drive.node.sdo
        assert sdo[0x1801][1].raw == 0x40000285 and sdo[0x1801][5].raw == 10
        assert [sdo[0x1A01][k].raw for k in range(4)] == [3, 0x60410010, 0x60770010, 0x60780010]
        assert sdo[0x1017].raw == 1000

    def test_a_refused_write_is_an_error_and_the_drive_stays_pre_operational(self, setup: Setup) -> None:
        """A drive whose TPDO2 mapping is fixed aborts the write: an error event naming the object; not started."""
        from canopen.sdo.exceptions import SdoAbortedError

        def fixed_mapping(index: int, **_: Any) -> None:
            if index == 0x1A01:
                raise SdoAbortedError(0x06010002)

        drive = setup.drive
        event = setup.configure(lambda node: node.add_write_callback(fixed_mapping))
        assert event["event"] == "error" and event["source"] == "left"
        assert "0x1A01:00 = 0x00 (TPDO2 mapping cleared): refused by the drive (SDO abort 0x06010002" in event["reason"]
        assert "left pre-operational (its sources not_present)" in event["reason"]
        assert drive.node.nmt.state == "PRE-OPERATIONAL"

    def test_a_drive_that_does_not_answer_is_an_error(self, setup: Setup) -> None:
        """No SDO server on the bus (the drive is off): an error event naming the first write; nothing started."""
        setup.drive.close()
        setup.client.sdo.RESPONSE_TIMEOUT = 0.05  # the library's 0.3 s, twice, is only slower
        event = setup.configure()
        assert event["event"] == "error"
        assert "0x1017:00 = 0x03E8 (producer heartbeat every 1000 ms): SdoCommunicationError" in event["reason"]

    def test_a_value_read_back_different_is_an_error(self, setup: Setup) -> None:
        """A drive that keeps its own heartbeat time (reads back 50 ms) is not started."""
        drive = setup.drive
        event = setup.configure(lambda node: node.add_read_callback(
            lambda index, **_: 50 if index == 0x1017 else None))
        assert event["event"] == "error"
        assert "0x1017:00 = 0x03E8 (producer heartbeat every 1000 ms): read back 0x0032" in event["reason"]
        assert drive.node.nmt.state == "PRE-OPERATIONAL"


@pytest.mark.slow
def test_a_drive_at_its_defaults_is_configured_guarded_stopped_and_configured_again_after_a_reboot(
    tmp_path: Path,
) -> None:
    """The daemon configures the drive; its TPDO trips the guard and the quick stop reaches it; after a reboot
    it is configured again and the task resumes."""
    channel = f"canguard-setup-{uuid.uuid4().hex[:12]}"
    config = write_config(tmp_path, channel)
    drive = Firmware(channel)
    recorder = can.Bus(interface="virtual", channel=channel)
    daemon = Daemon(config, notifier=Notifier(env={}))
    bench = Bench(drive.node, drive.network, daemon, recorder, tmp_path / "events.jsonl", config, [])
    result: list[int] = []
    thread = threading.Thread(target=lambda: result.append(daemon.run()), name="daemon", daemon=True)
    thread.start()
    try:
        bench.wait_for(lambda: bench.controlword() == 0x000F, "enable operation received by the configured drive")
        bench.set(torque=400)  # 40 % > 35: trip
        bench.wait_event(lambda e: e["event"] == "trip", "a torque trip")
        bench.wait_for(lambda: bench.controlword() == 0x0002, "the quick stop received by the drive")
        bench.set(torque=100, status=OPERATION_ENABLED)
        bench.wait_event(lambda e: e["event"] == "recover", "the guard's recovery")

        drive.reboot()
        deadline = time.monotonic() + WAIT_S
        while sum(e["event"] == "configure" for e in bench.journal()) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert [e["source"] for e in bench.journal() if e["event"] == "configure"] == ["left", "left"]
        bench.wait_for(lambda: drive.node.nmt.state == "OPERATIONAL" and bench.controlword() == 0x000F,
                       "enable operation again after the reboot")
        assert not [e for e in bench.journal() if e["event"] == "error"]
    finally:
        daemon.request_stop("test over")
        thread.join(10)
        drive.close()
        recorder.shutdown()
    assert result == [0]
