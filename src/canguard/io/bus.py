"""Open the configured python-can buses and receive from them without losing frames.

:func:`open_bus` opens one :class:`~canguard.config.schema.BusConfig` with ``can.Bus``
(any interface python-can supports), turning a failure into a
:class:`~canguard.errors.BusError` that names the bus and the interface.

:class:`BusReader` runs one daemon thread per bus. Each thread does nothing but
``bus.recv(timeout)``, build a :class:`~canguard.io.frame.Frame` (keeping the
message's kernel / hardware timestamp) and put ``(bus_name, frame)`` on one
unbounded :class:`queue.SimpleQueue` the engine drains, so no frame is dropped
while the engine is busy. A receive error is logged on ``canguard.io.bus``, handed
to ``on_error(bus_name, exc)``, and the bus is closed and reopened with
exponential backoff (``backoff_min_s`` .. ``backoff_max_s``, reset by the next
frame received): never a silent hang, never a dead thread.
"""

from __future__ import annotations

import logging
import queue
import socket
import threading
from collections.abc import Callable, Iterable, Iterator, Mapping
from time import monotonic

import can

from canguard.config.schema import BusConfig
from canguard.errors import BusError
from canguard.io.frame import Frame
from canguard.io.logs import frame_from_message

log = logging.getLogger(__name__)

ErrorCallback = Callable[[str, BaseException], None]
Opener = Callable[[BusConfig], can.BusABC]


def open_bus(cfg: BusConfig) -> can.BusABC:
    """Open ``cfg`` with ``can.Bus(**cfg.kwargs)``.

    Raises :class:`BusError` naming the bus, interface and channel, chained to
    python-can's own exception.
    """
    try:
        bus = can.Bus(**dict(cfg.kwargs))
    except Exception as exc:  # python-can raises CanError, OSError, ImportError, ValueError... per backend
        raise BusError(
            f"bus {cfg.name!r} (interface {cfg.interface or '?'}, channel {cfg.channel}) does not open: "
            f"{type(exc).__name__}: {exc}"
        ) from exc
    enlarge_receive_buffer(bus, cfg.name)
    return bus


RECEIVE_BUFFER_BYTES = 4 << 20
"""Kernel receive buffer asked for on socket-based buses: ~0.5 s of four saturated 1 Mbit/s buses."""


def enlarge_receive_buffer(bus: can.BusABC, name: str, size: int = RECEIVE_BUFFER_BYTES) -> int | None:
    """Ask the kernel for a larger receive buffer on a socket-based bus; returns the size granted.

    A burst that arrives while the receive thread waits for the GIL is then held
    by the kernel instead of dropped. SocketCAN and udp_multicast buses have a
    socket; others (virtual, vendor drivers with their own queues) are left alone.
    Without CAP_NET_ADMIN the kernel caps the size at ``net.core.rmem_max``
    (raise it with sysctl on the robot); SO_RCVBUFFORCE is tried first.
    """
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        sock = getattr(getattr(bus, "_multicast", None), "_socket", None)
    if not isinstance(sock, socket.socket):
        return None
    for opt in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
        if opt is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, opt, size)
            break
        except OSError:
            continue
    granted = int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
    log.debug("bus %s: receive buffer %d bytes", name, granted)
    return granted


def to_frame(msg: can.Message, bus_name: str) -> Frame:
    """The :class:`Frame` of a received python-can message; ``channel`` is the bus name."""
    return frame_from_message(msg, bus_name)


