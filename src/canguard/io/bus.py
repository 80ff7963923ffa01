"""Open the configured python-can buses and receive from them without losing frames.

:meth:`BusReader.receive` gives ``(bus_name, message, received)`` in arrival order, one of two ways:
- **Direct** (``direct=True``, every bus a socket): no thread; the caller waits in python-can's ``recv`` (one bus) or
  ``select``s on the sockets (several) and drains them with ``recv(0)``: the kernel's buffer is the queue (no thread
  hand-off, no wait for the GIL).
- **Threads** (otherwise: ``virtual``, vendor drivers): one thread per bus puts each message on an unbounded
  :class:`queue.SimpleQueue`, so no frame is dropped while the engine is busy.
Per bus the id keys the config reads go to SocketCAN as kernel filters (a foreign frame never wakes the daemon);
:func:`wants` drops foreign frames on any interface. A receive error is logged, handed to ``on_error``, and the bus
reopened with exponential backoff: never a silent hang, never a dead thread.
"""

from __future__ import annotations

import logging
import math
import os
import queue
import select
import socket
import stat
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from time import monotonic
from typing import TYPE_CHECKING

import can

from canguard.config.schema import BusConfig, Config
from canguard.errors import BusError
from canguard.io.block import EXT_KEY

if TYPE_CHECKING:
    from can.typechecking import CanFilter

log = logging.getLogger(__name__)

ErrorCallback = Callable[[str, BaseException], None]
Opener = Callable[[BusConfig], can.BusABC]
Wanted = Mapping[str, frozenset[int] | None]
"""Per bus, the id keys (as :attr:`Block.keys <canguard.io.block.Block.keys>`) of the frames taken; None: all."""

KERNEL_FILTERS_MAX = 512
"""SocketCAN takes at most this many filters a socket (``CAN_RAW_FILTER_MAX``); past it canguard filters alone."""


def receive_keys(cfg: Config) -> dict[str, frozenset[int] | None]:
    """Per bus of ``cfg``, the id keys of the frames the config reads; None for a bus with ``filter: false``."""
    keys: dict[str, set[int]] = {name: set() for name in cfg.buses}
    for source in cfg.sources.values():
        for ref in source.signals:
            keys.setdefault(ref.bus, set()).add(ref.frame_id + EXT_KEY if ref.is_extended_id else ref.frame_id)
    return {name: frozenset(keys[name]) if bus.filter else None for name, bus in cfg.buses.items()}


def kernel_filters(keys: Iterable[int]) -> list[CanFilter]:
    """python-can ``can_filters`` passing exactly the frames of ``keys`` (each id, full mask, its extended flag)."""
    return [{"can_id": k - EXT_KEY, "can_mask": 0x1FFFFFFF, "extended": True} if k >= EXT_KEY
            else {"can_id": k, "can_mask": 0x7FF, "extended": False} for k in sorted(keys)]


def wants(keys: frozenset[int] | None, msg: can.Message) -> bool:
    """Whether a bus receiving ``keys`` (:data:`Wanted`) takes ``msg``: an error frame always."""
    return (keys is None or (msg.arbitration_id + EXT_KEY if msg.is_extended_id else msg.arbitration_id) in keys
            or msg.is_error_frame)


def open_bus(cfg: BusConfig) -> can.BusABC:
    """Open ``cfg`` with ``can.Bus``; a :class:`BusError` naming bus, interface and channel when it does not open."""
    try:
        bus = can.Bus(**dict(cfg.kwargs))
    except Exception as exc:  # python-can raises CanError, OSError, ImportError, ValueError... per backend
        raise BusError(f"bus {cfg.name!r} (interface {cfg.interface or '?'}, channel {cfg.channel}) does not open: "
                       f"{type(exc).__name__}: {exc}") from exc
    enlarge_receive_buffer(bus, cfg.name)
    return bus


RECEIVE_BUFFER_BYTES = 4 << 20
"""Kernel receive buffer asked for on socket-based buses: ~0.5 s of four saturated 1 Mbit/s buses."""


