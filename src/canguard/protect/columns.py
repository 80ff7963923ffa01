"""Column helpers of the models' runs: a run's columns, the short-run check, the quiet screen's spans."""

from __future__ import annotations

import math
from itertools import islice
from operator import le, sub
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # numpy is imported by the first long run (or numpy column), not by importing the models
    import numpy as np
    import numpy.typing as npt

    FloatArray = npt.NDArray[np.float64]
    IndexArray = npt.NDArray[np.intp]
    BoolArray = npt.NDArray[np.bool_]

SHORT_RUN = 48
"""Runs up to this long go sample by sample to the kernel: the screen's fixed numpy cost is higher."""


def as_run(times: npt.ArrayLike, values: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Both columns of a run as float64 arrays; ValueError when they are not 1-D of one length."""
    import numpy as np

    t = np.asarray(times, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if t.ndim != 1 or t.shape != v.shape:
        raise ValueError(f"a run needs 1-D times and values of one length, got shapes {t.shape} and {v.shape}")
    return t, v


def short_run(times: npt.ArrayLike, values: npt.ArrayLike, most: int) -> tuple[list[float], list[float]] | None:
    """A run of at most ``most`` samples (lists, tuples, 1-D numpy) as two lists of floats; None: :func:`as_run`'s."""
    if isinstance(times, (tuple, list)) and isinstance(values, (tuple, list)):
        if not len(times) == len(values) <= most:
            return None
    else:
        import numpy as np  # not lists: numpy columns, or anything as_run converts (with numpy)

        if (isinstance(times, np.ndarray) and isinstance(values, np.ndarray)
                and times.ndim == values.ndim == 1 and times.size == values.size <= most):
            return times.astype(np.float64).tolist(), values.astype(np.float64).tolist()
        return None
    try:
        return list(map(float, times)), list(map(float, values))
    except (TypeError, ValueError):
        return None


def ordered(times: Any) -> bool:
    """A run's times are finite and never go back. Lists, or a numpy column."""
    first, final = float(times[0]), float(times[-1])
    if not (math.isfinite(first) and math.isfinite(final)):
        return False
    if len(times) < 2:
        return True
    if type(times) is list or type(times) is tuple:
        return all(map(le, times, islice(times, 1, None)))  # a NaN among them fails too
    import numpy as np

    with np.errstate(invalid="ignore"):  # inf - inf among times out of order: NaN, which fails
        return float((times[1:] - times[:-1]).min()) >= 0.0


def longest_step(times: Any) -> float:
    """The longest step between two times of a run that :func:`ordered` accepts (0 for one time)."""
    if len(times) < 2:
        return 0.0
    if type(times) is list or type(times) is tuple:
        return max(map(sub, islice(times, 1, None), times))
    return float((times[1:] - times[:-1]).max())


def values_span(values: Any) -> tuple[float, float] | None:
    """(lowest, highest) of a run's values when every one is finite, else None. Lists, or a numpy column."""
    if type(values) is list or type(values) is tuple:
        if not math.isfinite(sum(values)):
            return None
        return min(values), max(values)
    low, high = float(values.min()), float(values.max())  # NaN propagates
    return (low, high) if math.isfinite(low) and math.isfinite(high) else None
