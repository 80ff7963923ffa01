"""The simulated robot: ODrive-style drivers and a BMS, in simulated time.

Everything is a function of the seed, the scenarios and the frames received (no wall clock). Periodic
streams run from their nominal times plus a seeded jitter of 0 to 20 µs, so rates never drift. As an ODrive,
an Estop leaves the axis IDLE with ESTOP_REQUESTED set, and CLOSED_LOOP is entered only while no error is active.
"""

from __future__ import annotations

import bisect
import heapq
import math
import random
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass

import cantools.database

from canguard.io.frame import Frame
from canguard.sim.encode import MessageEncoder
from canguard.sim.scenarios import Producer, Scenario, parse_scenario

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


DEFAULT_RATES_HZ: dict[str, float] = {
    "Get_Iq": 250.0, "Get_Torques": 250.0, "Get_Encoder_Estimates": 100.0, "Get_Bus_Voltage_Current": 20.0,
    "Heartbeat": 10.0, "BMS_Status": 50.0, "BMS_Temperatures": 1.0,
}
"""Frames per second of each periodic message kind (per axis for ``Axis*_`` kinds)."""

AXIS_KINDS = ("Get_Iq", "Get_Torques", "Get_Encoder_Estimates", "Get_Bus_Voltage_Current", "Heartbeat")
COMMANDS = ("Estop", "Set_Axis_State", "Clear_Errors")


