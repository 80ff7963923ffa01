"""What the engine counts, and what it writes events to.

Events are stamped and counted at once, recorded at :meth:`Journal.flush` (the end of every tick): a trip's
stop frames leave before anything is recorded about it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol


class EventSink(Protocol):
    """What the engine writes events to (:class:`~canguard.engine.events.EventJournal` is one)."""

    def write(self, event: Mapping[str, Any]) -> None:
        """Append one event."""
        ...

    def flush(self) -> None:
        """Make every written event durable."""
        ...


class TickObserver(Protocol):
    """What watches the engine tick by tick (the live monitors: :class:`canguard.service.monitor.Monitor`)."""

    def publish(self, engine: Any, now: float) -> None:
        """Called with the engine at the end of each tick; must neither raise nor wait."""
        ...


@dataclass
class EngineStats:
    """Counters of one engine run (the replay summary and the daemon's STATUS read them)."""

    frames: int = 0
    ticks: int = 0
    edge_ticks: int = 0
    skipped_ticks: int = 0
    quiet_ticks: int = 0  # counted in ``ticks`` but not run (:mod:`canguard.engine.quiet`)
    tick_errors: int = 0
    backward_frames: int = 0
    trips: list[dict[str, Any]] = field(default_factory=list)  # up to MAX_KEPT_TRIPS: a flapping guard
    trip_count: int = 0  # every trip, kept or not
    samples: dict[str, int] = field(default_factory=dict)  # per source
    max_abs: dict[tuple[str, str], float] = field(default_factory=dict)  # per (source, role)
    heat_models: Mapping[str, Any] = field(default_factory=dict, repr=False)  # the I²t models by guard node

    @property
    def max_level_pct(self) -> dict[str, float]:
        """Largest accumulator level (% of trip) per I²t guard node over every sample it took."""
        return {node: model.peak_level_pct for node, model in self.heat_models.items()}


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
        self.durable = durable  # False: never fsync (replay: nobody reads the journal during the run)
        self.on_event = on_event  # also called with every event, at :meth:`flush`
        self.seen: Counter[str] = Counter()  # events written by name (summaries count escalations...)
        self.written = 0  # held ones included (a quiet stretch of ticks ends at any event)
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
