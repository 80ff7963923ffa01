"""Clocks: the only place canguard reads the time.

:class:`LiveClock` live, :class:`ManualClock` in replay and tests; ``protect/`` and ``nodes/`` are handed one."""

from __future__ import annotations

import math
import time
from typing import Protocol


class Clock(Protocol):
    """Tells the time in the frames' time base (seconds)."""

    def now(self) -> float:
        """The current time in seconds."""
        ...

    def advance_to(self, t: float) -> None:
        """Move to ``t`` if this clock is driven (replay); live clocks ignore it."""
        ...


class ManualClock:
    """A clock that only moves when told, and never backwards by :meth:`advance_to` (a log going back in time)."""

    def __init__(self, start: float = 0.0) -> None:
        self._now = float(start)

    def now(self) -> float:
        """The current time."""
        return self._now

    def set(self, t: float) -> None:
        """Set the time, backwards included (tests only)."""
        self._now = float(t)

    def advance_to(self, t: float) -> None:
        """Move forward to ``t``; a ``t`` in the past is ignored."""
        self._now = max(self._now, t)


class LiveClock:
    """Epoch seconds advancing with the monotonic clock (a wall-clock step does not move canguard's time)."""

    def __init__(self) -> None:
        self._offset = time.time() - time.monotonic()

    def now(self) -> float:
        """The current time in epoch seconds, monotonic."""
        return time.monotonic() + self._offset

    def advance_to(self, t: float) -> None:
        """Live time moves by itself: a no-op, so the engine drives both clocks alike."""


class PinnedClock:
    """The engine's view of a clock: never goes back, and stands still for a tick (one ``now`` per tick)."""

    def __init__(self, inner: Clock) -> None:
        self.inner = inner
        self._pinned: float | None = None
        self._last = -math.inf

    def now(self) -> float:
        """The pinned time during a tick; otherwise the inner clock's, never below the last pin."""
        return self._pinned if self._pinned is not None else max(self._last, self.inner.now())

    def advance_to(self, t: float) -> None:
        """Drive the inner clock (replay); live clocks ignore it."""
        self.inner.advance_to(t)

    def pin(self, t: float) -> float:
        """Stand still at ``t`` (or at the last pin, if that is later) until :meth:`unpin`; returns the pin."""
        self._pinned = self._last = max(t, self._last)
        return self._pinned

    def unpin(self) -> None:
        """Let time move again."""
        self._pinned = None


BOOT_ID_PATH = "/proc/sys/kernel/random/boot_id"


class BootClock:
    """Downtime a wall-clock step cannot fake (the I²t state's stamp): ``CLOCK_BOOTTIME``'s within one boot (an NTP
    correction after boot is no hours of cooling), else the wall clock's."""

    @staticmethod
    def boot_id() -> str | None:
        """This boot's id, None where the kernel does not tell."""
        try:
            with open(BOOT_ID_PATH, encoding="ascii") as f:
                return f.read().strip() or None
        except OSError:
            return None

    @staticmethod
    def since_boot() -> float | None:
        """Seconds since boot (CLOCK_BOOTTIME), None where there is no such clock."""
        clock = getattr(time, "CLOCK_BOOTTIME", None)
        return None if clock is None else time.clock_gettime(clock)

    def stamp(self) -> dict[str, object]:
        """What a save records: ``{"boot_id": ..., "since_boot_s": ...}``."""
        return {"boot_id": self.boot_id(), "since_boot_s": self.since_boot()}

    def downtime(self, saved: object, wall_downtime_s: float) -> float:
        """Seconds since a save stamped ``saved``: boot time within one boot, else the wall-clock difference."""
        if isinstance(saved, dict):
            boot, since = saved.get("boot_id"), saved.get("since_boot_s")
            now_since = self.since_boot()
            if boot is not None and boot == self.boot_id() and isinstance(since, (int, float)) \
                    and now_since is not None and math.isfinite(since):
                return max(0.0, now_since - float(since))
        return wall_downtime_s
