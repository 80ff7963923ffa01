"""What every protection model is: a pure, per-sample state machine.

Models see every valid sample of the signal they guard (``update``), take time
as an argument (never from a clock), and report their state at tick time
(``poll``) with a *peak latch*: a trip that happened at any moment since the
previous poll is reported even when the current sample is back to normal, so a
one-frame spike between two ticks is never lost.

Invalid data (no sample, stale, present = false, NaN/inf, out of range) is
tracked by :class:`canguard.protect.staleness.SourceHealth`, not by the models:
models only ever see finite values.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

# Reasons a guard is not satisfied, as they appear in snapshots and events.
REASON_OK = ""
REASON_OVERCURRENT = "overcurrent"
REASON_I2T = "i2t"
REASON_NO_DATA = "no_data"
REASON_STALE = "stale"
REASON_NOT_PRESENT = "not_present"


@dataclass(frozen=True)
class Snapshot:
    """A model's state, small enough for events, metrics and plots.

    ``value``: the latest |value| the model saw (A, or N·m), NaN before any.
    ``threshold``: the trip threshold in force (same unit as value; for I²t the
    trip level of the accumulator, A²s or θ = 1).
    ``level_pct``: how close to tripping, in % of the trip level (100 = trip).
    ``tripped``: True while tripped (or, from ``poll``, tripped at any moment since the last poll).
    ``since``: time of the last trip / recover edge, None if never.
    ``reason``: "" when fine, otherwise why not (``overcurrent``, ``i2t``, ...).
    """

    value: float
    threshold: float
    level_pct: float
    tripped: bool
    since: float | None
    reason: str


class ProtectionModel(ABC):
    """A pure state machine over one signal's samples."""

    @abstractmethod
    def update(self, value: float, t: float) -> bool:
        """Feed one finite sample (signed; the model takes |value|) taken at time ``t``.

        Returns True when the tripped state changed (an edge: the engine ticks
        the tree at once). Out-of-order (``t`` earlier than the last sample) and
        repeated timestamps never raise and never corrupt the state.
        """

    @abstractmethod
    def poll(self, now: float) -> Snapshot:
        """The state at tick time ``now``, with the peak latch; resets the latch."""

    @abstractmethod
    def snapshot(self) -> Snapshot:
        """The current state without touching the latch."""

    @property
    @abstractmethod
    def tripped(self) -> bool:
        """True while the model is tripped (no latch)."""
