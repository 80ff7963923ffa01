"""Values with their units, one way everywhere a person reads them."""

from __future__ import annotations

import math

AMPERE = "A"
AMPERE2_SECOND = "A²s"
"""A leaky I²t accumulator and its trip level: ∫(I² − I_cont²) dt."""
THETA = "θ"
"""A thermal I²t image: the heat as a fraction of the steady heat at I_cont (trips at 1)."""
I2T_LIMIT_PCT = "% of the I²t limit"
"""An I²t guard's level: its accumulator in % of its trip level (100 = trip)."""

DIGITS = 6
"""Significant digits a quantity is printed with (the JSON summary keeps its own rounding)."""


def quantity(value: float | int | None, unit: str | None, digits: int = DIGITS) -> str:
    """``value`` and its ``unit``: ``31.6 A``, ``300 A²s``, ``99.8 % of the I²t limit``; ``no data`` for None/NaN."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "no data"
    number = f"{value:.{digits}g}"
    return f"{number} {unit}" if unit else number
