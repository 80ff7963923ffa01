"""The engine's journal: every event of one engine, stamped, counted, and recorded after the frames it caused.

The engine, its task gate and the daemon around it write their events here
(:meth:`Journal.write`): each is stamped and counted at once, and held in memory.
:meth:`Journal.flush` records the held events, in the order written, to the sink
(and the live view), then makes them durable. The engine flushes at the end of
every tick and every :meth:`~canguard.engine.core.Engine.advance`, the daemon after
events of its own (a reload, a bus reopened). So the stop frames of a trip leave
before anything is recorded about it: the trip and the stop are written once the
tick that sent the frames is over, with the times they happened at.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Any

from canguard.engine.stats import EventSink


class Journal:
    """Stamps events with the clock's time, counts them by name, and records them to ``sink`` (when given) at
    :meth:`flush`."""

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
        """Also called with every event, at :meth:`flush` (the live view, the realtime replay)."""
        self.seen: Counter[str] = Counter()
        """How many events of each name were written (summaries count escalations...); bounded, live for weeks."""
        self.written = 0
        """Events written so far, held ones included (a quiet stretch of ticks ends at any event)."""
        self._held: list[dict[str, Any]] = []
        self._dirty = False

    def write(self, event: dict[str, Any]) -> None:
        """Take one event, recorded at the next :meth:`flush`; ``t`` is the clock's time now unless it has one."""
        if "t" not in event:
            event = {"t": self.now(), **event}
        self.seen[str(event.get("event"))] += 1
        self.written += 1
        self._held.append(event)

    def flush(self) -> None:
        """Record the events held, in order, and make them durable (when the journal is)."""
        if self._held:
            held, self._held = self._held, []
            sink, on_event = self.sink, self.on_event
            for event in held:
                if sink is not None:
                    sink.write(event)
                    self._dirty = True
                if on_event is not None:
                    on_event(event)
        if self._dirty and self.durable and self.sink is not None:
            self.sink.flush()
            self._dirty = False
