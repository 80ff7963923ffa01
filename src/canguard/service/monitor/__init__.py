"""Watching the daemon live: the status page (:mod:`.web`) and Groot2's monitor (:mod:`.groot2`).

The engine publishes one immutable snapshot per tick (:class:`.snapshot.Observer`, the engine's
``observer``); the journal's events are copied on their way to it (:class:`EventTee`). Both land
in a :class:`.hub.Hub` without a lock; the servers run in their own threads and read only the
hub. Nothing here can change what canguard does, nor make the loop wait.

Imported only when a monitor is configured (``monitor:``, ``--http``, ``--groot2``): the
daemon's start-up without one does not pay for ``http.server`` or ``zmq``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from canguard.config.monitor import Address, parse_address
from canguard.config.schema import MonitorConfig
from canguard.errors import ConfigError
from canguard.service.monitor.hub import Hub
from canguard.service.monitor.layout import TreeLayout
from canguard.service.monitor.snapshot import Observer

if TYPE_CHECKING:
    from canguard.engine.core import Engine
    from canguard.engine.stats import EventSink

log = logging.getLogger(__name__)

__all__ = ["EventTee", "Monitor"]


class EventTee:
    """The daemon's journal, and a copy of each event for the monitors (the journal first)."""

    def __init__(self, journal: EventSink, hub: Hub) -> None:
        self.journal = journal
        self.hub = hub

    def write(self, event: Mapping[str, Any]) -> None:
        """Append to the journal, then keep a copy for the page."""
        self.journal.write(event)
        self.hub.event(event)

    def flush(self) -> None:
        """Flush the journal."""
        self.journal.flush()


class Monitor:
    """The configured monitors of one daemon: started once, attached to each engine it runs."""

    def __init__(self, settings: MonitorConfig) -> None:
        self.settings = settings
        self.hub = Hub()
        self.web: Any = None
        self.groot2: Any = None
        try:
            if settings.http:
                self.web = _web(_address(settings.http), self.hub, settings.token)
            if settings.groot2:
                self.groot2 = _groot2(_address(settings.groot2, port_span=2), self.hub)
        except BaseException:
            self.close()
            raise

    def start(self) -> None:
        """Start serving; say where (and that a non-loopback page needs its token)."""
        self.hub.start()
        if self.web is not None:
            self.web.start()
            addr = self.web.address
            if addr.loopback:
                log.warning("status page on http://%s/ (this machine only)", addr)
            else:
                log.warning("status page on http://%s/ reachable from the network: every request needs "
                            "'Authorization: Bearer <monitor.token>' (or ?token=<monitor.token>)", addr)
        if self.groot2 is not None:
            self.groot2.start()
            addr = self.groot2.address
            where = "this machine only" if addr.loopback else "reachable from the network, read-only, no token"
            log.warning("Groot2 monitor on %s (REP %d, PUB %d; %s)", addr, addr.port, addr.port + 1, where)

    def attach(self, engine: Engine) -> None:
        """Watch ``engine`` from its next tick on (the daemon's engine at start and after each reload)."""
        layout = TreeLayout(engine.loaded, engine.ctx)
        engine.observer = Observer(engine, layout, self.hub)

    def tee(self, journal: EventSink) -> EventTee:
        """The sink the engine writes events to: ``journal``, and the page's copy."""
        return EventTee(journal, self.hub)

    def close(self) -> None:
        """Stop every server and thread."""
        self.hub.close()
        for server in (self.web, self.groot2):
            if server is not None:
                server.close()


def _address(text: str, port_span: int = 1) -> Address:
    address = parse_address(text, port_span=port_span)
    if isinstance(address, str):  # validated by the config loader / with_overrides already
        raise ConfigError(f"monitor address {text!r}: expected {address}")
    return address


def _web(address: Address, hub: Hub, token: str | None) -> Any:
    from canguard.service.monitor.web import WebMonitor

    try:
        return WebMonitor(address, hub, token)
    except OSError as exc:
        raise ConfigError(f"status page on {address}: cannot listen ({exc.strerror or exc})") from exc


def _groot2(address: Address, hub: Hub) -> Any:
    try:
        from canguard.service.monitor.groot2 import Groot2Monitor
    except ModuleNotFoundError as exc:
        if exc.name != "zmq":
            raise
        raise ConfigError(f"Groot2 monitor on {address}: needs pyzmq, which is not installed: "
                          "pip install 'canguard[monitor]'") from None
    try:
        return Groot2Monitor(address, hub)
    except Exception as exc:  # zmq.ZMQError: address in use, no such interface
        raise ConfigError(f"Groot2 monitor on {address}: cannot listen ({exc})") from exc
