"""What clients of the monitors did wrong, logged as one line per cause at most every :data:`EVERY_S`."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

EVERY_S = 60.0
"""Shortest time between two lines of the same cause; the ones between are counted into the next."""


class ClientNotes:
    """Per cause: the first occurrence logged at once, then at most one line per :data:`EVERY_S` with the count."""

    def __init__(self, log: logging.Logger, server: str, clock: Callable[[], float] = time.monotonic) -> None:
        self._log = log
        self._server = server
        self._clock = clock
        self._causes: dict[str, tuple[float, int]] = {}
        """cause -> (when its next line may be written, occurrences not yet logged)."""

    def note(self, cause: str) -> None:
        """One more occurrence of ``cause`` (a sentence of what the client did and what was done about it)."""
        now = self._clock()
        next_s, held = self._causes.get(cause, (-1.0, 0))
        if now < next_s:
            self._causes[cause] = (next_s, held + 1)
            return
        self._causes[cause] = (now + EVERY_S, 0)
        more = f" ({held} more times since the last such line)" if held else ""
        self._log.warning("%s: %s%s", self._server, cause, more)
