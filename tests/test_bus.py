"""Tests of canguard.io.bus: opening buses, receiving into the queue, reopening, sending."""

from __future__ import annotations

import itertools
import logging
import os
import re
import struct
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import can
import pytest
import yaml

from canguard.config.loader import load_config
from canguard.config.schema import BusConfig
from canguard.errors import BusError
from canguard.io.block import EXT_KEY, frame_from_message
from canguard.io.bus import KERNEL_FILTERS_MAX, BusReader, kernel_filters, open_bus, receive_keys
from canguard.io.frame import Frame
from checkout import REPO, SRC
from test_canopen_config import config as canopen_config
from test_daemon import unique_udp
from waitkit import wait_until


def virtual(name: str = "main") -> BusConfig:
    """A virtual bus on a channel no other test uses."""
    return BusConfig(name=name, kwargs={"interface": "virtual", "channel": f"t-{uuid.uuid4().hex}"})


def frames_from(reader: BusReader, n: int) -> list[tuple[str, Frame]]:
    """The next ``n`` frames on the reader's queue, as soon as they are there."""
    out: list[tuple[str, Frame]] = []

    def enough() -> bool:
        out.extend((name, frame_from_message(msg, name)) for name, msg, _received in reader.receive(0.05, n - len(out)))
        return len(out) >= n

    wait_until(enough, what=f"{n} frames on the reader's queue")
    return out


class TestOpenBus:
    """open_bus passes the config to python-can and names the bus at fault."""

    def test_opens_virtual_bus(self) -> None:
        """A virtual bus config opens into a python-can bus."""
        bus = open_bus(virtual())
        try:
            assert isinstance(bus, can.BusABC)
        finally:
            bus.shutdown()

    def test_failure_names_bus_and_interface(self) -> None:
        """An interface that does not exist gives a BusError naming the bus and the interface, chained."""
        cfg = BusConfig(name="drives", kwargs={"interface": "nosuchiface", "channel": "can7"})
        with pytest.raises(BusError, match=r"bus 'drives' \(interface nosuchiface, channel can7\)") as info:
            open_bus(cfg)
        assert info.value.__cause__ is not None


