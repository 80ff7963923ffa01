"""At most one report a second per key: a fault that repeats every frame must not flood stderr or the journal."""

from __future__ import annotations

import math
from collections.abc import Hashable

REPORT_INTERVAL_S = 1.0
"""One report per key per this many seconds."""


class RateLimit:
    """Decides which of many equal reports to make: the first per key per ``interval_s``, counting the rest."""

    def __init__(self, interval_s: float = REPORT_INTERVAL_S) -> None:
        self.interval_s = interval_s
        self._last: dict[Hashable, float] = {}
        self._held: dict[Hashable, int] = {}

    def allow(self, key: Hashable, now: float) -> int | None:
        """None when this report is held back (and counted); else how many were held back before it."""
        if now - self._last.get(key, -math.inf) < self.interval_s:
            self._held[key] = self._held.get(key, 0) + 1
            return None
        self._last[key] = now
        return self._held.pop(key, 0)

    def held(self) -> int:
        """Reports held back and not yet accounted for by a later one (all keys)."""
        return sum(self._held.values())


def held_note(held: int, interval_s: float = REPORT_INTERVAL_S) -> str:
    """``"; 12 more like it held back (...)"`` (empty for none): what a report stands for besides itself."""
    return f"; {held} more like it held back (at most one report per {interval_s:g} s)" if held else ""
