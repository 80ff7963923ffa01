"""A plain limit with a peak latch: behind IsCurrentNormal and IsJointEffortNormal (docs/protection.md)."""

from __future__ import annotations

import math
from typing import Any

from canguard.protect.base import REASON_OVERCURRENT, LatchedModel, check_limit


class Threshold(LatchedModel):
    """Tripped while |value| > ``max_value`` (A, or N·m for efforts); reason ``overcurrent``."""

    reason_tripped = REASON_OVERCURRENT

    def __init__(self, max_value: float) -> None:
        super().__init__()
        self.max_value = check_limit("max_value", max_value)

    def set_max(self, max_value: float) -> None:
        """Change the limit at run time (validated like the constructor); applies from the next sample."""
        self.max_value = check_limit("max_value", max_value)

    def _step(self, t: float, a: float) -> bool:
        return a > self.max_value

    def _quiet(self, t: Any, low_a: float, high_a: float, final_a: float) -> bool:
        return low_a > self.max_value if self._tripped else not high_a > self.max_value

    def _levels(self) -> tuple[float, float]:
        return self.max_value, level_pct(self._value, self.max_value)


def level_pct(value: float, threshold: float | None) -> float:
    """``value`` in % of ``threshold``: 0 before any value or with no threshold in force."""
    if threshold is None or math.isnan(value):
        return 0.0
    if threshold <= 0:
        return 100.0 if value > 0 else 0.0
    return min(100.0 * value / threshold, 1e12)