class TestBusReader:
    """BusReader receives every frame with its timestamp, reopens after errors, and sends without raising."""

    def test_virtual_round_trip(self) -> None:
        """Frames sent by a peer arrive as Frames on the queue with the bus name, timestamp and payload."""
        cfg = virtual("main")
        peer = can.Bus(**cfg.kwargs)
        try:
            with BusReader([cfg]) as reader:
                sent = [
                    can.Message(arbitration_id=0x14, data=bytes(range(8)), is_extended_id=False),
                    can.Message(arbitration_id=0x18FF50E5, data=b"\x01\x02", is_extended_id=True),
                    can.Message(arbitration_id=0x21, is_remote_frame=True, dlc=4, is_extended_id=False),
                ]
                for m in sent:
                    m.timestamp = time.time()
                    peer.send(m)
                got = frames_from(reader, 3)
                assert [bus for bus, _ in got] == ["main"] * 3
                frames = [f for _, f in got]
                assert [(f.arbitration_id, f.data, f.is_extended_id) for f in frames] == [
                    (0x14, bytes(range(8)), False),
                    (0x18FF50E5, b"\x01\x02", True),
                    (0x21, b"", False),
                ]
                assert frames[2].is_remote_frame and frames[2].dlc == 4
                assert all(f.channel == "main" for f in frames)
                assert all(abs(f.t - time.time()) < 5 for f in frames)
                assert reader.received["main"] == 3
        finally:
            peer.shutdown()

    def test_send_reaches_peer_and_failures_are_counted(self) -> None:
        """send() delivers to a peer; sending on an unknown bus returns False and is counted, not raised."""
        cfg = virtual("main")
        peer = can.Bus(**cfg.kwargs)
        try:
            with BusReader({"main": cfg}) as reader:
                assert reader.send("main", can.Message(arbitration_id=0x02, data=b"", is_extended_id=False))
                msg = peer.recv(2.0)
                assert msg is not None and msg.arbitration_id == 0x02
                assert reader.send("nope", can.Message(arbitration_id=0x02)) is False
                assert reader.sent["main"] == 1 and reader.send_failures["nope"] == 1
        finally:
            peer.shutdown()

    def test_no_frame_lost_under_a_burst(self) -> None:
        """A burst of 5000 frames sent while nobody drains the queue all arrive, in order."""
        cfg = virtual("main")
        peer = can.Bus(**cfg.kwargs)
        try:
            with BusReader([cfg]) as reader:
                for i in range(5000):
                    peer.send(
                        can.Message(arbitration_id=0x100, data=i.to_bytes(4, "little"), is_extended_id=False)
                    )
                got = frames_from(reader, 5000)
                assert [int.from_bytes(f.data, "little") for _, f in got] == list(range(5000))
        finally:
            peer.shutdown()

    def test_reopens_after_recv_error(self, caplog: pytest.LogCaptureFixture) -> None:
        """A recv error is logged, reported via on_error, and the bus is reopened and receives again."""
        cfg = virtual("main")
        opened: list[can.BusABC] = []

        def opener(c: BusConfig) -> can.BusABC:
            bus = open_bus(c)
            if not opened:  # the first bus breaks on its first recv

                def broken(timeout: float | None = None) -> can.Message | None:
                    raise can.CanOperationError("device went away")

                bus.recv = broken  # type: ignore[method-assign]
            opened.append(bus)
            return bus

        errors: list[tuple[str, BaseException]] = []
        peer = can.Bus(**cfg.kwargs)
        caplog.set_level(logging.ERROR, logger="canguard.io.bus")
        reader = BusReader(
            [cfg], on_error=lambda n, e: errors.append((n, e)), opener=opener, backoff_min_s=0.01
        )
        try:
            reader.start()
            wait_until(lambda: reader.reopens["main"] >= 1, what="the bus reopened")
            assert reader.reopens["main"] == 1
            peer.send(can.Message(arbitration_id=0x14, data=b"\x00" * 8, is_extended_id=False))
            got = frames_from(reader, 1)
            assert [f.arbitration_id for _, f in got] == [0x14]
            assert [(n, str(e)) for n, e in errors] == [("main", "device went away")]
            assert "bus main (virtual, channel" in caplog.text and "device went away" in caplog.text
            assert reader.alive() == {"main": True}
        finally:
            reader.stop()
            peer.shutdown()
        assert reader.alive() == {"main": False}

    def test_reopen_backs_off_while_the_bus_stays_away(self, caplog: pytest.LogCaptureFixture) -> None:
        """While reopening keeps failing, attempts are spaced by a delay that doubles up to its cap (the waits are
        at least that long; the log says the delay, capped), and stop() still returns."""
        cfg = virtual("main")
        attempts: list[float] = []
        first = threading.Event()

        def opener(c: BusConfig) -> can.BusABC:
            if not first.is_set():
                first.set()
                bus = open_bus(c)

                def broken(timeout: float | None = None) -> can.Message | None:
                    raise OSError("ENODEV")

                bus.recv = broken  # type: ignore[method-assign]
                return bus
            attempts.append(time.monotonic())
            raise BusError("still gone")

        reader = BusReader([cfg], opener=opener, backoff_min_s=0.02, backoff_max_s=0.16)
        reader.start()
        wait_until(lambda: len(attempts) >= 6, what="six attempts to reopen")  # the delay reaches its cap
        t0 = time.monotonic()
        reader.stop()
        assert time.monotonic() - t0 < 1.0
        gaps = [b - a for a, b in itertools.pairwise(attempts)]
        delays = [0.04, 0.08, 0.16, 0.16, 0.16]  # each wait after a failed attempt: doubled, capped at 0.16 s
        assert all(gap >= delay - 0.005 for gap, delay in zip(gaps, delays, strict=False))  # later on a loaded machine
        said = [float(d) for d in re.findall(r"reopen failed \(still gone\); retrying in ([0-9.]+) s", caplog.text)]
        assert len(said) >= 6 and max(said) == said[-1] == 0.2  # 0.16 s to one decimal: never more (0.3, 0.6...)

    def test_start_failure_closes_opened_buses(self) -> None:
        """When the second bus does not open, start() raises BusError and the first bus is shut down."""
        good = virtual("good")
        bad = BusConfig(name="bad", kwargs={"interface": "nosuchiface"})
        reader = BusReader([good, bad])
        with pytest.raises(BusError, match="'bad'"):
            reader.start()
        assert reader.alive() == {"good": False, "bad": False}


PEER = """
import sys, time, can
bus = can.Bus(interface="udp_multicast", channel=sys.argv[1], port=int(sys.argv[2]))
for i in range(20):
    bus.send(can.Message(arbitration_id=0x18FF50E5, data=bytes([i] * 8), is_extended_id=True))
deadline = time.monotonic() + 5.0
reply = None
while time.monotonic() < deadline:  # multicast loops our own frames back: wait for the reply's id
    msg = bus.recv(0.5)
    if msg is not None and msg.arbitration_id == 0x02:
        reply = msg
        break
print(hex(reply.arbitration_id) if reply else "none", flush=True)
bus.shutdown()
"""


class TestUdpMulticast:
    """Two processes exchange frames over python-can's udp_multicast bus."""

    @pytest.mark.slow
    def test_round_trip_between_processes(self) -> None:
        """20 frames from a peer process arrive in order; a frame sent back reaches the peer."""
        pytest.importorskip("msgpack")
        udp = unique_udp()
        group, port = udp["channel"], udp["port"]
        cfg = BusConfig(name="udp", kwargs=udp)
        with BusReader([cfg]) as reader:
            peer = subprocess.Popen(
                [sys.executable, "-c", PEER, group, str(port)],
                stdout=subprocess.PIPE,
                text=True,
                env={**os.environ, "PYTHONPATH": str(SRC)},
            )
            try:
                got = frames_from(reader, 20)
                assert [f.data[0] for _, f in got] == list(range(20))
                assert all(f.is_extended_id and f.arbitration_id == 0x18FF50E5 for _, f in got)
                assert reader.send("udp", can.Message(arbitration_id=0x02, data=b"", is_extended_id=False))
                out, _ = peer.communicate(timeout=10)
            finally:
                if peer.poll() is None:
                    peer.kill()
        assert out.strip() == "0x2"


