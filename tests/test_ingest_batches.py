"""A live batch on its way in: the reader's receive stamps, several buses merged, stamps far from the clock.

The daemon's loop drains its buses (:class:`~canguard.io.bus.BusReader`), stamps each bus's messages with their
arrival (:meth:`BusReader.admit`) and hands the batch, merged by kernel stamp, to the engine as one block
(:meth:`Daemon.take_received`). These tests hold each step to what a frame taken alone gives.
"""

from __future__ import annotations

import time
import uuid
from pathlib import Path
from typing import Any

import can

from canguard.config.schema import BusConfig
from canguard.io.block import frame_from_message
from canguard.io.bus import WALL_STAMP_S, BusReader
from canguard.service.daemon import Daemon
from canguard.service.systemd import Notifier
from test_daemon import BMS_ID, bms_data, write_config


def _two_buses(doc: dict[str, Any]) -> None:
    """The battery on bus ``b``; everything else, and every frame canguard sends, on bus ``a``."""
    suffix = uuid.uuid4().hex[:12]
    doc["buses"] = {"a": {"interface": "virtual", "channel": f"ingest-a-{suffix}"},
                    "b": {"interface": "virtual", "channel": f"ingest-b-{suffix}"}}
    for name, source in doc["sources"].items():
        source["bus"] = "b" if name == "/battery_state" else "a"
    for section in (doc["task"], doc["stop"]):
        for frame in section["frames"]:
            frame["bus"] = "a"
    for frame in doc["stop"].get("escalate", []):
        frame["bus"] = "a"
    for action in doc.get("actions", {}).values():
        for frame in action["frames"]:
            frame["bus"] = "a"


class TestFrameFromMessage:
    def test_every_kind_of_message_converts_to_its_frame(self) -> None:
        """Data, extended, remote with a DLC, CAN FD, error and data-less messages keep what a frame carries."""
        msgs = [
            can.Message(timestamp=1.5, arbitration_id=0x123, data=b"\x01\x02", channel=0),
            can.Message(timestamp=1.6, arbitration_id=0x18FF50E5, data=bytes(8), is_extended_id=True),
            can.Message(timestamp=1.7, arbitration_id=0x7FF, is_remote_frame=True, dlc=4),
            can.Message(timestamp=1.8, arbitration_id=0x10, data=bytes(12), is_fd=True, bitrate_switch=True),
            can.Message(timestamp=1.9, arbitration_id=0x0, is_error_frame=True, data=b"\x04"),
            can.Message(timestamp=0.0, arbitration_id=0x20, data=None, channel="vcan1"),
        ]
        frames = [frame_from_message(m) for m in msgs]
        assert [f.channel for f in frames] == ["can0", "", "", "", "", "vcan1"]
        assert frames[0].data == b"\x01\x02" and frames[0].dlc == -1 and frames[0].t == 1.5
        assert frames[1].is_extended_id and frames[1].arbitration_id == 0x18FF50E5
        assert frames[2].is_remote_frame and frames[2].dlc == 4 and frames[2].data == b""
        assert frames[3].is_fd and frames[3].bitrate_switch and len(frames[3].data) == 12
        assert frames[4].is_error_frame and frames[5].data == b"" and frames[5].dlc == -1
        assert frame_from_message(msgs[0], "main").channel == "main"


class TestAdmit:
    def test_wall_clock_stamps_become_arrival_times_never_after_now(self) -> None:
        """A bus stamping with the wall clock: a frame that waited 50 ms in the kernel is seen as arrived 50 ms
        ago (its wait counts), one stamped in the future as arrived now; both are counted as received."""
        reader = BusReader([BusConfig(name="main", kwargs={"interface": "virtual", "channel": "unused"})])
        wall, mono = time.time(), time.monotonic()
        msgs = [can.Message(timestamp=wall - 0.05, arbitration_id=0x600, data=bytes(8)),
                can.Message(timestamp=wall + 0.2, arbitration_id=0x601, data=bytes(8))]
        out: list[tuple[str, can.Message, float]] = []
        reader.admit("main", msgs, out)
        after = time.monotonic()
        assert [(name, msg.arbitration_id, msg.timestamp) for name, msg, _ in out] == [
            ("main", 0x600, wall - 0.05), ("main", 0x601, wall + 0.2)]
        assert mono - 0.05 - 0.01 < out[0][2] < mono - 0.05 + 0.01
        assert mono <= out[1][2] <= after
        assert reader.received["main"] == 2

    def test_stamps_of_another_clock_arrive_when_received(self) -> None:
        """A bus whose stamps are not the wall clock (a device's own counter): its frames arrive when read."""
        reader = BusReader([BusConfig(name="main", kwargs={"interface": "virtual", "channel": "unused"})])
        before = time.monotonic()
        out: list[tuple[str, can.Message, float]] = []
        reader.admit("main", [can.Message(timestamp=5.0, arbitration_id=0x600, data=bytes(8))], out)
        assert before <= out[0][2] <= time.monotonic()
        assert out[0][1].timestamp == 5.0