def enlarge_receive_buffer(bus: can.BusABC, name: str, size: int = RECEIVE_BUFFER_BYTES) -> int | None:
    """Ask the kernel for a larger receive buffer on a socket-based bus (SocketCAN, udp_multicast; others are left
    alone), so that a burst while the loop is busy is held, not dropped; the size granted. SO_RCVBUFFORCE is tried
    first: without CAP_NET_ADMIN the kernel caps the size at ``net.core.rmem_max`` (raise it on the robot)."""
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        sock = getattr(getattr(bus, "_multicast", None), "_socket", None)
    if not isinstance(sock, socket.socket):
        return None
    for opt in filter(None, (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF)):
        try:
            sock.setsockopt(socket.SOL_SOCKET, opt, size)
            break
        except OSError:
            continue
    granted = int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
    log.debug("bus %s: receive buffer %d bytes", name, granted)
    return granted


def bus_fileno(bus: can.BusABC) -> int:
    """The socket ``select`` can wait on for ``bus``'s frames, or -1. Only a socket: python-can reads several frames
    from a serial adapter's descriptor at once and keeps the rest, which ``select`` cannot see."""
    try:
        fd = bus.fileno()
        if not isinstance(fd, int) or fd < 0 or not stat.S_ISSOCK(os.fstat(fd).st_mode):
            return -1
    except (NotImplementedError, OSError, AttributeError, ValueError):
        return -1
    return fd


WALL_STAMP_S = 1.0
"""A frame stamped this close to the wall clock: the bus stamps with it, its stamps are arrival times from then on."""


