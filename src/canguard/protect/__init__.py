"""Protection models: pure, per-sample state machines that take time as an argument.

- :class:`Threshold`: a plain limit with a peak latch (IsCurrentNormal, IsJointEffortNormal).
- :class:`Hysteresis`: trip / recovery thresholds, optional persistence and inrush blanking (IsCurrentSafe).
- :class:`InrushBlanking`: the threshold in force just after a motor start.
- :class:`LeakyI2t`, :class:`ThermalI2t`: I²t heat, exported to / restored from :class:`HeatStore`.
- :class:`SourceHealth`: no data, stale, not present, NaN/inf, out of range.
"""

from .base import LatchedModel, ProtectionModel, Snapshot
from .hysteresis import Hysteresis
from .i2t import LeakyI2t, ThermalI2t, thermal_tau
from .inrush import InrushBlanking
from .staleness import SourceHealth
from .state import HeatModel, HeatStore
from .threshold import Threshold

__all__ = [
    "HeatModel",
    "HeatStore",
    "Hysteresis",
    "InrushBlanking",
    "LatchedModel",
    "LeakyI2t",
    "ProtectionModel",
    "Snapshot",
    "SourceHealth",
    "ThermalI2t",
    "Threshold",
    "thermal_tau",
]
