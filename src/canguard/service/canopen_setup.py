"""``configure: true``: canguard gives a CANopen drive what its config expects, over SDO.

At start and at each boot-up (docs/config.md); a write that fails is an ``error`` event and the drive stays
pre-operational (fail safe).
"""

from __future__ import annotations

import functools
import logging
import queue
import threading
from collections.abc import Iterable
from typing import Any

from canguard.config.canopen import HEARTBEAT_BASE, CanopenDrive, SdoWrite
from canguard.config.schema import BusConfig
from canguard.errors import CanguardError
from canguard.io.bus import open_bus

log = logging.getLogger(__name__)

SDO_RESPONSE_BASE = 0x580
NMT_PRE_OPERATIONAL, NMT_START = 0x80, 0x01
BOOT_UP = 0x00  # the NMT state byte of a boot-up message
NOTIFIER_CYCLE_S = 0.1
"""How long the library's receive thread waits per read: what stopping it may take (its default is 1 s)."""


def read_back(writes: Iterable[SdoWrite]) -> list[SdoWrite]:
    """The writes to compare after configuring: the last checked write of each object, in order."""
    last: dict[tuple[int, int], SdoWrite] = {}
    for w in writes:
        if w.check:
            last.pop((w.index, w.subindex), None)
            last[(w.index, w.subindex)] = w
    return list(last.values())


class DriveSetup:
    """Configures the drives of one config that have ``configure: true`` (see the module docstring)."""

    def __init__(self, drives: Iterable[CanopenDrive], buses: dict[str, BusConfig]) -> None:
        self.drives = {d.name: d for d in drives if d.configure}
        self.buses = {d.bus: buses[d.bus] for d in self.drives.values()}
        self._networks: list[Any] = []
        self._nodes: dict[str, Any] = {}
        self._jobs: queue.SimpleQueue[str | None] = queue.SimpleQueue()
        self._pending: set[str] = set()
        self._lock = threading.Lock()
        self._events: queue.SimpleQueue[dict[str, Any]] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Open a bus per drive bus, listen for boot-ups, and configure every drive (in the background)."""
        import canopen

        for bus_name, bus_cfg in self.buses.items():
            drives = [d for d in self.drives.values() if d.bus == bus_name]
            filters = [{"can_id": base + d.node, "can_mask": 0x7FF}
                       for d in drives for base in (SDO_RESPONSE_BASE, HEARTBEAT_BASE)]
            try:
                bus = open_bus(BusConfig(bus_name, {**bus_cfg.kwargs, "can_filters": filters}))
            except CanguardError as exc:
                for drive in drives:
                    self._events.put(_failed(drive, str(exc)))
                continue
            network = canopen.Network(bus)
            network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
            network.connect()
            self._networks.append(network)
            for drive in drives:
                node = canopen.RemoteNode(drive.node, canopen.ObjectDictionary())
                network.add_node(node)
                node.nmt.add_heartbeat_callback(functools.partial(self._heard, drive.name))
                self._nodes[drive.name] = node
        self._thread = threading.Thread(target=self._run, name="canopen-setup", daemon=True)
        self._thread.start()
        for name in self._nodes:
            self.request(name)

    def _heard(self, name: str, state: int) -> None:
        if state == BOOT_UP:  # the drive rebooted: what it was told is gone
            self.request(name)

    def request(self, name: str) -> None:
        """Configure drive ``name`` again (once, however often it is asked before the thread gets to it)."""
        with self._lock:
            if name in self._pending:
                return
            self._pending.add(name)
        self._jobs.put(name)

    def stop(self) -> None:
        """End the thread and close the buses."""
        if self._thread is not None:
            self._jobs.put(None)
            self._thread.join(5.0)
            self._thread = None
        for network in self._networks:
            network.disconnect()
        self._networks.clear()

    def events(self) -> list[dict[str, Any]]:
        """The ``configure`` and ``error`` events since the last call (the daemon journals them)."""
        return [self._events.get_nowait() for _ in range(self._events.qsize())]

    def _run(self) -> None:
        while (name := self._jobs.get()) is not None:
            with self._lock:
                self._pending.discard(name)
            event = self.configure(self.drives[name], self._nodes[name])
            (log.info if event["event"] == "configure" else log.error)("%s", event["reason"])
            self._events.put(event)

    @staticmethod
    def configure(drive: CanopenDrive, node: Any) -> dict[str, Any]:
        """Configure ``drive`` through ``node`` (a canopen ``RemoteNode``): the event that says how it went."""
        from canopen.sdo.exceptions import SdoAbortedError, SdoError

        step: SdoWrite | None = None
        try:
            node.nmt.send_command(NMT_PRE_OPERATIONAL)
            for step in drive.setup:
                node.sdo.download(step.index, step.subindex, step.data)
            checks = read_back(drive.setup)
            for step in checks:
                got = int.from_bytes(node.sdo.upload(step.index, step.subindex), "little")
                if got != step.value:
                    return _failed(drive, f"{step.describe()}: read back 0x{got:0{step.size * 2}X}")
            node.nmt.send_command(NMT_START)
        except (SdoError, OSError) as exc:  # refused, no answer (timeout), a bus that failed
            what = step.describe() if step is not None else "SDO"
            if isinstance(exc, SdoAbortedError):
                return _failed(drive, f"{what}: refused by the drive (SDO abort 0x{exc.code:08X}: {exc})")
            return _failed(drive, f"{what}: {type(exc).__name__}: {exc}")
        return {"event": "configure", "source": drive.name,
                "reason": f"node {drive.node} configured over SDO ({len(drive.setup)} writes, {len(checks)} read "
                          "back) and started"}


def _failed(drive: CanopenDrive, why: str) -> dict[str, Any]:
    return {"event": "error", "source": drive.name,
            "reason": f"configure {drive.name} (node {drive.node}): {why}; the drive is left pre-operational "
                      "(its sources not_present)"}
