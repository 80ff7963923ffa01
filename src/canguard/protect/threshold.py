"""A plain limit with a peak latch: behind IsCurrentNormal and IsJointEffortNormal.

Trips while |value| > ``max_value`` and clears as soon as |value| <= ``max_value``
(no hysteresis, exactly like the C++ nodes of design note 004, section 3.1/3.2).
Because it sees every sample and :meth:`poll` latches, a one-frame spike between
two ticks is still reported at the next tick (design note 004, section 5.1).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from canguard.protect.base import REASON_OVERCURRENT, LatchedModel
from canguard.protect.columns import Marks

if TYPE_CHECKING:
    from canguard.protect.columns import FloatArray


def check_limit(name: str, value: float) -> float:
    """Return ``value`` as float; ValueError naming ``name`` when it is negative or not finite."""
    v = float(value)
    if not math.isfinite(v) or v < 0:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return v


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
        """Tripped after a sample exactly when its |value| exceeds the limit: no state beyond that."""
        return a > self.max_value

    def _screen(self, t: FloatArray, a: FloatArray) -> Marks:
        """Only a sample on the other side of the limit changes anything."""
        over = a > self.max_value
        return Marks(over, ~over)

    def _quiet_side(self, t: Any, low_a: float, high_a: float) -> bool:
        """Every sample on the side of ``max_value`` the model is on."""
        if self._tripped:
            return low_a > self.max_value
        return not high_a > self.max_value

    def _threshold_value(self) -> float:
        return self.max_value

    def _level_pct(self) -> float:
        return level_pct(self._value, self.max_value)


def level_pct(value: float, threshold: float | None) -> float:
    """``value`` in % of ``threshold``: 0 before any value or with no threshold in force."""
    if threshold is None or math.isnan(value):
        return 0.0
    if threshold <= 0:
        return 100.0 if value > 0 else 0.0
    return min(100.0 * value / threshold, 1e12)