def _interleaved(daemon: Daemon, age_s: float) -> list[tuple[str, can.Message, float]]:
    """A batch of three unconfigured frames of bus ``a`` and three BMS frames (12, 13, 14 A) of bus ``b``,
    alternating, stamped ``age_s`` ago, as the reader gives it."""
    past = time.time() - age_s
    msgs = {
        "a": [can.Message(timestamp=past + i * 1e-4, arbitration_id=0x600 + i, data=bytes(8)) for i in range(3)],
        "b": [can.Message(timestamp=past + i * 1e-4 + 5e-5, arbitration_id=BMS_ID, is_extended_id=True,
                          data=bms_data(12.0 + i)) for i in range(3)],
    }
    items: list[tuple[str, can.Message, float]] = []
    for bus, batch in msgs.items():
        daemon.reader.admit(bus, batch, items)
    items.sort(key=lambda item: item[2])
    assert [name for name, _f, _r in items] == ["a", "b"] * 3
    return items


class TestMergedBuses:
    def test_a_late_batch_of_two_buses_starts_an_overrun_and_loses_no_frame(self, tmp_path: Path) -> None:
        """Frames of two buses that waited longer than the sources allow stop the task for an overrun, and
        every frame is still counted on its own bus and decoded."""
        daemon = Daemon(write_config(tmp_path, {}, edit=_two_buses), notifier=Notifier(env={}))
        engine = daemon.engine
        try:
            engine.start(daemon.clock.now())
            assert daemon.overrun_limit_s < WALL_STAMP_S  # stamps older than the limit still read as the wall clock's
            daemon.take_received(engine, _interleaved(daemon, (daemon.overrun_limit_s + WALL_STAMP_S) / 2))
            assert "overrun" in engine.gate.inhibits
            counts = engine.decoder.per_bus
            assert (counts["a"].frames, counts["b"].frames, counts["b"].decoded) == (3, 3, 3)
        finally:
            engine.finish(reason="test over")
            daemon.journal.close()

    def test_interleaved_buses_in_one_batch_reach_their_own_bus(self, tmp_path: Path) -> None:
        """Frames of two buses merged by arrival in one batch are counted on their own bus, and the battery's
        frames on its bus feed the battery source (the last value is the battery's current)."""
        daemon = Daemon(write_config(tmp_path, {}, edit=_two_buses), notifier=Notifier(env={}))
        engine = daemon.engine
        try:
            engine.start(daemon.clock.now())
            items = _interleaved(daemon, 0.01)  # 10 ms old: merged by their stamps, in the order they alternate
            daemon.take_received(engine, items)
            counts = engine.decoder.per_bus
            assert (counts["a"].frames, counts["a"].decoded) == (3, 0)
            assert (counts["b"].frames, counts["b"].decoded) == (3, 3)
            battery = engine.ctx.health["/battery_state"]
            assert battery.value("current") == 14.0
        finally:
            engine.finish(reason="test over")
            daemon.journal.close()


class TestStamps:
    def test_a_stamp_far_from_the_clock_is_taken_as_received_now(self, tmp_path: Path) -> None:
        """A frame stamped 100 s ahead of the daemon's clock (a device's own counter) is taken at the time of its
        batch: its value reaches the source, and the latest frame time does not jump ahead."""
        bus = {"interface": "virtual", "channel": f"skew-{uuid.uuid4().hex[:12]}"}
        daemon = Daemon(write_config(tmp_path, bus), notifier=Notifier(env={}))
        engine = daemon.engine
        try:
            engine.start(daemon.clock.now())
            now = daemon.clock.now()
            msgs = [can.Message(timestamp=now, arbitration_id=BMS_ID, data=bms_data(12.0)),
                    can.Message(timestamp=now + 100.0, arbitration_id=BMS_ID, data=bms_data(13.0))]
            daemon.take_received(engine, [("main", m, time.monotonic()) for m in msgs])
            assert engine.ctx.health["/battery_state"].value("current") == 13.0
            assert now <= engine.last_frame_t < now + 1.0
        finally:
            engine.finish(reason="test over")
            daemon.journal.close()
