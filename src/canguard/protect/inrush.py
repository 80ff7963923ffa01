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

This is a helper of :class:`~canguard.protect.hysteresis.Hysteresis`, not a
protection model itself.
"""

from __future__ import annotations

import math

from canguard.protect.base import TIME_EPS_S
from canguard.protect.threshold import check_limit


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

    def observe(self, abs_value: float, t: float) -> bool:
        """Feed one |I| sample at ``t``; True when it is a motor start (opens a window).

        Samples older than the latest one, and non-finite ones, are ignored.
        """
        if not (math.isfinite(abs_value) and math.isfinite(t)):
            return False
        if self._last_t is not None and t < self._last_t:
            return False
        self._last_t = t
        if abs(abs_value) <= self.start_current_a:
            if self._below_since is None:
                self._below_since = t
            return False
        started = self._below_since is not None and t - self._below_since >= self.inrush_time_s - TIME_EPS_S
        self._below_since = None
        if started:
            self._window_start = t
            self.starts += 1
        return started

    def carry_from(self, old: InrushBlanking) -> None:
        """Continue the start detection and the open window of the helper this one replaces."""
        self._below_since, self._window_start, self._last_t = old._below_since, old._window_start, old._last_t
        self.starts = old.starts

    def blanking(self, t: float) -> bool:
        """True when ``t`` lies inside a blanking window."""
        w = self._window_start
        return w is not None and w <= t < w + self.inrush_time_s - TIME_EPS_S

    def threshold(self, normal: float, t: float) -> float | None:
        """The overcurrent threshold in force at ``t``: ``normal`` outside a window,
        ``inrush_threshold_a`` inside one (None: no overcurrent check)."""
        if self.blanking(t):
            return self.inrush_threshold_a
        return normal
