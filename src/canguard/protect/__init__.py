"""Protection models: pure state machines that take time as an argument and advance over runs of samples."""

from canguard.protect.base import LatchedModel, ProtectionModel, Run, Snapshot
from canguard.protect.hysteresis import Hysteresis
from canguard.protect.i2t import LeakyI2t, ThermalI2t, thermal_tau
from canguard.protect.inrush import InrushBlanking
from canguard.protect.staleness import SourceHealth
from canguard.protect.state import HeatModel, HeatStore
from canguard.protect.threshold import Threshold

__all__ = ["HeatModel", "HeatStore", "Hysteresis", "InrushBlanking", "LatchedModel", "LeakyI2t", "ProtectionModel",
           "Run", "Snapshot", "SourceHealth", "ThermalI2t", "Threshold", "thermal_tau"]
