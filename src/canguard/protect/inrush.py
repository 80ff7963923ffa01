"""Inrush blanking: a higher (or no) overcurrent threshold just after a motor start (docs/protection.md)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from canguard.protect.base import TIME_EPS_S, check_limit
from canguard.protect.columns import as_run

if TYPE_CHECKING:
    import numpy.typing as npt

    from canguard.protect.columns import BoolArray


class InrushBlanking:
    """Tracks motor starts (|I| above ``start_current_a`` after ``inrush_time_s`` at or below it) and tells which
    overcurrent threshold is in force (``inrush_threshold_a`` in a window; None: no check); a Hysteresis helper."""

    def __init__(self, start_current_a: float, inrush_time_s: float, inrush_threshold_a: float | None = None) -> None:
        self.start_current_a = check_limit("start_current_a", start_current_a)
        self.inrush_time_s = check_limit("inrush_time_s", inrush_time_s)
        self.inrush_threshold_a = None if inrush_threshold_a is None else check_limit("inrush_threshold_a",
                                                                                      inrush_threshold_a)
        self._below_since: float | None = None
        self._window_start: float | None = None
        self._last_t: float | None = None

    def observe(self, abs_value: float, t: float) -> bool:
        """The kernel: one |I| sample at ``t``; True when it is a motor start (ignored: out of order, not finite)."""
        a, t = float(abs_value), float(t)
        if not (math.isfinite(a) and math.isfinite(t)) or (self._last_t is not None and t < self._last_t):
            return False
        self._last_t = t
        if a <= self.start_current_a:
            if self._below_since is None:
                self._below_since = t
            return False
        started = self._below_since is not None and t - self._below_since >= self.inrush_time_s - TIME_EPS_S
        self._below_since = None
        if started:
            self._window_start = t
        return started

    def advance(self, times: npt.ArrayLike, abs_values: npt.ArrayLike) -> BoolArray:
        """Feed a run of |I| samples; which of them are motor starts (ignored: out of order, not finite)."""
        import numpy as np

        t, a = as_run(times, abs_values)
        observe = self.observe
        return np.array([observe(x, s) for s, x in zip(t.tolist(), np.abs(a).tolist(), strict=True)], dtype=bool)

    def resume(self, state: tuple[float | None, float | None, float | None]) -> None:
        """Go back to (or, on a reload, take over) a state :meth:`running` gave."""
        self._below_since, self._window_start, self._last_t = state

    def running(self) -> tuple[float | None, float | None, float | None]:
        """The running state: (quiet since, window start, latest time)."""
        return self._below_since, self._window_start, self._last_t

    def threshold(self, normal: float, t: float) -> float | None:
        """The overcurrent threshold in force at ``t``: ``normal``, or ``inrush_threshold_a`` in a blanking window."""
        w = self._window_start
        return self.inrush_threshold_a if w is not None and w <= t < w + self.inrush_time_s - TIME_EPS_S else normal
