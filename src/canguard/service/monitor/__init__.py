"""Watching the daemon live: the status page (:mod:`.web`) and Groot2's monitor (:mod:`.groot2`).

Served by a process of their own (:mod:`.server`), fed by :class:`Monitor` after each tick without ever waiting
(docs/monitor.md), over one ``AF_UNIX`` ``SOCK_SEQPACKET`` pair (a message whole or not at all). Daemon → monitor:
pickled messages in frames of :data:`FRAME_BYTES` (flag byte ``M`` more / ``E`` end). Monitor → daemon: fixed byte
strings and one JSON answer: the daemon never unpickles what comes from the side the network can reach.
"""

from __future__ import annotations

import ctypes
import errno
import json
import logging
import math
import os
import pickle
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import py_trees

from canguard.bt.dryrun import root_blackboard
from canguard.config.monitor import Address
from canguard.config.schema import MonitorConfig
from canguard.errors import ConfigError
from canguard.service.monitor.layout import LayoutRecord, TreeLayout

if TYPE_CHECKING:
    from canguard.bt.loaded import GuardView
    from canguard.engine.core import Engine
    from canguard.engine.stats import EventSink

log = logging.getLogger(__name__)

KEEP_EVENTS = 500
"""Journal events kept for a monitor process that is behind; past that the oldest are dropped (it says how many)."""
START_TIMEOUT_S = 30.0
"""How long the daemon waits at start for its monitor process to listen (a loaded robot takes seconds)."""
BLACKBOARD_S = 1.0
"""How long a Groot2 request for the blackboard puts it in the records."""
REQUESTS_S = 0.1
"""How often the hand-over also reads the monitor process's requests (Groot2 waits 0.3 s for a blackboard)."""
PERIOD_S = 0.02
"""Shortest time between two records (Groot2 polls STATUS at up to 50 Hz)."""
GUARD_PERIOD_S = 0.08
"""Longest time between two readings of the guards' values while nothing else changes."""

IDLE, RUNNING, SUCCESS, FAILURE, SKIPPED = 0, 1, 2, 3, 4
"""BehaviorTree.CPP's ``NodeStatus`` values (Groot2's STATUS carries them; ``10 + s``: idle after ``s``)."""
STATUS_NAMES = ("IDLE", "RUNNING", "SUCCESS", "FAILURE", "SKIPPED")
_CODES = {py_trees.common.Status.RUNNING: RUNNING, py_trees.common.Status.SUCCESS: SUCCESS,
          py_trees.common.Status.FAILURE: FAILURE}


FRAME_BYTES = 32 * 1024
"""Largest frame (a seqpacket message must fit the socket's send buffer, 208 kB by default on Linux)."""
SEND_BUFFER_BYTES = 1 << 20
"""Send buffer asked for (Linux caps it at ``net.core.wmem_max``)."""
MORE, END = b"M", b"E"
WANT_BLACKBOARD = b"B"
"""Monitor process → daemon: a Groot2 client asked for the blackboard (put it in the records for 1 s)."""


class GilHoldingSocket:
    """Non-blocking send and receive that keep the GIL (``socket.send`` releases it, then the loop waits for it)."""

    _libc = ctypes.PyDLL(None, use_errno=True)
    _send = _libc.send
    _send.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_size_t, ctypes.c_int)
    _send.restype = ctypes.c_ssize_t
    _recv = _libc.recv
    _recv.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_size_t, ctypes.c_int)
    _recv.restype = ctypes.c_ssize_t

    def __init__(self, sock: socket.socket) -> None:
        self._fd = sock.fileno()
        self._buf = ctypes.create_string_buffer(64)

    def send(self, data: bytes) -> bool:
        """Send one message whole; False when the socket cannot take it now. OSError when the other end is gone."""
        return self._send(self._fd, data, len(data), socket.MSG_DONTWAIT | socket.MSG_NOSIGNAL) >= 0 or _again()

    def recv(self) -> bytes | None:
        """One short message (at most 64 bytes), b"" when the other end closed, None when none waits."""
        n = self._recv(self._fd, self._buf, len(self._buf), socket.MSG_DONTWAIT)
        if n >= 0:
            return self._buf.raw[:n]
        _again()
        return None


