"""The engine's journal: every event of one engine, stamped, counted and written to its sink.

The engine, its task gate and the daemon around it write their events here
(:meth:`Journal.write`); :meth:`Journal.flush` makes them durable (the engine calls it
once per batch of ticks, the daemon after events of its own: a reload, a bus reopened).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Any

from canguard.engine.stats import EventSink


class Journal:
    """Stamps events with the clock's time, counts them by name and writes them to ``sink`` (when given)."""

    def __init__(
        self,
        now: Callable[[], float],
        sink: EventSink | None,
        *,
        durable: bool = True,
        on_event: Callable[[dict[str, Any]], None] | None = None,
    ) -> None:
        self.now = now
        self.sink = sink
        self.durable = durable
        """False: :meth:`flush` never fsyncs (replay writes a journal nobody reads during the run)."""
        self.on_event = on_event
        """Also called with every event (the live view, the realtime replay)."""
        self.seen: Counter[str] = Counter()
        """How many events of each name were written (summaries count escalations...); bounded, live for weeks."""
        self.written = 0
        """Events written so far (a quiet stretch of ticks ends at any event)."""
        self._dirty = False

    def write(self, event: dict[str, Any]) -> None:
        """Record one event; ``t`` is the clock's time unless the event has one."""
        if "t" not in event:
            event = {"t": self.now(), **event}
        self.seen[str(event.get("event"))] += 1
        self.written += 1
        if self.sink is not None:
            self.sink.write(event)
            self._dirty = True
        if self.on_event is not None:
            self.on_event(event)

    def flush(self) -> None:
        """Make the events written since the last flush durable (when the journal is)."""
        if self._dirty and self.durable and self.sink is not None:
            self.sink.flush()
            self._dirty = False
