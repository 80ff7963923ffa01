"""What the engine counts, and what it writes events to."""

from __future__ import annotations

from collections.abc import Mapping
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
    quiet_ticks: int = 0
    """Grid ticks proven to repeat the last tick, counted in ``ticks`` but not run (:mod:`canguard.engine.quiet`)."""
    tick_errors: int = 0
    backward_frames: int = 0
    trips: list[dict[str, Any]] = field(default_factory=list)
    """Every trip event, up to :data:`MAX_KEPT_TRIPS` (a guard flapping for days must not eat the memory)."""
    trip_count: int = 0
    """Every trip, kept or not."""
    samples: dict[str, int] = field(default_factory=dict)
    """Samples decoded per source."""
    max_abs: dict[tuple[str, str], float] = field(default_factory=dict)
    """Largest |value| seen per (source, role): for the lowest margin to each threshold."""
    heat_models: Mapping[str, Any] = field(default_factory=dict, repr=False)
    """The I²t models by guard node (the engine's context's): :attr:`max_level_pct` reads their peaks."""

    @property
    def max_level_pct(self) -> dict[str, float]:
        """Largest accumulator level (% of trip) per I²t guard node: each model's own peak over every sample it
        took (:attr:`~canguard.protect.i2t.LeakyI2t.peak_level_pct`)."""
        return {node: model.peak_level_pct for node, model in self.heat_models.items()}