def _again() -> bool:
    """False for ``EAGAIN`` (nothing done, try later); OSError for any other error of the call just made."""
    code = ctypes.get_errno()
    if code in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR):
        return False
    raise OSError(code, os.strerror(code))


def socket_pair() -> tuple[socket.socket, socket.socket]:
    """(the daemon's end, the monitor process's end); neither is inherited by other children."""
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    for sock in (ours, theirs):
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
    return ours, theirs


def frames(message: Any) -> list[bytes]:
    """``message`` pickled and cut into frames (one for all but the largest messages)."""
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    size = FRAME_BYTES - 1
    parts = [data[i:i + size] for i in range(0, len(data), size)] or [b""]
    return [MORE + p for p in parts[:-1]] + [END + parts[-1]]


class Monitor:
    """The monitor process of one daemon, observer of each engine it runs, and the sink its engines write events to:
    ``journal`` first, then a copy for the monitors. ConfigError when a server cannot listen."""

    def __init__(self, settings: MonitorConfig, journal: EventSink) -> None:
        self._sock, theirs = socket_pair()
        try:
            self._proc = _spawn(theirs)
        finally:
            theirs.close()
        self.http: Address | None = None
        """Where the status page listens (the port the system gave for port 0), when served."""
        self.groot2: Address | None = None
        """Where Groot2's REP socket listens (PUB: port + 1), when served."""
        try:
            self._start(settings)
        except BaseException:
            self.close()
            raise
        self._sock.setblocking(False)
        self._io = GilHoldingSocket(self._sock)  # the engine's thread never lets go of the GIL for it
        self._tree: TreeLayout | None = None  # the engine's (attach sets what is read of it)
        self._seq = 0
        # what the monitor process has (or is being sent), and what it has not had yet
        self._record: tuple[Any, ...] | None = None
        self._sent: tuple[Any, ...] | None = None
        self._layout: LayoutRecord | None = None
        self._guards: tuple[tuple[Any, ...], ...] | None = None
        self._journal = journal
        self._events: deque[tuple[int, dict[str, Any]]] = deque(maxlen=KEEP_EVENTS)
        self._event_seq = 0
        self._outbox: deque[bytes] = deque()  # the frames of a large message not all taken yet: they go first
        self._blackboard_until = -1.0
        self._closing = self._failed = self._gone = False
        self._requests_at = 0.0

    def _start(self, settings: MonitorConfig) -> None:
        """Tell the process what to serve; wait until it listens (its addresses) or says why it cannot."""
        self._sock.sendall(json.dumps({"http": settings.http, "groot2": settings.groot2,
                                       "token": settings.token}).encode())  # never on its command line
        self._sock.settimeout(START_TIMEOUT_S)
        try:
            data = self._sock.recv(65536)
        except TimeoutError:
            raise ConfigError(f"monitor: the monitor process did not start within {START_TIMEOUT_S:.0f} s") from None
        if not data:
            code = self._proc.wait(5)
            raise ConfigError(f"monitor: the monitor process ended at start (exit code {code}; its error is above)")
        doc = json.loads(data.decode())
        if not isinstance(doc, dict) or not ({"ready", "error"} & set(doc)):
            raise ValueError(f"not a start answer: {data[:80]!r}")
        if "error" in doc:
            raise ConfigError(str(doc["error"]))
        ready = doc["ready"]
        self.http = Address(*ready["http"]) if ready.get("http") else None
        self.groot2 = Address(*ready["groot2"]) if ready.get("groot2") else None

    def start(self) -> None:
        """Say where the monitors listen (and that a page on the network needs its token)."""
        if self.http is not None:
            if self.http.loopback:
                log.warning("status page on http://%s/ (this machine only)", self.http)
            else:
                log.warning("status page on http://%s/ reachable from the network: every request needs "
                            "'Authorization: Bearer <monitor.token>' (or ?token=<monitor.token>)", self.http)
        if self.groot2 is not None:
            where = "this machine only" if self.groot2.loopback else "reachable from the network, read-only, no token"
            log.warning("Groot2 monitor on %s (REP %d, PUB %d; %s)", self.groot2, self.groot2.port,
                        self.groot2.port + 1, where)

    def attach(self, engine: Engine) -> None:
        """Watch ``engine`` from its next tick on (the daemon's engine at start and after each reload)."""
        tree = TreeLayout(engine.loaded, engine.ctx)
        self._tree, self._guard_views, self._guard_nodes = tree, engine.guards(), engine.loaded.guard_nodes()
        self._last_active = [IDLE] * len(tree.behaviours)
        self._key: tuple[Any, ...] = ()
        self._guard_states: tuple[tuple[Any, ...], ...] = ()
        self._guards_at = self._next_at = -math.inf
        self._stops, self._record = -1, None
        self._stopped_by: tuple[str, ...] = ()
        engine.observer = self

    def close(self) -> None:
        """End the monitor process (it also ends by itself when the daemon's end of the socket closes)."""
        self._closing = True
        self._gone = True  # nothing is sent on the descriptor once closed (the system may reuse its number)
        self._sock.close()
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(2)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(2)

    @property
    def pid(self) -> int:
        """The monitor process's id."""
        return self._proc.pid

    # -- the engine's side: after its tick (the stop frames are out), never waiting -----------------
    def write(self, event: Mapping[str, Any]) -> None:
        """Append ``event`` to the journal, then keep a copy for the next record."""
        self._journal.write(event)
        self._event_seq += 1
        self._events.append((self._event_seq, dict(event)))

    def flush(self) -> None:
        """Flush the journal."""
        self._journal.flush()

    def publish(self, engine: Engine, now: float) -> None:
        """After each tick: a record when something changed, offered to the monitor process (never raises or waits)."""
        try:
            if self._take(engine, now):
                self.offer()
        except Exception:  # a monitor must never take the loop down with it (a record that cannot be pickled)
            if not self._failed:
                log.exception("monitor snapshot failed; the monitors show the last good one")
            self._failed = True
            self._events.clear()
            self._sent = self._record  # dropped: the next one goes

    def _take(self, engine: Engine, now: float) -> bool:
        """This tick's record, when something changed; False when the next one is not due yet."""
        gate = engine.gate
        if gate.stops != self._stops:  # read in the tick the stop began, however soon the next record is due
            self._stops = gate.stops
            self._stopped_by = self._failing()
        mono = time.monotonic()
        if mono < self._next_at or self._tree is None:  # the one bound on what the monitors cost the loop
            return False
        codes = self._codes(self._tree)
        key = (codes, gate.state, gate.stops, engine.journal.written, gate.stop_reason)
        stale = mono - self._guards_at >= GUARD_PERIOD_S
        if key == self._key and not stale:
            return True  # nothing new: what the monitor process could not take before goes now
        if stale:  # a node's status or an event in between: published at once, with the guards as last read
            self._guard_states = tuple(self._guard_state(engine, g, now) for g in self._guard_views)
            self._guards_at = mono
        self._next_at = mono + PERIOD_S
        self._key = key
        self._seq += 1
        task = (gate.state, gate.stop_since, gate.stop_reason, gate.stops, tuple(gate.inhibits.items()),
                self._failing(), self._stopped_by)  # as hub.task_document reads it
        blackboard = root_blackboard() if time.monotonic() < self._blackboard_until else None
        self._record = (self._seq, now, codes, task, engine.cfg.stop.confirm is not None, blackboard)
        return True

    def _failing(self) -> tuple[str, ...]:
        """The guard nodes that failed in the tick just done."""
        return tuple(g.name for g in self._guard_nodes if g.status == py_trees.common.Status.FAILURE)

    def _codes(self, tree: TreeLayout) -> bytes:
        out = bytearray()
        last = self._last_active
        for i, node in enumerate(tree.behaviours):
            code = SKIPPED if getattr(node, "skipped", False) else _CODES.get(node.status, IDLE)
            if code != IDLE:
                last[i] = code
            elif last[i] != IDLE:
                code = 10 + last[i]  # BT.CPP: IDLE after SUCCESS is 12
            out.append(code)
        return bytes(out)

    @staticmethod
    def _guard_state(engine: Engine, g: GuardView, now: float) -> tuple[Any, ...]:
        """One guarded signal now, as :func:`.hub.guard_document` reads it."""
        snap = g.snapshot()
        health = engine.ctx.health.get(g.source)
        why = health.reason(now, g.role) if health is not None else "no_data"
        value = snap.threshold * snap.level_pct / 100.0 if g.kind == "i2t" else snap.value
        status = why or ("tripped" if snap.tripped else "ok")
        return (g.node, g.role, g.kind, g.source, value, g.threshold_unit, snap.threshold, snap.level_pct, status,
                why or snap.reason)

    # -- sending -----------------------------------------------------------------------------------
    def offer(self) -> None:
        """Offer what the monitor process has not had yet, never waiting (a dead one is reported by a thread)."""
        if self._gone or (self._record is self._sent and not self._events and not self._outbox):
            return
        try:
            now = time.monotonic()
            if now >= self._requests_at:
                self._requests_at = now + REQUESTS_S
                self._read_requests()
            self._send()
        except OSError as exc:
            self._gone = True
            if not self._closing:
                threading.Thread(target=self._died, args=(exc,), name="canguard-monitor-gone", daemon=True).start()

    def _send(self) -> None:
        """Offer the layout (once per tree), then the events and latest record; what is not taken waits for later."""
        if not self._send_outbox():  # the rest of a large message first
            return
        record = self._record
        layout = None if self._tree is None else self._tree.record
        if record is not None and layout is not self._layout:
            if not self._offer(frames(("layout", layout))):
                return
            self._layout = layout  # once per tree: the monitor process keeps it
            self._guards = None
        if record is self._sent and not self._events:
            return
        events = list(self._events)
        guards = self._guard_states  # the guards only when new (their tuple is kept between readings)
        if record is not None:
            record = (*record, None if guards is self._guards else guards)
        if self._offer(frames(("tick", events, record))):
            for _ in events:
                self._events.popleft()
            self._sent = self._record
            self._guards = guards if record is not None else None

    def _offer(self, frames: list[bytes]) -> bool:
        """Send one message (the rest of a large one as the socket takes it); False: nothing of it was taken."""
        if not self._send_outbox() or not self._io.send(frames[0]):
            return False  # the monitor process is behind: this record is dropped, the next one is newer
        self._outbox.extend(frames[1:])
        self._send_outbox()
        return True

    def _send_outbox(self) -> bool:
        """Send the frames waiting, in order; False when the socket cannot take more now."""
        while self._outbox:
            if not self._io.send(self._outbox[0]):
                return False
            self._outbox.popleft()
        return True

    def _read_requests(self) -> None:
        """Take the monitor process's requests (a Groot2 client wants the blackboard); never waits."""
        while (data := self._io.recv()) is not None:
            if not data:
                raise ConnectionResetError(errno.ECONNRESET, "the monitor process closed its socket")
            if data == WANT_BLACKBOARD:
                self._blackboard_until = time.monotonic() + BLACKBOARD_S

    def _died(self, exc: OSError) -> None:
        """The monitor process is gone: say so once; the guard goes on (a thread of its own, started once)."""
        try:
            code: int | None = self._proc.wait(1)  # its socket closes a moment before it can be reaped
        except subprocess.TimeoutExpired:
            code = None
        log.error("the monitor process (pid %d) %s (%s): the status page and Groot2's monitor are gone; "
                  "the guard goes on", self._proc.pid,
                  "is not answering" if code is None else f"ended with exit code {code}", exc)


def _spawn(theirs: Any) -> subprocess.Popen[bytes]:
    """``python -m canguard.service.monitor.server FD``, finding this canguard whatever sys.path the daemon has."""
    import canguard

    env = dict(os.environ)
    here = str(Path(canguard.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (here, env.get("PYTHONPATH", "")) if p)
    env.pop("NOTIFY_SOCKET", None)  # systemd's messages are the daemon's to send
    env.pop("WATCHDOG_USEC", None)
    return subprocess.Popen([sys.executable, "-m", "canguard.service.monitor.server", str(theirs.fileno())],
                            pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL, env=env)
