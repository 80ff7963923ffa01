"""Protection models: pure state machines that take time as an argument and advance over runs of samples.

Every model's one entry point is ``advance(times, values, until_edge) -> Run`` (a sample is a run of
one): :mod:`canguard.protect.base` gives the contract, docs/protection.md the models.

- :class:`Threshold`: a plain limit with a peak latch (IsCurrentNormal, IsJointEffortNormal).
- :class:`Hysteresis`: trip / recovery thresholds, optional persistence and inrush blanking (IsCurrentSafe).
- :class:`InrushBlanking`: the threshold in force just after a motor start.
- :class:`LeakyI2t`, :class:`ThermalI2t`: I²t heat, exported to / restored from :class:`HeatStore`.
- :class:`SourceHealth`: no data, stale, not present, NaN/inf, out of range.
"""

from canguard.protect.base import LatchedModel, ProtectionModel, Run, Snapshot
from canguard.protect.hysteresis import Hysteresis
from canguard.protect.i2t import LeakyI2t, ThermalI2t, thermal_tau
from canguard.protect.inrush import InrushBlanking
from canguard.protect.staleness import SourceHealth
from canguard.protect.state import HeatModel, HeatStore
from canguard.protect.threshold import Threshold

__all__ = [
    "HeatModel",
    "HeatStore",
    "Hysteresis",
    "InrushBlanking",
    "LatchedModel",
    "LeakyI2t",
    "ProtectionModel",
    "Run",
    "Snapshot",
    "SourceHealth",
    "ThermalI2t",
    "Threshold",
    "thermal_tau",
]
