"""What the protection models report: a :class:`Snapshot` of their state, a :class:`Run` of a run's edges."""

from __future__ import annotations

from collections.abc import Sequence
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
    """What a model's (or a source health's) ``advance`` did with a run of samples.

    ``index``: positions in the run (int) of the samples at which the state changed (an edge),
    ascending. ``t``: their times (s). ``tripped``: the state entered at each (a model's: they
    alternate; a source health's: unusable). ``taken``: samples consumed from the start of
    the run (all of them unless ``until_edge`` stopped early). A result: read it, never
    change it (not frozen only because a frozen dataclass costs a run of one ~1 µs more).
    """

    index: IndexArray
    t: FloatArray
    tripped: BoolArray
    taken: int
    changed: bool = field(init=False)
    """True when the run changed the state at least once (an edge: tick the tree)."""

    def __post_init__(self) -> None:
        self.changed = bool(self.index.size)


QUIET_RUNS: dict[int, Run] = {}
"""The :class:`Run` of ``n`` samples taken without an edge, by ``n`` (short runs: built once each, shared)."""
quiet_cached = QUIET_RUNS.get
"""``quiet_cached(n) or quiet_run(n)``: a cached result with no Python call (``QUIET_RUNS.get`` on a name an
import bound compiles to an attribute load that builds a bound method at each call)."""


def quiet_run(n: int) -> Run:
    """The result of a run of ``n`` samples that changed nothing (shared: a result is only read)."""
    run = QUIET_RUNS.get(n)
    if run is None:
        none = QUIET_RUNS.get(0)
        if none is None:
            import numpy as np

            none = QUIET_RUNS[0] = Run(np.empty(0, dtype=np.intp), np.empty(0), np.empty(0, dtype=bool), 0)
            for column in (none.index, none.t, none.tripped):
                column.flags.writeable = False
        run = Run(none.index, none.t, none.tripped, n)
        if n <= 64:
            QUIET_RUNS[n] = run
    return run


def edges(index: Sequence[int] | IndexArray, times: Sequence[float] | FloatArray, states: Sequence[bool],
          taken: int) -> Run:
    """The result of a run with edges: their positions, times and the states entered (lists or numpy columns)."""
    import numpy as np

    return Run(np.array(index, dtype=np.intp), np.array(times, dtype=np.float64), np.array(states, dtype=bool), taken)


def alternate(last: bool, n: int) -> list[bool]:
    """The states entered at ``n`` alternating edges, the last one entering ``last``."""
    return [last == ((n - 1 - i) % 2 == 0) for i in range(n)]
