"""Column helpers of the models' run maths: a run's columns, its order filter, edges, latches and stretches.

Every helper works on the samples of one run (1-D numpy columns, times in order where it
says so) and has no state of its own.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IndexArray = npt.NDArray[np.intp]


def as_run(times: npt.ArrayLike, values: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Both columns of a run as float64 arrays; ValueError when they are not 1-D of one length."""
    t = np.asarray(times, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if t.ndim != 1 or t.shape != v.shape:
        raise ValueError(f"a run needs 1-D times and values of one length, got shapes {t.shape} and {v.shape}")
    return t, v


def in_order(t: FloatArray, finite: npt.NDArray[np.bool_], last_t: float | None) -> npt.NDArray[np.bool_]:
    """Which samples are not older than the latest accepted one before them (``finite``: the usable ones).

    A finite sample that is ignored as out of order is older than an accepted one, so the
    latest accepted time before each sample is the running maximum of the usable times
    (and of ``last_t``).
    """
    if t.size <= 1:
        return finite if last_t is None or t.size == 0 else finite & (t >= last_t)
    usable = np.where(finite, t, -np.inf)
    before = np.empty_like(usable)
    before[0] = -np.inf if last_t is None else last_t
    if usable.size > 1:
        np.maximum.accumulate(usable[:-1], out=before[1:])
        np.maximum(before[1:], before[0], out=before[1:])
    return finite & (t >= before)


def toggles(state: npt.NDArray[np.bool_], before: bool) -> IndexArray:
    """Positions where the boolean column ``state`` differs from its previous entry (``before`` for the first)."""
    if state.size <= 1:
        return (state != before).nonzero()[0]
    changed = np.empty(state.size, dtype=bool)
    changed[0] = bool(state[0]) != before
    np.not_equal(state[1:], state[:-1], out=changed[1:])
    return changed.nonzero()[0]


def last_marked(mark: npt.NDArray[np.bool_]) -> IndexArray:
    """For each position, the latest position at or before it where ``mark`` is set (-1: none yet)."""
    pos = np.where(mark, np.arange(mark.size), -1)
    np.maximum.accumulate(pos, out=pos)
    return pos


def hold(on: npt.NDArray[np.bool_], off: npt.NDArray[np.bool_], before: bool) -> npt.NDArray[np.bool_]:
    """A set/reset latch over a column: True from an ``on`` sample, False from an ``off`` one, else held.

    ``on`` wins where both are set; ``before`` is the state before the first sample.
    """
    pos = last_marked(on | off)
    out = np.where(pos >= 0, on[np.maximum(pos, 0)], before)
    return np.asarray(out, dtype=bool)


def stretch_begins(cond: npt.NDArray[np.bool_], breaks: npt.NDArray[np.bool_], before: float | None
                   ) -> npt.NDArray[np.bool_]:
    """The samples that begin a stretch of consecutive ``cond`` samples.

    A stretch ends at a sample without ``cond`` and before a sample with ``breaks`` set (a
    gap). ``before``: the start time of a stretch already running before the first sample
    (None: none), which a first sample with ``cond`` and no break continues (no begin there).
    """
    begins = cond.copy()
    begins[1:] &= ~cond[:-1] | breaks[1:]
    if before is not None and cond.size and not breaks[0]:
        begins[0] = False
    return begins


def stretch_start_times(begins: npt.NDArray[np.bool_], cond: npt.NDArray[np.bool_], t: FloatArray,
                        before: float | None) -> FloatArray:
    """When the stretch each ``cond`` sample belongs to began (entries of other samples are meaningless).

    The times are in order, so the latest begin's time is the running maximum of the begins'
    times, ``before`` standing for the stretch carried in (it is not later than any sample).
    """
    marks = np.where(begins, t, -np.inf)
    if before is not None and cond.size and cond[0] and not begins[0]:
        marks[0] = before
    return np.maximum.accumulate(marks)