class TestReceiveFilters:
    """Each bus receives the frames the config reads: SocketCAN's kernel filters, canguard's check elsewhere."""

    KEYS = frozenset({0x74, 0x18FF50E5 + EXT_KEY, 0x282, 0x702, 0x82})
    """A DBC current (0x74), the extended BMS id, a CANopen drive's TPDO2, heartbeat and EMCY (node 2)."""

    def test_the_keys_are_the_ids_the_config_reads(self, tmp_path: Path) -> None:
        """Standard, extended and CANopen ids of every source; none with ``filter: false``."""
        path = canopen_config(tmp_path, dbc=[str(REPO / "dbc" / "robot.dbc")])
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
        doc["sources"]["axis3"] = {"kind": "current", "message": "Axis3_Get_Iq", "signal": "Iq_Measured"}
        doc["sources"]["bms"] = {"kind": "battery", "message": "BMS_Status", "current": "Pack_Current"}
        path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        assert receive_keys(load_config(path)) == {"main": self.KEYS}
        doc["buses"]["main"]["filter"] = False
        path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        cfg = load_config(path)
        assert receive_keys(cfg) == {"main": None}
        assert "filter" not in cfg.buses["main"].kwargs  # never handed to can.Bus

    def test_the_kernel_passes_exactly_the_configured_frames(self) -> None:
        """The filters as SocketCAN packs and matches them pass those ids in their own frame format only."""
        from can.interfaces.socketcan.constants import CAN_EFF_FLAG
        from can.interfaces.socketcan.utils import pack_filters

        packed = pack_filters(kernel_filters(self.KEYS))
        words = struct.unpack(f"={len(packed) // 4}I", packed)
        pairs = list(zip(words[::2], words[1::2], strict=True))

        def passes(cid: int, extended: bool) -> bool:
            word = cid | (CAN_EFF_FLAG if extended else 0)
            return any(word & mask == fid & mask for fid, mask in pairs)

        candidates = [(cid, ext) for cid in range(0x800) for ext in (False, True)]
        candidates += [(0x18FF50E5, True), (0x18FF50E5 ^ 1, True), (0x18FF50E5 | 1 << 28, True), (0x1FFFFFFF, True)]
        passed = {cid + EXT_KEY if ext else cid for cid, ext in candidates if passes(cid, ext)}
        assert passed == self.KEYS

    def test_a_socketcan_bus_gets_the_kernel_filters(self) -> None:
        """On a SocketCAN bus the reader sets python-can's filters, anew after a reload; past the kernel's limit
        none (canguard's own check then)."""
        opened: list[can.BusABC] = []
        cfg = BusConfig("main", {"interface": "socketcan", "channel": "can0"})

        def opener(_cfg: BusConfig) -> can.BusABC:
            opened.append(can.Bus(interface="virtual", channel=f"t-{uuid.uuid4().hex}"))
            return opened[-1]

        with BusReader([cfg], opener=opener, wanted={"main": self.KEYS}) as reader:
            assert opened[0].filters == kernel_filters(self.KEYS)
            reader.want({"main": frozenset({0x74})})
            assert opened[0].filters == [{"can_id": 0x74, "can_mask": 0x7FF, "extended": False}]
            reader.want({"main": frozenset(range(KERNEL_FILTERS_MAX + 1))})
            assert opened[0].filters is None

    def test_foreign_frames_are_dropped_and_error_frames_kept(self) -> None:
        """A bus with canguard's check (no kernel filters) gives its configured and error frames only."""
        cfg = virtual()
        peer = can.Bus(**cfg.kwargs)
        try:
            with BusReader([cfg], wanted={"main": frozenset({0x74, 0x123 + EXT_KEY})}) as reader:
                wait_until(lambda: all(reader.alive().values()), what="the receive thread")
                for cid, ext, err in [(0x600, False, False), (0x123, False, False), (0x74, True, False),
                                      (0x74, False, False), (0x4, False, True), (0x123, True, False)]:
                    peer.send(can.Message(arbitration_id=cid, is_extended_id=ext, is_error_frame=err, data=b"\1"))
                got = [(f.arbitration_id, f.is_extended_id, f.is_error_frame) for _name, f in frames_from(reader, 3)]
                assert got == [(0x74, False, False), (0x4, False, True), (0x123, True, False)]
                assert reader.received["main"] == 3
        finally:
            peer.shutdown()