class BusReader:
    """Receives from every configured bus on its own daemon thread into one queue.

    Use as a context manager, or call :meth:`start` and :meth:`stop`. Counters
    (by bus name): :attr:`received`, :attr:`sent`, :attr:`send_failures`,
    :attr:`recv_errors`, :attr:`reopens`.
    """

    def __init__(
        self,
        buses: Mapping[str, BusConfig] | Iterable[BusConfig],
        *,
        on_error: ErrorCallback | None = None,
        recv_timeout_s: float = 0.1,
        backoff_min_s: float = 0.1,
        backoff_max_s: float = 5.0,
        opener: Opener = open_bus,
    ) -> None:
        configs = list(buses.values()) if isinstance(buses, Mapping) else list(buses)
        self.configs: dict[str, BusConfig] = {c.name: c for c in configs}
        self.queue: queue.SimpleQueue[tuple[str, Frame, float]] = queue.SimpleQueue()
        """``(bus_name, frame, received)``: ``received`` is ``time.monotonic()`` when the receive thread got it."""
        self.on_error = on_error
        self.recv_timeout_s = recv_timeout_s
        self.backoff_min_s = backoff_min_s
        self.backoff_max_s = backoff_max_s
        self._opener = opener
        self._buses: dict[str, can.BusABC | None] = dict.fromkeys(self.configs)
        self._threads: dict[str, threading.Thread] = {}
        self._stop = threading.Event()
        self._lock = threading.Lock()  # guards bus replacement against a concurrent send()
        self.received: dict[str, int] = dict.fromkeys(self.configs, 0)
        self.sent: dict[str, int] = dict.fromkeys(self.configs, 0)
        self.send_failures: dict[str, int] = dict.fromkeys(self.configs, 0)
        self.recv_errors: dict[str, int] = dict.fromkeys(self.configs, 0)
        self.reopens: dict[str, int] = dict.fromkeys(self.configs, 0)

    # -- life cycle --------------------------------------------------------
    def start(self) -> None:
        """Open every bus, then start one receive thread per bus.

        Raises :class:`BusError` for the first bus that does not open (the buses
        already opened are shut down again).
        """
        if self._threads:
            raise RuntimeError("BusReader already started")
        self._stop.clear()
        try:
            for name, cfg in self.configs.items():
                self._buses[name] = self._opener(cfg)
        except Exception:
            self._shutdown_all()
            raise
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
        self._shutdown_all()

    def __enter__(self) -> BusReader:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        """True while the receive threads run."""
        return bool(self._threads) and not self._stop.is_set()

    def alive(self) -> dict[str, bool]:
        """Whether each bus's thread is alive and its bus currently open."""
        return {
            name: (name in self._threads and self._threads[name].is_alive() and self._buses[name] is not None)
            for name in self.configs
        }

    # -- consuming ---------------------------------------------------------
    def get(self, timeout_s: float | None = None) -> tuple[str, Frame] | None:
        """The next ``(bus_name, frame)``, or None after ``timeout_s`` without one."""
        try:
            name, frame, _received = self.queue.get(timeout=timeout_s)
        except queue.Empty:
            return None
        return name, frame

    def drain(self) -> list[tuple[str, Frame]]:
        """Every ``(bus_name, frame)`` queued right now, without waiting."""
        out: list[tuple[str, Frame]] = []
        get = self.queue.get_nowait
        try:
            while True:
                name, frame, _received = get()
                out.append((name, frame))
        except queue.Empty:
            return out

    def __iter__(self) -> Iterator[tuple[str, Frame]]:
        """``(bus_name, frame)`` as they arrive, until :meth:`stop`."""
        while not self._stop.is_set():
            item = self.get(self.recv_timeout_s)
            if item is not None:
                yield item

    # -- sending -----------------------------------------------------------
    def send(self, bus_name: str, msg: can.Message) -> bool:
        """Send ``msg`` on ``bus_name`` without blocking (timeout 0).

        Returns True when the bus took it; a failure (unknown or closed bus, full
        transmit buffer, ...) is counted in :attr:`send_failures` and logged at
        debug level, never raised.
        """
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

    # -- the receive threads -----------------------------------------------
    def _run(self, name: str) -> None:
        put = self.queue.put
        stop = self._stop
        timeout = self.recv_timeout_s
        delay = self.backoff_min_s
        while not stop.is_set():
            bus = self._buses[name]
            if bus is None:
                if not self._reopen(name, delay):
                    delay = min(delay * 2, self.backoff_max_s)
                continue
            try:
                msg = bus.recv(timeout)
                if msg is None:
                    continue
                put((name, to_frame(msg, name), monotonic()))  # when it arrived: how long it then waits
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
        self.recv_errors[name] += 1
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

    def _reopen(self, name: str, delay: float) -> bool:
        """Try once to reopen ``name``; on failure wait ``delay`` (or until stopped)."""
        try:
            bus = self._opener(self.configs[name])
        except Exception as exc:
            log.warning("bus %s: reopen failed (%s); retrying in %.1f s", name, exc, delay)
            self._stop.wait(delay)
            return False
        if self._stop.is_set():
            _shutdown(bus, name)
            return False
        with self._lock:
            self._buses[name] = bus
        self.reopens[name] += 1
        log.info("bus %s reopened", name)
        return True

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