class SimRobot:
    """A deterministic simulated robot: N ODrive CANSimple axes and a BMS on one bus (messages as ``dbc/robot.dbc``);
    ``scenarios``: ``name`` or ``name@offset_s``. ValueError for a bad scenario, axis count or missing message."""

    def __init__(self, db: cantools.database.Database, *, axes: int = 4, seed: int = 0,
                 scenarios: Sequence[str] = ("normal",), channel: str = "can0", start_t: float = 1_700_000_000.0,
                 rates_hz: Mapping[str, float] | None = None) -> None:
        if isinstance(scenarios, str):
            scenarios = (scenarios,)
        if not 1 <= axes <= 63:
            raise ValueError(f"axes must be 1..63, got {axes}")
        self.db = db
        self.axes = axes
        self.channel = channel
        self.start_t = float(start_t)
        self.rng = random.Random(seed)
        self.rates_hz = {**DEFAULT_RATES_HZ, **(rates_hz or {})}  # set by benchmarks and tests, not by users
        parsed = [parse_scenario(s) for s in scenarios]
        self._by_name = {m.name: MessageEncoder(m) for m in db.messages}
        needed = ["BMS_Status", "BMS_Temperatures"]
        needed += [f"Axis{n}_{kind}" for n in range(axes) for kind in (*AXIS_KINDS, *COMMANDS, "Get_Error")]
        for name in needed:
            if name not in self._by_name:
                raise ValueError(f"the DBC has no message {name!r}: the simulator needs ODrive axes and a BMS")
        self.drives = [_Axis(index=n, scale=self.rng.uniform(0.85, 1.0)) for n in range(axes)]
        """Each axis' state now: ``state`` (1 IDLE, 8 CLOSED_LOOP), ``errors`` (ERROR_ESTOP_REQUESTED after Estop)."""
        self._commands = {self.encoder(n, kind).frame_id: (n, kind) for n in range(axes) for kind in COMMANDS}
        self._soc_t = 0.0
        self._alive = 0
        self._heap: list[tuple[float, int, Producer]] = []
        self._cmds: list[tuple[float, int, Frame]] = []
        self._seq = 0
        self._now = 0.0
        self.stream_rates_hz: dict[str, float] = {}
        """Frames per second of each periodic stream (scenarios' one-off frames not counted)."""
        self._setpoint_hooks = [s for s in parsed if type(s).setpoint is not Scenario.setpoint]
        self.soc_pct = START_SOC_PCT
        self._suppress_hooks = [s for s in parsed if type(s).suppress is not Scenario.suppress]
        self._add_base_streams()
        for sc in sorted(parsed, key=lambda s: s.setup_last):
            sc.setup(self)

    @property
    def now(self) -> float:
        """The simulated time reached so far (epoch seconds, the frames' time base)."""
        return self.start_t + self._now

    def frames(self, duration_s: float) -> Iterator[Frame]:
        """The next ``duration_s`` seconds of frames, in time order, from where the previous call stopped."""
        end = self._now + float(duration_s)
        heap = self._heap
        while heap and heap[0][0] < end:
            t, _, produce = heapq.heappop(heap)
            self._apply_until(t)
            self._now = max(self._now, t)
            frame = produce(t)
            if frame is not None:
                yield frame
        self._apply_until(end)
        self._now = max(self._now, end)

    def receive(self, frame: Frame) -> None:
        """Answer a driver command (Estop, Set_Axis_State, Clear_Errors) at ``frame.t``, or at once if that is past."""
        if frame.is_error_frame or frame.is_remote_frame or frame.is_extended_id:
            return
        if frame.arbitration_id not in self._commands:
            return
        t = frame.t - self.start_t
        if t <= self._now:
            self._apply(self._now, frame)
        else:
            self._seq += 1
            heapq.heappush(self._cmds, (t, self._seq, frame))

    def period_s(self, kind: str) -> float:
        """The period of a periodic message kind (``"BMS_Status"``, ``"Get_Iq"``, ...)."""
        return 1.0 / self.rates_hz[kind]

    def encoder(self, axis: int | None, kind: str) -> MessageEncoder:
        """The encoder of ``Axis{axis}_{kind}``, or of the BMS message ``kind`` when axis is None."""
        return self._by_name[kind if axis is None else f"Axis{axis}_{kind}"]

    def schedule_once(self, t: float, produce: Producer) -> None:
        """Call ``produce(t)`` for one frame at ``t`` seconds from the start."""
        self._seq += 1
        heapq.heappush(self._heap, (t, self._seq, produce))

    def add_periodic(self, kind: str, period_s: float, phase_s: float, produce: Producer) -> None:
        """Add a periodic stream: ``produce(t)`` at ``phase_s + k·period_s`` (k = 0, 1, ...) unless suppressed."""
        self.stream_rates_hz[kind] = self.stream_rates_hz.get(kind, 0.0) + 1.0 / period_s
        k = 0

        def stream(t: float) -> Frame | None:
            nonlocal k
            k += 1  # the next one from its nominal time: the rate never drifts
            self.schedule_once(phase_s + k * period_s + self.rng.uniform(0.0, JITTER_S), stream)
            return None if any(s.suppress(kind, t) for s in self._suppress_hooks) else produce(t)

        self.schedule_once(phase_s + self.rng.uniform(0.0, JITTER_S), stream)  # a real bus' jitter

    def raw_frame(self, t: float, frame_id: int, data: bytes, extended: bool = False, *, error: bool = False
                  ) -> Frame:
        """A frame with the given id and bytes at ``t`` seconds from the start."""
        return Frame(round(self.start_t + t, 6), self.channel, frame_id, data, extended, False, error)

    def bms_frame(self, t: float, pack_current_a: float | None = None) -> Frame:
        """A BMS_Status frame at ``t``; ``pack_current_a`` overrides the measured current (the spike)."""
        current = self.pack_current(t)
        dt = max(0.0, t - self._soc_t)
        self._soc_t = max(self._soc_t, t)
        self.soc_pct = max(0.0, self.soc_pct - current * dt / (PACK_CAPACITY_AH * 36.0))
        self._alive = (self._alive + 1) & 0xFF
        enc = self._by_name["BMS_Status"]
        data = enc.encode({"Pack_Current": current if pack_current_a is None else pack_current_a,
                           "Pack_Voltage": self.pack_voltage(current), "State_Of_Charge": self.soc_pct,
                           "Present": 1, "Fault": 0, "Alive_Counter": self._alive})
        return self.raw_frame(t, enc.frame_id, data, enc.is_extended_id)

    def _apply_until(self, t: float) -> None:
        while self._cmds and self._cmds[0][0] <= t:
            at, _, frame = heapq.heappop(self._cmds)
            self._apply(at, frame)

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
        for sc in self._setpoint_hooks:
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
        total = BASE_LOAD_A + sum(abs(self.current(ax, t)) for ax in self.drives)
        return total + self.rng.gauss(0.0, PACK_NOISE_A)

    def pack_voltage(self, current_a: float) -> float:
        """Open-circuit voltage at the state of charge, less the pack's resistance drop."""
        ocv = PACK_CELLS * (3.3 + 0.9 * self.soc_pct / 100.0)
        return ocv - PACK_R_OHM * current_a

    def _add_base_streams(self) -> None:
        for slot, kind in enumerate(AXIS_KINDS):
            period = self.period_s(kind)
            for ax in self.drives:
                # Spread the axes and kinds over the period so frames do not all collide.
                phase = period * ((ax.index + slot / len(AXIS_KINDS)) / self.axes)
                self.add_periodic(kind, period, phase, self._producer(kind, ax))
        self.add_periodic("BMS_Status", self.period_s("BMS_Status"), 0.0, self.bms_frame)
        self.add_periodic("BMS_Temperatures", self.period_s("BMS_Temperatures"), 0.5 * self.period_s("BMS_Status"),
                          self._temps)

    def _set_state(self, ax: _Axis, t: float, state: int) -> None:
        if state != ax.state:
            ax.edge_i = self.current(ax, t)
            ax.edge_t = t
            ax.state = state

    def _apply(self, t: float, frame: Frame) -> None:
        """Apply one driver command at simulated time ``t``."""
        axis, kind = self._commands[frame.arbitration_id]
        ax = self.drives[axis]
        if kind == "Estop":
            ax.errors |= ERROR_ESTOP_REQUESTED
            self._set_state(ax, t, AXIS_STATE_IDLE)
        elif kind == "Clear_Errors":
            ax.errors = 0
        elif len(frame.data) >= 4:  # Set_Axis_State
            requested = int.from_bytes(frame.data[:4], "little")
            if requested == AXIS_STATE_IDLE:
                self._set_state(ax, t, AXIS_STATE_IDLE)
            elif requested == AXIS_STATE_CLOSED_LOOP and ax.errors == 0:
                self._set_state(ax, t, AXIS_STATE_CLOSED_LOOP)

    def _payload(self, enc: MessageEncoder, kind: str, ax: _Axis, t: float) -> bytes:
        """The bytes of an axis' ``kind`` frame at ``t`` (telemetry: its two float32 signals)."""
        if kind == "Heartbeat":
            done = int(ax.state != AXIS_STATE_CLOSED_LOOP or self.velocity(ax, t) == 0.0)
            return enc.encode({"Axis_Error": ax.errors, "Axis_State": ax.state, "Procedure_Result": 0,
                               "Trajectory_Done_Flag": done})
        if kind == "Get_Iq":
            return enc.pack(self.setpoint(ax, t), self.measured(ax, t))
        if kind == "Get_Torques":
            return enc.pack(KT_NM_PER_A * self.setpoint(ax, t), KT_NM_PER_A * self.measured(ax, t))
        if kind == "Get_Encoder_Estimates":
            vel = self.velocity(ax, t) if ax.state == AXIS_STATE_CLOSED_LOOP else 0.0
            ax.pos_rev += vel * max(0.0, t - ax.enc_t)
            ax.enc_t = max(ax.enc_t, t)
            return enc.pack(ax.pos_rev, vel)
        iq = abs(self.measured(ax, t))  # Get_Bus_Voltage_Current
        return enc.pack(self.pack_voltage(self.pack_current(t)) - 0.1, iq)

    def _producer(self, kind: str, ax: _Axis) -> Producer:
        enc = self.encoder(ax.index, kind)
        return lambda t: self.raw_frame(t, enc.frame_id, self._payload(enc, kind, ax, t))

    def _temps(self, t: float) -> Frame:
        enc = self._by_name["BMS_Temperatures"]
        cell_v = self.pack_voltage(0.0) / PACK_CELLS
        data = enc.encode({"Cell_Temp_Min": 27.0 + self.rng.uniform(0, 1),
                           "Cell_Temp_Max": 30.0 + self.rng.uniform(0, 1), "Cell_Voltage_Min": cell_v - 0.01,
                           "Cell_Voltage_Max": cell_v + 0.01, "Pack_Temp_Delta": 3.0})
        return self.raw_frame(t, enc.frame_id, data, enc.is_extended_id)
