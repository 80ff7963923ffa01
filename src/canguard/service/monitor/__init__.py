"""Watching the daemon live: the status page (:mod:`.web`) and Groot2's monitor (:mod:`.groot2`).

After its tick the engine publishes an immutable snapshot (:class:`.snapshot.Observer`); the journal's
events are copied on their way (:class:`EventTee`). :class:`.link.ChildLink` offers both to a process of
their own (:mod:`.server`) without ever waiting (latest wins): nothing there can change what canguard
does, nor make the loop wait. Imported only when a monitor is configured.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from canguard.config.schema import MonitorConfig
from canguard.service.monitor.layout import TreeLayout
from canguard.service.monitor.link import ChildLink
from canguard.service.monitor.snapshot import Observer

if TYPE_CHECKING:
    from canguard.engine.core import Engine
    from canguard.engine.stats import EventSink

log = logging.getLogger(__name__)

__all__ = ["EventTee", "Monitor"]


class EventTee:
    """The daemon's journal, and a copy of each event for the monitors (the journal first)."""

    def __init__(self, journal: EventSink, hub: ChildLink) -> None:
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
    """The configured monitors of one daemon: their process started once, attached to each engine it runs.

    Raises :class:`~canguard.errors.ConfigError` when a server cannot listen (naming the address and why).
    """

    def __init__(self, settings: MonitorConfig) -> None:
        self.settings = settings
        self.hub = ChildLink(settings)
        """The monitor process, as the engine's snapshot sink."""

    def start(self) -> None:
        """Say where the monitors listen (and that a page on the network needs its token)."""
        addr = self.hub.http
        if addr is not None:
            if addr.loopback:
                log.warning("status page on http://%s/ (this machine only)", addr)
            else:
                log.warning("status page on http://%s/ reachable from the network: every request needs "
                            "'Authorization: Bearer <monitor.token>' (or ?token=<monitor.token>)", addr)
        addr = self.hub.groot2
        if addr is not None:
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
        """End the monitor process."""
        self.hub.close()