class BusReader:
    """Receives from the configured buses (a context manager); per bus: received, sent, send_failures, reopens."""

    def __init__(
        self,
        buses: Mapping[str, BusConfig] | Iterable[BusConfig],
        *,
        on_error: ErrorCallback | None = None,
        recv_timeout_s: float = 0.1,
        backoff_min_s: float = 0.1,
        backoff_max_s: float = 5.0,
        opener: Opener = open_bus,
        direct: bool = False,
        wanted: Wanted | None = None,
    ) -> None:
        configs = list(buses.values()) if isinstance(buses, Mapping) else list(buses)
        self.configs: dict[str, BusConfig] = {c.name: c for c in configs}
        self.queue: queue.SimpleQueue[tuple[str, can.Message, float]] = queue.SimpleQueue()
        """``(bus_name, message, received)``: ``received`` is ``time.monotonic()`` when the receive thread got it."""
        self.on_error = on_error
        self.recv_timeout_s = recv_timeout_s
        self.backoff_min_s = backoff_min_s
        self.backoff_max_s = backoff_max_s
        self._opener = opener
        self.wanted: dict[str, frozenset[int] | None] = {name: (wanted or {}).get(name) for name in self.configs}
        """Per bus, the id keys of the frames taken (:func:`wants`); None: every frame. Set with :meth:`want`."""
        self._direct_wanted = direct
        self.direct = False
        """True once started without threads: :meth:`receive` waits on the buses' sockets itself."""
        self._started = False
        self._fds: dict[str, int] = {}
        self._pending: dict[str, Callable[[int], list[tuple[int, int]]]] = {}
        """Per bus received directly: a poll of its socket (``pending(0)`` non-empty: the kernel holds a frame)."""
        self._wall_stamps: dict[str, bool | None] = dict.fromkeys(self.configs)
        self._reopen_at: dict[str, float] = dict.fromkeys(self.configs, 0.0)
        self._delay: dict[str, float] = dict.fromkeys(self.configs, backoff_min_s)
        self._buses: dict[str, can.BusABC | None] = dict.fromkeys(self.configs)
        self._threads: dict[str, threading.Thread] = {}
        self._stop = threading.Event()
        self._lock = threading.Lock()  # guards bus replacement against a concurrent send()
        self.received: dict[str, int] = dict.fromkeys(self.configs, 0)
        self.sent: dict[str, int] = dict.fromkeys(self.configs, 0)
        self.send_failures: dict[str, int] = dict.fromkeys(self.configs, 0)
        self.reopens: dict[str, int] = dict.fromkeys(self.configs, 0)

    # -- life cycle --------------------------------------------------------
    def start(self) -> None:
        """Open every bus and start its receive thread (none when direct); BusError for the first that does not open."""
        if self._started:
            raise RuntimeError("BusReader already started")
        self._stop.clear()
        try:
            for name in self.configs:
                self._buses[name] = self._open(name)
        except Exception:
            self._shutdown_all()
            raise
        self._started = True
        fds = {name: bus_fileno(bus) for name, bus in self._buses.items() if bus is not None}
        self.direct = self._direct_wanted and bool(fds) and min(fds.values()) >= 0 and hasattr(select, "poll")
        if self.direct:
            for name, fd in fds.items():
                self._watch(name, fd)
            return
        for name in self.configs:
            t = threading.Thread(target=self._run, args=(name,), name=f"canguard-bus-{name}", daemon=True)
            self._threads[name] = t
            t.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the threads (each within about one receive timeout) and shut every bus down."""
        self._stop.set()
        for t in self._threads.values():
            t.join(timeout_s)
            if t.is_alive():
                log.warning("bus thread %s did not stop within %.1f s", t.name, timeout_s)
        self._threads.clear()
        self._started = False
        self._shutdown_all()

    def __enter__(self) -> BusReader:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def alive(self) -> dict[str, bool]:
        """Whether each bus is received from (its thread alive, or receiving directly) and currently open."""
        return {
            name: (self._buses[name] is not None and self._started
                   and (self.direct or (name in self._threads and self._threads[name].is_alive())))
            for name in self.configs
        }

    def want(self, wanted: Wanted) -> None:
        """Take the frames of ``wanted`` from now on (a config reloaded): the kernel's filters follow."""
        self.wanted = {name: wanted.get(name) for name in self.configs}
        with self._lock:
            for name, bus in self._buses.items():
                if bus is not None:
                    self._filter(name, bus)

    def _open(self, name: str) -> can.BusABC:
        """Open bus ``name`` with the kernel's filters of :attr:`wanted` (SocketCAN)."""
        bus = self._opener(self.configs[name])
        self._filter(name, bus)
        return bus

    def _filter(self, name: str, bus: can.BusABC) -> None:
        """On SocketCAN (no ``can_filters`` of its own): :attr:`wanted` as kernel filters, or all when too many."""
        cfg = self.configs[name]
        if cfg.interface != "socketcan" or "can_filters" in cfg.kwargs:
            return
        keys = self.wanted[name]
        bus.set_filters(kernel_filters(keys) if keys and len(keys) <= KERNEL_FILTERS_MAX else None)

    # -- consuming ---------------------------------------------------------
    def receive(self, timeout_s: float | None, limit: int) -> list[tuple[str, can.Message, float]]:
        """Up to ``limit`` ``(bus_name, message, received)`` in arrival order, waiting ``timeout_s`` for the first."""
        if self.direct:
            return self._receive_direct(timeout_s, limit)
        try:
            first = self.queue.get(timeout=timeout_s) if timeout_s is None or timeout_s > 0 else self.queue.get_nowait()
        except queue.Empty:
            return []
        out = [first]
        get = self.queue.get_nowait
        try:
            while len(out) < limit:
                out.append(get())
        except queue.Empty:
            pass
        return out

    # -- sending -----------------------------------------------------------
    def send(self, bus_name: str, msg: can.Message) -> bool:
        """Send ``msg`` without blocking: True when the bus took it; a failure is counted and logged, never raised."""
        bus = self._buses.get(bus_name)
        if bus is None:
            self.send_failures[bus_name] = self.send_failures.get(bus_name, 0) + 1
            return False
        try:
            bus.send(msg, timeout=0)
        except Exception as exc:  # can.CanOperationError, OSError, ... per backend
            self.send_failures[bus_name] = self.send_failures.get(bus_name, 0) + 1
            log.debug("send on bus %s failed: %s", bus_name, exc)
            return False
        self.sent[bus_name] += 1
        return True

    # -- receiving directly -------------------------------------------------
    def _receive_direct(self, timeout_s: float | None, limit: int) -> list[tuple[str, can.Message, float]]:
        """Wait on the open buses' sockets, drain the ready ones, reopen those due; until ``timeout_s`` is over."""
        end = math.inf if timeout_s is None else monotonic() + timeout_s
        while not self._stop.is_set():
            out = self._wake(timeout_s, limit)
            if out is not None:
                return out
            left = end - monotonic()
            if left <= 0.0:
                break
            timeout_s = None if left == math.inf else left
        return []

    def _wake(self, timeout_s: float | None, limit: int) -> list[tuple[str, can.Message, float]] | None:
        """One wait and drain: the frames taken; [] when none came in time, None when what came was all dropped.
        One bus open: python-can's receive waits on its socket itself (one system call less a wake-up)."""
        buses = self._buses
        if len(buses) == 1 and None not in buses.values():
            out: list[tuple[str, can.Message, float]] = []
            name = next(iter(buses))
            read = self._drain_bus(name, limit, out, timeout_s)
            return out if out or not read else None
        if None in buses.values():  # a bus closed: reopened when due, waited on until then
            now = monotonic()
            self._reopen_due(now)
            due = min((self._reopen_at[n] for n, bus in buses.items() if bus is None), default=math.inf)
            wait = max(0.0, min(math.inf if timeout_s is None else timeout_s, due - now))
            timeout_s = None if wait == math.inf else wait
            fds = [self._fds[name] for name, bus in buses.items() if bus is not None]
        else:
            fds = list(self._fds.values())
        try:
            ready, _, _ = select.select(fds, [], [], timeout_s)
        except (OSError, ValueError):  # a socket closed under us: each recv below says which
            ready = fds
        if not ready:
            return []
        out = []
        share = max(1, limit // len(ready))  # a busy bus does not starve the others
        for name, fd in self._fds.items():
            if fd in ready and self._buses[name] is not None:
                self._drain_bus(name, share, out)
        if len(ready) > 1:
            out.sort(key=lambda item: item[2])  # buses drained one after the other: back to arrival order
        return out if out or None in self._buses.values() else None

    def _drain_bus(self, name: str, limit: int, out: list[tuple[str, can.Message, float]],
                   wait_s: float | None = 0.0) -> int:
        """Append up to ``limit`` frames the kernel holds for bus ``name``, the first waited for up to ``wait_s``; a
        failure closes the bus. The frames read (taken or dropped). System calls are the cost: after a frame taken
        alone or dropped a poll of the socket (cheaper than a ``recv(0)`` that finds none) asks for another, after
        two ``recv(0)`` until none; a frame dropped while the one bus is waited on: the wait goes on."""
        bus = self._buses[name]
        assert bus is not None
        msgs: list[can.Message] = []
        recv = bus.recv
        pending = self._pending[name]
        keys = self.wanted[name]
        read = 0
        end = monotonic() + wait_s if wait_s else 0.0
        try:
            while len(msgs) < limit:
                msg = recv(wait_s)
                if msg is None:
                    break
                read += 1
                if wants(keys, msg):
                    msgs.append(msg)
                    wait_s = 0.0
                elif not msgs and wait_s:  # dropped while waiting on the one bus: waited on for the rest of the time
                    wait_s = end - monotonic()
                    if wait_s <= 0.0:
                        break
                    continue
                if len(msgs) < 2 and not pending(0):  # a frame alone, the usual wake-up: no recv(0) that finds none
                    break
        except Exception as exc:  # the bus went away (or a backend bug): report, close, reopen later
            self._failed(name, exc)
            self._reopen_at[name] = monotonic() + self._delay[name]
        if msgs:
            self.admit(name, msgs, out)
        return read

    def admit(self, name: str, msgs: list[can.Message], out: list[tuple[str, can.Message, float]]) -> None:
        """Append the messages just received from bus ``name`` to ``out`` as ``(name, message, received)``: the
        kernel stamp on ``time.monotonic()``'s base (never after now) once the bus stamps with the wall clock
        (:data:`WALL_STAMP_S`), else now."""
        now = monotonic()
        offset = time.time() - now  # wall clock minus monotonic: a wall-clock stamp to monotonic's base
        wall = self._wall_stamps[name]
        for msg in msgs:
            t = float(msg.timestamp or 0.0) - offset
            if not wall:  # until one of its frames says so: does the bus stamp with the wall clock?
                wall = self._wall_stamps[name] = abs(t - now) < WALL_STAMP_S
            out.append((name, msg, (now if now < t else t) if wall else now))  # min(t, now), NaN kept
        self.received[name] += len(msgs)
        self._delay[name] = self.backoff_min_s

    def _reopen_due(self, now: float) -> None:
        """Try once to reopen each closed bus whose backoff delay has passed; a failure doubles its delay."""
        for name, bus in self._buses.items():
            if bus is not None or now < self._reopen_at[name]:
                continue
            delay = self._delay[name]
            self._delay[name] = min(delay * 2, self.backoff_max_s)
            opened = self._open_once(name, delay)
            if opened is None:
                self._reopen_at[name] = now + delay
                continue
            fd = bus_fileno(opened)
            if fd < 0:  # cannot happen for the same interface; fail loudly rather than never receive
                _shutdown(opened, name)
                raise BusError(f"bus {name!r} reopened without a socket to wait on")
            self._watch(name, fd)
            self._wall_stamps[name] = None

    def _watch(self, name: str, fd: int) -> None:
        """Receive bus ``name`` directly from socket ``fd``: waited on with the others, polled while drained."""
        self._fds[name] = fd
        poller = select.poll()
        poller.register(fd, select.POLLIN)
        self._pending[name] = poller.poll

    # -- the receive threads -----------------------------------------------
    def _run(self, name: str) -> None:
        put = self.queue.put
        stop = self._stop
        timeout = self.recv_timeout_s
        delay = self.backoff_min_s
        while not stop.is_set():
            bus = self._buses[name]
            if bus is None:
                if self._open_once(name, delay) is None:
                    stop.wait(delay)
                    delay = min(delay * 2, self.backoff_max_s)
                continue
            try:
                msg = bus.recv(timeout)
                if msg is None or not wants(self.wanted[name], msg):
                    continue
                put((name, msg, monotonic()))  # arrival: how long it then waits
            except Exception as exc:  # the bus went away (or a backend bug): report, close, reopen
                if stop.is_set():
                    break
                self._failed(name, exc)
                stop.wait(delay)
                delay = min(delay * 2, self.backoff_max_s)
                continue
            self.received[name] += 1
            delay = self.backoff_min_s

    def _failed(self, name: str, exc: BaseException) -> None:
        """Log and report a receive error and close the bus (the thread reopens it)."""
        cfg = self.configs[name]
        log.error(
            "bus %s (%s, channel %s): receive failed: %s; reopening", name, cfg.interface, cfg.channel, exc
        )
        if self.on_error is not None:
            try:
                self.on_error(name, exc)
            except Exception:  # a faulty callback must not kill the receive thread
                log.exception("on_error callback failed for bus %s", name)
        with self._lock:
            bus, self._buses[name] = self._buses[name], None
        _shutdown(bus, name)

    def _open_once(self, name: str, delay: float) -> can.BusABC | None:
        """Try once to reopen ``name``; the bus, or None (logged, saying when the next try is)."""
        try:
            bus = self._open(name)
        except Exception as exc:
            log.warning("bus %s: reopen failed (%s); retrying in %.1f s", name, exc, delay)
            return None
        if self._stop.is_set():
            _shutdown(bus, name)
            return None
        with self._lock:
            self._buses[name] = bus
        self.reopens[name] += 1
        log.info("bus %s reopened", name)
        return bus

    def _shutdown_all(self) -> None:
        with self._lock:
            buses = list(self._buses.items())
            self._buses = dict.fromkeys(self.configs)
        for name, bus in buses:
            _shutdown(bus, name)


def _shutdown(bus: can.BusABC | None, name: str) -> None:
    """Shut ``bus`` down, logging (not raising) a failure."""
    if bus is None:
        return
    try:
        bus.shutdown()
    except Exception as exc:  # a bus that is already gone may fail to close
        log.debug("bus %s: shutdown failed: %s", name, exc)
