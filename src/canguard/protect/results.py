"""What the protection models report: a :class:`Snapshot` of their state, a :class:`Run` of a run's edges."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from canguard.protect.columns import BoolArray, FloatArray, IndexArray


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


@dataclass(slots=True)
class Run:
    """What :meth:`ProtectionModel.advance` did with a run of samples.

    ``index``: positions in the run (int) of the samples at which the tripped state
    changed, ascending. ``t``: their times (s). ``tripped``: the state entered at
    each (they alternate). ``taken``: samples consumed from the start of the run
    (all of them unless ``until_edge`` stopped early). A result: read it, never
    change it (not frozen only because a frozen dataclass costs a run of one ~1 µs more).
    """

    index: IndexArray
    t: FloatArray
    tripped: BoolArray
    taken: int
    changed: bool = field(init=False)
    """True when the run changed the tripped state at least once (an edge: tick the tree)."""

    def __post_init__(self) -> None:
        self.changed = bool(self.index.size)
