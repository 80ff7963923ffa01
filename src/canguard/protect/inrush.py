"""Inrush blanking: a higher (or no) overcurrent threshold just after a motor start (docs/protection.md)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from canguard.protect.base import TIME_EPS_S, check_limit
from canguard.protect.columns import as_run, in_order

if TYPE_CHECKING:
    import numpy.typing as npt

    from canguard.protect.columns import BoolArray, FloatArray


def in_window(start: Any, t: Any, length_s: float) -> Any:
    """``start <= t < start + length_s`` (less TIME_EPS_S; a NaN start never), for floats or numpy columns."""
    return (start <= t) & (t < start + length_s - TIME_EPS_S)


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
        self.starts = 0
        """Motor starts recognised so far."""

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
            self.starts += 1
        return started

    def advance(self, times: npt.ArrayLike, abs_values: npt.ArrayLike) -> BoolArray:
        """Feed a run of |I| samples; which of them are motor starts (ignored: out of order, not finite)."""
        import numpy as np

        t, a = as_run(times, abs_values)
        ok = in_order(t, np.isfinite(a) & np.isfinite(t), self._last_t)
        picked = ok.nonzero()[0]
        out = np.zeros(t.size, dtype=bool)
        out[picked[self.starts_in(t[picked], np.abs(a[picked]))]] = True
        return out

    def starts_in(self, t: FloatArray, a: FloatArray) -> list[int]:
        """Feed accepted |I| samples; the positions of the motor starts among them.

        Only a rise after a long enough low stretch can be a start: those go to :meth:`observe`.
        """
        import numpy as np

        if not t.size:
            return []
        below = a <= self.start_current_a
        flips = np.empty(a.size, dtype=bool)
        flips[0] = bool(below[0]) != (self._below_since is not None)
        np.not_equal(below[1:], below[:-1], out=flips[1:])
        began = np.maximum.accumulate(np.where(flips & below, t, -np.inf))
        if self._below_since is not None:
            np.maximum(began, self._below_since, out=began)
        rises = flips & ~below
        rises[rises] = t[rises] - began[rises] >= self.inrush_time_s - TIME_EPS_S
        started: list[int] = []
        for j in rises.nonzero()[0].tolist():
            self._last_t = float(t[j - 1]) if j else self._last_t
            self._below_since = float(began[j])
            if self.observe(float(a[j]), float(t[j])):
                started.append(j)
        self._last_t = float(t[-1])
        self._below_since = float(began[-1]) if below[-1] else None
        return started

    def windows(self, t: FloatArray, started: list[int], before: float | None) -> FloatArray:
        """The window start in force at each time ``t`` (NaN: none), given the starts and the one ``before``."""
        import numpy as np

        latest = np.full(t.size, -1)
        latest[started] = started
        np.maximum.accumulate(latest, out=latest)
        return np.where(latest >= 0, t[np.maximum(latest, 0)], math.nan if before is None else before)

    def resume(self, state: tuple[float | None, float | None, float | None, int]) -> None:
        """Go back to (or, on a reload, take over) a state :meth:`running` gave."""
        self._below_since, self._window_start, self._last_t, self.starts = state

    def running(self) -> tuple[float | None, float | None, float | None, int]:
        """The running state: (quiet since, window start, latest time, starts so far)."""
        return self._below_since, self._window_start, self._last_t, self.starts

    def blanking(self, t: float) -> bool:
        """True when ``t`` lies inside a blanking window."""
        w = self._window_start
        return w is not None and bool(in_window(w, t, self.inrush_time_s))

    def threshold(self, normal: float, t: float) -> float | None:
        """The overcurrent threshold in force at ``t``: ``normal``, or ``inrush_threshold_a`` in a window."""
        return self.inrush_threshold_a if self.blanking(t) else normal
