"""Groot2's monitor: BehaviorTree.CPP 4's Groot2 publisher protocol, read-only.

REP on PORT, PUB on PORT + 1; hooks, breakpoints and recording are refused (docs/monitor.md)."""

from __future__ import annotations

import logging
import struct
import threading
import time
from typing import Any

import zmq

from canguard.config.monitor import Address
from canguard.service.monitor.hub import ClientNotes, Hub
from canguard.service.monitor.layout import LayoutRecord

log = logging.getLogger(__name__)

PROTOCOL_ID = 2
HEADER = struct.Struct("<BBI")
"""protocol, request type, request id: ``SerializeHeader(RequestHeader)``."""
MAX_MESSAGE_BYTES = 64 * 1024
"""Largest request part taken (Groot2's are a few bytes, a BLACKBOARD's names a few hundred)."""
HANDSHAKE_MS = HEARTBEAT_MS = 5000
"""ZeroMQ's handshake limit, and heartbeat interval (three unanswered: disconnected)."""
MALFORMED = (b"wrong request header", b"must be 2 parts message", b"Request not recognized")
"""The error replies to requests that are not Groot2's (logged; a refused hook is a user's click, not logged)."""
READ_ONLY = ("canguard's Groot2 monitor is read-only: hooks, breakpoints and recording are refused, "
             "because nothing from outside may pause or change the safety loop")


class Groot2Monitor:
    """The REP / PUB sockets and the thread serving them."""

    def __init__(self, address: Address, hub: Hub) -> None:
        self.hub = hub
        self._context = zmq.Context()
        self._server = self._context.socket(zmq.REP)
        self._publisher = self._context.socket(zmq.PUB)
        for sock in (self._server, self._publisher):
            sock.setsockopt(zmq.LINGER, 0)
            sock.setsockopt(zmq.SNDTIMEO, 0)  # a reply no one takes now is dropped
            sock.setsockopt(zmq.MAXMSGSIZE, MAX_MESSAGE_BYTES)
            sock.setsockopt(zmq.HANDSHAKE_IVL, HANDSHAKE_MS)
            sock.setsockopt(zmq.HEARTBEAT_IVL, HEARTBEAT_MS)
            sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, 3 * HEARTBEAT_MS)
        self.notes = ClientNotes(log, "Groot2 monitor")
        port = self._bind(address)
        self.address = Address(address.host, port)
        """Where the REP socket listens (PUB: port + 1)."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="canguard-monitor-groot2", daemon=True)

    def _bind(self, address: Address) -> int:
        """Bind REP on the port and PUB on the next one; port 0: a free pair."""
        host = f"[{address.host}]" if ":" in address.host else address.host
        if ":" in address.host:
            for sock in (self._server, self._publisher):
                sock.setsockopt(zmq.IPV6, 1)
        for _ in range(50 if address.port == 0 else 1):
            port = address.port or self._server.bind_to_random_port(f"tcp://{host}", 20000, 60000)
            try:
                if address.port:
                    self._server.bind(f"tcp://{host}:{port}")
                self._publisher.bind(f"tcp://{host}:{port + 1}")
                return port
            except zmq.ZMQError:
                if address.port:
                    raise
                self._server.unbind(self._server.getsockopt_string(zmq.LAST_ENDPOINT))
        raise OSError(f"no free pair of ports for the Groot2 monitor on {address.host}")

    def start(self) -> None:
        """Serve in a thread of its own."""
        self._thread.start()

    def close(self) -> None:
        """Stop serving: the thread closes its sockets as it ends (never waited for longer than 2 s)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2)
        else:  # never started
            self._context.destroy(0)

    def _serve(self) -> None:
        poller = zmq.Poller()
        poller.register(self._server, zmq.POLLIN)
        try:
            while not self._stop.is_set():
                if not poller.poll(100):
                    continue
                try:
                    request = self._server.recv_multipart(zmq.NOBLOCK)
                except zmq.ZMQError:
                    continue
                try:
                    reply = self.answer(request)
                except Exception as exc:  # canguard's fault, not the client's (answer takes any bytes): say where
                    log.exception("Groot2 request failed")
                    reply = [b"error", f"{type(exc).__name__}: {exc}".encode()]
                if reply[0] == b"error" and reply[1] in MALFORMED:
                    self.notes.note(f"a malformed request ({reply[1].decode()})")
                try:
                    self._server.send_multipart(reply)
                except zmq.ZMQError as exc:
                    self.notes.note(f"a reply not sent ({exc})")
        finally:
            self._context.destroy(0)  # its sockets too: ZeroMQ sockets belong to the thread that uses them

    def answer(self, request: list[bytes]) -> list[bytes]:
        """The reply to one multipart request (the parts as the REP socket sends them)."""
        if not request or len(request[0]) != HEADER.size:
            return [b"error", b"wrong request header"]
        _protocol, kind, request_id = HEADER.unpack(request[0])
        snap = self.hub.latest
        if snap is None:
            return [b"error", b"the tree has not ticked yet"]
        layout = snap.layout
        header = HEADER.pack(PROTOCOL_ID, kind, request_id) + layout.uuid
        letter = chr(kind)
        if letter == "T":
            return [header, layout.xml.encode()]
        if letter == "S":
            return [header, b"".join(struct.pack("<HB", uid, code) for uid, code in enumerate(snap.codes, 1))]
        if letter == "B":
            if len(request) != 2:
                return [b"error", b"must be 2 parts message"]
            return [header, self._blackboards(layout, request[1].decode("utf-8", "replace"))]
        if letter == "D":
            return [header, b"[]"]
        if letter in "AX":
            return [header]
        if letter in "IRUNrt":
            return [b"error", READ_ONLY.encode()]
        return [b"error", b"Request not recognized"]

    def _root_entries(self) -> dict[str, Any]:
        """The root blackboard as the engine's next snapshots carry it once asked for (waits up to 0.3 s)."""
        self.hub.want_blackboard()
        deadline = time.monotonic() + 0.3
        while True:
            snap = self.hub.latest
            if snap is not None and snap.blackboard is not None:
                return dict(snap.blackboard)
            if time.monotonic() > deadline or self._stop.wait(0.01):
                return {}

    def _blackboards(self, layout: LayoutRecord, names: str) -> bytes:
        """MessagePack of the asked blackboards that exist: the main tree's is the root blackboard."""
        import msgpack

        wanted = [n for n in names.split(";") if n]
        out: dict[str, Any] = {}
        if layout.main_id in wanted:
            out[layout.main_id] = self._root_entries()
        for path in layout.paths:
            if path in wanted:
                out[path] = {}  # a subtree's entries are remapped onto the root's (see docs)
        packed: bytes = msgpack.packb(out)
        return packed
