"""The simulated robot's motion: each axis' 4 s duty cycle, its current, and the battery pack it draws on."""

from __future__ import annotations

import bisect
import math
import random
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from canguard.sim.scenarios import Scenario

AXIS_STATE_IDLE = 1
AXIS_STATE_CLOSED_LOOP = 8
ERROR_ESTOP_REQUESTED = 0x04000000
"""ODrive ``ODriveError.ESTOP_REQUESTED``: set by an Estop, cleared by Clear_Errors."""

KT_NM_PER_A = 8.27 / 100.0
BASE_LOAD_A = 2.0
PACK_R_OHM = 0.04
PACK_CELLS = 13
PACK_CAPACITY_AH = 20.0
START_SOC_PCT = 85.0
STOP_TAU_S = 0.002
RESUME_TAU_S = 0.02
IQ_NOISE_A = 0.03
IDLE_NOISE_A = 0.005
PACK_NOISE_A = 0.05
JITTER_S = 20e-6

# Duty cycle: one 4 s back-and-forth move per axis, as (start_s, current setpoint).
_CYCLE_S = 4.0
_RAMP_S = 0.02
_ACCEL_A, _CRUISE_A, _BRAKE_A, _HOLD_A = 7.0, 2.0, 4.0, 1.0
_SEGMENTS: tuple[tuple[float, float], ...] = (
    (0.00, +_ACCEL_A), (0.25, +_CRUISE_A), (0.75, -_BRAKE_A), (1.00, +_HOLD_A),
    (2.00, -_ACCEL_A), (2.25, -_CRUISE_A), (2.75, +_BRAKE_A), (3.00, +_HOLD_A),
)
_SEG_STARTS = [s for s, _ in _SEGMENTS]
_VMAX_REV_S = 2.0
_STAGGER_S = 0.5


@dataclass
class _Axis:
    """One simulated ODrive axis' state."""

    index: int
    scale: float
    state: int = AXIS_STATE_CLOSED_LOOP
    errors: int = 0
    edge_t: float = -math.inf
    edge_i: float = 0.0
    pos_rev: float = 0.0
    enc_t: float = 0.0


class Motion:
    """Setpoints, currents and the battery pack of the simulated robot: functions of time and the axes' state."""

    def __init__(self, rng: random.Random, axes: list[_Axis], setpoint_hooks: list[Scenario]) -> None:
        self.rng = rng
        self.axes = axes
        self.setpoint_hooks = setpoint_hooks
        self.soc_pct = START_SOC_PCT

    def duty(self, ax: _Axis, t: float) -> float:
        """The duty cycle's current setpoint: trapezoid moves with 20 ms ramps."""
        u = (t + ax.index * _STAGGER_S) % _CYCLE_S
        i = bisect.bisect_right(_SEG_STARTS, u) - 1
        start, level = _SEGMENTS[i]
        into = u - start
        if into < _RAMP_S:
            prev = _SEGMENTS[i - 1][1]
            level = prev + (level - prev) * into / _RAMP_S
        return level * ax.scale

    def velocity(self, ax: _Axis, t: float) -> float:
        """Velocity of the duty cycle's move (rev/s): trapezoid rising while accelerating."""
        u = (t + ax.index * _STAGGER_S) % _CYCLE_S
        sign = 1.0 if u < 2.0 else -1.0
        u %= 2.0
        v = max(0.0, min(u / 0.25, 1.0, (1.0 - u) / 0.25))  # 0.25 s up, 0.5 s at full speed, 0.25 s down, then still
        return sign * v * _VMAX_REV_S * ax.scale

    def setpoint(self, ax: _Axis, t: float) -> float:
        """The current setpoint: the duty cycle's as the scenarios change it; 0 unless in closed loop."""
        if ax.state != AXIS_STATE_CLOSED_LOOP:
            return 0.0
        iq = self.duty(ax, t)
        for sc in self.setpoint_hooks:
            iq = sc.setpoint(ax.index, t, iq)
        return iq

    def current(self, ax: _Axis, t: float) -> float:
        """Noise-free Iq: the setpoint in closed loop (after a resume ramp), a decay when idle."""
        dt = t - ax.edge_t
        if ax.state == AXIS_STATE_CLOSED_LOOP:
            sp = self.setpoint(ax, t)
            if dt < 10 * RESUME_TAU_S:
                return sp + (ax.edge_i - sp) * math.exp(-max(dt, 0.0) / RESUME_TAU_S)
            return sp
        if dt > 30 * STOP_TAU_S:
            return 0.0
        return ax.edge_i * math.exp(-max(dt, 0.0) / STOP_TAU_S)

    def measured(self, ax: _Axis, t: float) -> float:
        """Iq as the drive measures it (with noise)."""
        noise = IQ_NOISE_A if ax.state == AXIS_STATE_CLOSED_LOOP else IDLE_NOISE_A
        return self.current(ax, t) + self.rng.gauss(0.0, noise)

    def pack_current(self, t: float) -> float:
        """The BMS's pack current: base load + Σ|Iq| + noise."""
        total = BASE_LOAD_A + sum(abs(self.current(ax, t)) for ax in self.axes)
        return total + self.rng.gauss(0.0, PACK_NOISE_A)

    def pack_voltage(self, current_a: float) -> float:
        """Open-circuit voltage at the state of charge, less the pack's resistance drop."""
        ocv = PACK_CELLS * (3.3 + 0.9 * self.soc_pct / 100.0)
        return ocv - PACK_R_OHM * current_a
