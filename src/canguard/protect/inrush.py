"""Inrush blanking: a higher (or no) overcurrent threshold just after a motor start.

A *motor start* is |I| rising above ``start_current_a`` after having been at or
below it for at least ``inrush_time_s`` (with a zero-order hold of the samples:
the current is taken to stay at a sample's value until the next one, so the time
"below" runs from the first sample at or below ``start_current_a`` to the sample
that rises above it). A start opens a blanking window of ``inrush_time_s``
seconds, ``[t_start, t_start + inrush_time_s)``, during which the overcurrent
threshold in force is ``inrush_threshold_a`` (or no overcurrent check at all when
it is None).

Fail safe: before the current has been seen below ``start_current_a`` for
``inrush_time_s`` no start is recognised, so a motor already running (or starting)
when canguard starts is checked against the normal threshold. Dips shorter than
``inrush_time_s`` do not re-arm the blanking, so a chattering current cannot keep
the check off. I²t models are not blanked: heat is heat.

Over a run of samples the starts are a column computation: the stretches of
samples at or below ``start_current_a`` and their start times, a start where such
a stretch long enough ends, and the window in force at each sample the latest
start before it. This is a helper of :class:`~canguard.protect.hysteresis.Hysteresis`,
not a protection model itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from canguard.protect.base import TIME_EPS_S
from canguard.protect.columns import FloatArray, as_run, in_order, last_marked, stretch_begins, stretch_start_times
from canguard.protect.threshold import check_limit


def in_window(start: Any, t: Any, length_s: float) -> Any:
    """``start <= t < start + length_s`` (the end less TIME_EPS_S), for floats or numpy columns alike.

    A NaN start (no window) is never in force.
    """
    return (start <= t) & (t < start + length_s - TIME_EPS_S)


@dataclass(frozen=True)
class InrushScan:
    """Inrush blanking over a run of samples (nothing changed yet): see :meth:`InrushBlanking.scan`.

    ``started``: the samples that are motor starts. ``blanking``: the samples inside a
    blanking window. ``window_start``: the window start in force at each sample (NaN: none).
    """

    helper: InrushBlanking
    t: FloatArray
    below: npt.NDArray[np.bool_]
    below_since: FloatArray
    started: npt.NDArray[np.bool_]
    window_start: FloatArray
    blanking: npt.NDArray[np.bool_]

    def commit(self, k: int) -> None:
        """Give the helper the state right after sample ``k`` of the scanned run."""
        self.helper.take_scan(self, k)


class InrushBlanking:
    """Tracks motor starts and tells which overcurrent threshold is in force.

    ``start_current_a`` (A): above it the motor counts as running.
    ``inrush_time_s`` (s): how long the motor must have been stopped for a rise
    to count as a start, and how long the blanking window lasts.
    ``inrush_threshold_a`` (A): the threshold during the window; None turns the
    overcurrent check off during the window.
    """

    def __init__(
        self, start_current_a: float, inrush_time_s: float, inrush_threshold_a: float | None = None
    ) -> None:
        self.start_current_a = check_limit("start_current_a", start_current_a)
        self.inrush_time_s = check_limit("inrush_time_s", inrush_time_s)
        self.inrush_threshold_a = (
            None if inrush_threshold_a is None else check_limit("inrush_threshold_a", inrush_threshold_a)
        )
        self._below_since: float | None = None
        self._window_start: float | None = None
        self._last_t: float | None = None
        self.starts = 0
        """Motor starts recognised so far."""

    @property
    def window_start(self) -> float | None:
        """Time of the latest recognised motor start, None if none yet."""
        return self._window_start

    def scan(self, t: FloatArray, a: FloatArray) -> InrushScan:
        """Starts and windows over accepted |I| samples ``a`` at times ``t`` (in order, finite); nothing changes.

        :meth:`InrushScan.commit` then takes the state after any of its samples.
        """
        below = a <= self.start_current_a
        begins = stretch_begins(below, np.zeros(a.size, dtype=bool), self._below_since)
        since = stretch_start_times(begins, below, t, self._below_since)
        was_below = np.empty(a.size, dtype=bool)
        quiet = np.empty(a.size)
        if a.size:
            was_below[0] = self._below_since is not None
            was_below[1:] = below[:-1]
            quiet[0] = math.nan if self._below_since is None else self._below_since
            quiet[1:] = since[:-1]
        started = ~below & was_below & (t - quiet >= self.inrush_time_s - TIME_EPS_S)
        latest = last_marked(started)
        before = math.nan if self._window_start is None else self._window_start
        window = np.where(latest >= 0, t[np.maximum(latest, 0)], before)
        blanking = in_window(window, t, self.inrush_time_s)
        return InrushScan(self, t, below, since, started, window, blanking)

    def take_scan(self, scan: InrushScan, k: int) -> None:
        """Take the state right after sample ``k`` of a run this helper scanned."""
        self._last_t = float(scan.t[k])
        self._below_since = float(scan.below_since[k]) if scan.below[k] else None
        w = float(scan.window_start[k])
        self._window_start = None if math.isnan(w) else w
        self.starts += int(np.count_nonzero(scan.started[: k + 1]))

    def advance(self, times: npt.ArrayLike, abs_values: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Feed a run of |I| samples; which of them are motor starts (each opens a window).

        Samples older than the latest one, and non-finite ones, are ignored (never a start).
        """
        t, a = as_run(times, abs_values)
        ok = in_order(t, np.isfinite(a) & np.isfinite(t), self._last_t)
        picked = ok.nonzero()[0]
        out = np.zeros(t.size, dtype=bool)
        if picked.size:
            scan = self.scan(t[picked], np.abs(a[picked]))
            scan.commit(picked.size - 1)
            out[picked] = scan.started
        return out

    def observe(self, abs_value: float, t: float) -> bool:
        """Feed one |I| sample at ``t`` (a run of one); True when it is a motor start (opens a window)."""
        return bool(self.advance((t,), (abs_value,))[0])

    def carry_from(self, old: InrushBlanking) -> None:
        """Continue the start detection and the open window of the helper this one replaces."""
        self._below_since, self._window_start, self._last_t, self.starts = old.running()

    def running(self) -> tuple[float | None, float | None, float | None, int]:
        """What a reload carries: (quiet since, window start, latest time, starts so far)."""
        return self._below_since, self._window_start, self._last_t, self.starts

    def blanking(self, t: float) -> bool:
        """True when ``t`` lies inside a blanking window."""
        w = self._window_start
        return w is not None and bool(in_window(w, t, self.inrush_time_s))

    def threshold(self, normal: float, t: float) -> float | None:
        """The overcurrent threshold in force at ``t``: ``normal`` outside a window,
        ``inrush_threshold_a`` inside one (None: no overcurrent check)."""
        if self.blanking(t):
            return self.inrush_threshold_a
        return normal
