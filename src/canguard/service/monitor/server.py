"""The monitor process: ``python -m canguard.service.monitor.server FD``, started by the daemon (:class:`.Monitor`).

Its settings come over the socket ``FD`` (the token never shows on a command line)."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import pickle
import signal
import socket
import sys
from collections.abc import Iterator
from typing import Any

from canguard.config.monitor import Address, parse_address
from canguard.errors import ConfigError
from canguard.service.monitor import END, FRAME_BYTES
from canguard.service.monitor.hub import Hub

NICE = 10
"""How much lower than the daemon's this process's CPU priority is: on a busy robot the loop gets the CPU first."""
FILES = 65536
"""File descriptors this process asks for (up to the hard limit): each client of the page or Groot2 holds one."""


def _address(text: str, port_span: int = 1) -> Address:
    address = parse_address(text, port_span=port_span)
    if isinstance(address, str):  # validated by the config loader / with_overrides already
        raise ConfigError(f"monitor address {text!r}: expected {address}")
    return address


def servers(settings: dict[str, Any], hub: Hub) -> dict[str, Any]:
    """The servers ``settings`` ask for (``http``, ``groot2``), listening; :class:`ConfigError` when one cannot."""
    out: dict[str, Any] = {}
    try:
        if settings.get("http"):
            from canguard.service.monitor.web import WebMonitor

            address = _address(settings["http"])
            try:
                out["http"] = WebMonitor(address, hub, settings.get("token"))
            except OSError as exc:
                raise ConfigError(f"status page on {address}: cannot listen ({exc.strerror or exc})") from exc
        if settings.get("groot2"):
            address = _address(settings["groot2"], port_span=2)
            try:
                from canguard.service.monitor.groot2 import Groot2Monitor
            except ModuleNotFoundError as exc:
                if exc.name != "zmq":
                    raise
                raise ConfigError(f"Groot2 monitor on {address}: needs pyzmq, which is not installed: "
                                  "pip install 'canguard[monitor]'") from None
            try:
                out["groot2"] = Groot2Monitor(address, hub)
            except Exception as exc:  # zmq.ZMQError: address in use, no such interface
                raise ConfigError(f"Groot2 monitor on {address}: cannot listen ({exc})") from exc
    except BaseException:
        for server in out.values():
            server.close()
        raise
    return out


def lower_priority() -> None:
    """``SCHED_BATCH`` and :data:`NICE` below the daemon, before any thread starts (they inherit it); not
    ``SCHED_IDLE``: that would starve the page whenever the CPUs are busy, when a person most needs it."""
    with contextlib.suppress(OSError, AttributeError):  # AttributeError: not Linux
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    with contextlib.suppress(OSError):
        os.nice(NICE)


def more_descriptors() -> None:
    """Raise this process's open-file limit to :data:`FILES` or the hard limit (:class:`.web.Limits`)."""
    import resource

    with contextlib.suppress(OSError, ValueError):
        soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        wanted = FILES if hard == resource.RLIM_INFINITY else min(FILES, hard)
        if soft != resource.RLIM_INFINITY and soft < wanted:
            resource.setrlimit(resource.RLIMIT_NOFILE, (wanted, hard))


def messages(sock: socket.socket) -> Iterator[Any]:
    """The daemon's messages, each put back together from its frames, until the daemon's end closes."""
    parts: list[bytes] = []
    while frame := sock.recv(FRAME_BYTES + 64):
        parts.append(frame[1:])
        if frame[:1] == END:
            yield pickle.loads(b"".join(parts))  # only ever from our own daemon, over a private socket pair
            parts = []


def main(argv: list[str] | None = None) -> int:
    """Serve the monitors for the daemon at the other end of socket ``argv[0]``; 0 when it ended, 2 on bad settings."""
    args = sys.argv[1:] if argv is None else argv
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, lambda _num, _frame: sys.exit(0))
    lower_priority()
    more_descriptors()
    logging.basicConfig(level=logging.WARNING, format="canguard monitor: %(levelname)s %(name)s: %(message)s")
    sock = socket.socket(fileno=int(args[0]))
    hub = Hub(sock)
    try:
        try:
            serving = servers(json.loads(sock.recv(65536).decode() or "{}"), hub)
        except ConfigError as exc:
            sock.send(json.dumps({"error": str(exc)}).encode())  # the one answer at start: ready, or why not
            return 2
        ready = {name: [s.address.host, s.address.port] if (s := serving.get(name)) else None
                 for name in ("http", "groot2")}
        sock.send(json.dumps({"ready": ready}).encode())
        try:
            for server in serving.values():
                server.start()
            for message in messages(sock):
                hub.receive(message)
        finally:
            for server in serving.values():
                server.close()
    finally:
        sock.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
