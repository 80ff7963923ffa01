"""At most one report a second per key: a fault that repeats every frame must not flood stderr or the journal."""

from __future__ import annotations

import math
from collections.abc import Hashable

REPORT_INTERVAL_S = 1.0
"""One report per key per this many seconds."""


class RateLimit:
    """Decides which of many equal reports to make: the first per key per :data:`REPORT_INTERVAL_S`, counting the
    rest."""

    def __init__(self) -> None:
        self._last: dict[Hashable, float] = {}
        self._held: dict[Hashable, int] = {}

    def allow(self, key: Hashable, now: float) -> int | None:
        """None when this report is held back (and counted); else how many were held back before it."""
        if now - self._last.get(key, -math.inf) < REPORT_INTERVAL_S:
            self._held[key] = self._held.get(key, 0) + 1
            return None
        self._last[key] = now
        return self._held.pop(key, 0)


def held_note(held: int) -> str:
    """``"; 12 more like it held back (...)"`` (empty for none): what a report stands for besides itself."""
    return f"; {held} more like it held back (at most one report per {REPORT_INTERVAL_S:g} s)" if held else ""
