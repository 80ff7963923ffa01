"""What the protection models report: a :class:`Snapshot` of their state, a :class:`Run` of a run's edges."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from canguard.protect.columns import BoolArray, FloatArray, IndexArray


@dataclass(frozen=True)
class Snapshot:
    """A model's state for events, metrics and plots: latest |value|, trip threshold in force (I²t: the trip level),
    % of it, tripped (``poll``: latched), the last edge's time, and the reason ("" when fine)."""

    value: float
    threshold: float
    level_pct: float
    tripped: bool
    since: float | None
    reason: str


@dataclass(slots=True)
class Run:
    """What ``advance`` did with a run: the positions, times and states entered of its edges, and the samples
    ``taken`` (fewer when ``until_edge`` stopped). Read only (not frozen: that costs a run of one time)."""

    index: IndexArray
    t: FloatArray
    tripped: BoolArray
    taken: int
    changed: bool = field(init=False)
    """True when the run had an edge (tick the tree)."""

    def __post_init__(self) -> None:
        self.changed = bool(self.index.size)


QUIET_RUNS: dict[int, Run] = {}
"""The shared :class:`Run` of ``n`` short samples taken without an edge."""
quiet_cached = QUIET_RUNS.get
"""``quiet_cached(n) or quiet_run(n)``: a cached result without building a bound method per call."""


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
    """The result of a run with edges (lists or numpy columns)."""
    import numpy as np

    return Run(np.array(index, dtype=np.intp), np.array(times, dtype=np.float64), np.array(states, dtype=bool), taken)
