"""The simulated robot: ODrive-style drivers and a BMS, in simulated time.

Everything is a function of the seed, the scenarios and the frames received:
one seeded :class:`random.Random`, no global random state, no wall clock. Frames
come out of a heap of scheduled producers in time order; periodic streams are
scheduled from their nominal times (start + k·period, plus a seeded jitter of
0 to 20 µs: a frame is never early), so rates never drift.

The physics is deliberately simple and documented so that tests and example
logs can assert it:

* Current loop: in CLOSED_LOOP_CONTROL (8) the measured Iq is the setpoint plus
  Gaussian noise (σ = 0.03 A); after a resume it rises to the setpoint with
  τ = 20 ms. In IDLE (1) the setpoint is 0 and the current decays with
  τ = 2 ms (from 60 A below 1 A within 9 ms), noise σ = 0.005 A.
* Torque = Kt·Iq with Kt = 8.27 / KV = 0.0827 N·m/A (an ODrive motor of 100 KV).
* Pack current = 2 A base load + Σ|Iq| + noise (σ = 0.05 A); pack voltage =
  open-circuit voltage of a 13S pack at its state of charge − 0.04 Ω × pack
  current; SOC starts at 85 % of 20 Ah and falls with the charge drawn.
* Driver commands (:meth:`SimRobot.receive`): ``Axis*_Estop`` → IDLE with the
  ESTOP_REQUESTED error set; ``Axis*_Set_Axis_State`` 1 → IDLE; 8 → CLOSED_LOOP
  only while no error is active (as an ODrive refuses to arm with errors);
  ``Axis*_Clear_Errors`` clears the errors. Heartbeats (10 Hz) report
  Axis_Error and Axis_State.
"""

from __future__ import annotations

import heapq
import random
from collections.abc import Iterator, Mapping, Sequence
from os import PathLike

import cantools.database

from canguard.io.frame import Frame
from canguard.sim.encode import MessageEncoder
from canguard.sim.motion import (
    AXIS_STATE_CLOSED_LOOP,
    AXIS_STATE_IDLE,
    ERROR_ESTOP_REQUESTED,
    JITTER_S,
    KT_NM_PER_A,
    PACK_CAPACITY_AH,
    PACK_CELLS,
    Motion,
    _Axis,
)
from canguard.sim.scenarios import Producer, Scenario, parse_scenario

DEFAULT_RATES_HZ: dict[str, float] = {
    "Get_Iq": 250.0,
    "Get_Torques": 250.0,
    "Get_Encoder_Estimates": 100.0,
    "Get_Bus_Voltage_Current": 20.0,
    "Heartbeat": 10.0,
    "BMS_Status": 50.0,
    "BMS_Temperatures": 1.0,
}
"""Frames per second of each periodic message kind (per axis for ``Axis*_`` kinds)."""

AXIS_KINDS = ("Get_Iq", "Get_Torques", "Get_Encoder_Estimates", "Get_Bus_Voltage_Current", "Heartbeat")
BMS_KINDS = ("BMS_Status", "BMS_Temperatures")


class _Periodic:
    """A periodic stream: re-schedules itself from nominal times so its rate never drifts."""

    __slots__ = ("k", "kind", "period_s", "phase_s", "produce", "robot")

    def __init__(
        self, robot: SimRobot, kind: str, period_s: float, phase_s: float, produce: Producer
    ) -> None:
        self.robot = robot
        self.kind = kind
        self.period_s = period_s
        self.phase_s = phase_s
        self.produce = produce
        self.k = 0

    def __call__(self, t: float) -> Frame | None:
        """Produce this period's frame (unless a scenario suppresses it) and schedule the next."""
        robot = self.robot
        self.k += 1
        robot.schedule_once(self.phase_s + self.k * self.period_s + robot.jitter_s(), self)
        if robot.suppressed(self.kind, t):
            return None
        return self.produce(t)


class SimRobot:
    """A deterministic simulated robot: N ODrive CANSimple axes and a BMS on one bus.

    ``db`` is the robot's DBC (a cantools Database or a path to one, with
    messages ``Axis{n}_Heartbeat``, ``Axis{n}_Get_Iq``, ... and ``BMS_Status``,
    as in ``dbc/robot.dbc``). ``scenarios`` are names from
    :data:`canguard.sim.SCENARIOS`, optionally ``name@offset_s``; every one runs
    over the normal duty cycle. ``rates_hz`` overrides entries of
    :data:`DEFAULT_RATES_HZ`. Timestamps are ``start_t`` + seconds of
    simulated time, rounded to microseconds as candump writes them.

    Raises ValueError for an unknown scenario, an axis count the DBC does not
    have, or a DBC missing one of the messages above.
    """

    def __init__(
        self,
        db: cantools.database.Database | str | PathLike[str],
        *,
        axes: int = 4,
        seed: int = 0,
        scenarios: Sequence[str] = ("normal",),
        channel: str = "can0",
        start_t: float = 1_700_000_000.0,
        rates_hz: Mapping[str, float] | None = None,
    ) -> None:
        if not isinstance(db, cantools.database.Database):
            loaded = cantools.database.load_file(str(db))
            if not isinstance(loaded, cantools.database.Database):
                raise ValueError(f"{db}: not a DBC database")
            db = loaded
        if isinstance(scenarios, str):
            scenarios = (scenarios,)
        if not 1 <= axes <= 63:
            raise ValueError(f"axes must be 1..63, got {axes}")
        self.db = db
        self.axes = axes
        self.seed = seed
        self.channel = channel
        self.start_t = float(start_t)
        self.rng = random.Random(seed)
        self.rates_hz = dict(DEFAULT_RATES_HZ)
        for kind, rate in (rates_hz or {}).items():
            if kind not in DEFAULT_RATES_HZ or not rate > 0:
                raise ValueError(
                    f"rates_hz: {kind!r}: expected one of {sorted(DEFAULT_RATES_HZ)} with a rate > 0"
                )
            self.rates_hz[kind] = float(rate)
        self.scenarios: list[Scenario] = [parse_scenario(s) for s in scenarios]
        self._encoders = {m.name: MessageEncoder(m) for m in db.messages}
        self._by_name: dict[str, MessageEncoder] = {}
        for name in ("BMS_Status", "BMS_Temperatures"):
            self._by_name[name] = self._lookup(name)
        self._axes: list[_Axis] = []
        self._commands: dict[int, tuple[int, str]] = {}
        for n in range(axes):
            ax = _Axis(index=n, scale=self.rng.uniform(0.85, 1.0))
            for kind in (*AXIS_KINDS, "Estop", "Set_Axis_State", "Clear_Errors", "Get_Error"):
                enc = self._lookup(f"Axis{n}_{kind}")
                self._by_name[f"Axis{n}_{kind}"] = enc
                ax.ids[kind] = enc.frame_id
            for kind in ("Estop", "Set_Axis_State", "Clear_Errors"):
                self._commands[ax.ids[kind]] = (n, kind)
            self._axes.append(ax)
        self._heartbeats: dict[tuple[int, int, int, int], bytes] = {}
        self._soc_t = 0.0
        self._alive = 0
        self._heap: list[tuple[float, int, Producer]] = []
        self._cmds: list[tuple[float, int, Frame]] = []
        self._seq = 0
        self._now = 0.0
        self._stream_rates: dict[str, float] = {}
        self.motion = Motion(self.rng, self._axes,
                             [s for s in self.scenarios if type(s).setpoint is not Scenario.setpoint])
        self._suppress_hooks = [s for s in self.scenarios if type(s).suppress is not Scenario.suppress]
        self._add_base_streams()
        for sc in sorted(self.scenarios, key=lambda s: s.setup_last):
            sc.setup(self)

    # ------------------------------------------------------------------ public

    @property
    def now(self) -> float:
        """The simulated time reached so far (epoch seconds, the frames' time base)."""
        return self.start_t + self._now

    def frames(self, duration_s: float) -> Iterator[Frame]:
        """Yield the next ``duration_s`` seconds of frames, in time order.

        Calls continue where the previous one stopped. Frames received with
        :meth:`receive` while iterating take effect from their time on (or at
        once, when their time is already past).
        """
        end = self._now + float(duration_s)
        heap = self._heap
        cmds = self._cmds
        while heap and heap[0][0] < end:
            t, _, produce = heapq.heappop(heap)
            while cmds and cmds[0][0] <= t:
                self._apply(*self._pop_cmd())
            self._now = max(self._now, t)
            frame = produce(t)
            if frame is not None:
                yield frame
        while cmds and cmds[0][0] <= end:
            self._apply(*self._pop_cmd())
        self._now = max(self._now, end)

    def receive(self, frame: Frame) -> None:
        """Answer a frame from the bus as the drivers would (Estop, Set_Axis_State, Clear_Errors).

        Frames for other ids, error and remote frames and wrong lengths are
        ignored. The command takes effect at ``frame.t`` if that is still ahead
        of the simulated time, otherwise at once.
        """
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

    def axis_state(self, axis: int) -> int:
        """The ODrive axis state of ``axis`` (1 IDLE, 8 CLOSED_LOOP_CONTROL) at the current time."""
        return self._axes[axis].state

    def axis_errors(self, axis: int) -> int:
        """The active error bits of ``axis`` (``ERROR_ESTOP_REQUESTED`` after an Estop)."""
        return self._axes[axis].errors

    def current_a(self, axis: int) -> float:
        """The noise-free Iq of ``axis`` at the current time, in amps."""
        return self.motion.current(self._axes[axis], self._now)

    def nominal_rate_hz(self) -> float:
        """Frames per second of all periodic streams (scenarios' one-off frames not counted)."""
        return sum(self._stream_rates.values())

    # --------------------------------------------------- scenario-facing helpers

    def period_s(self, kind: str) -> float:
        """The period of a periodic message kind (``"BMS_Status"``, ``"Get_Iq"``, ...)."""
        return 1.0 / self.rates_hz[kind]

    def encoder(self, axis: int | None, kind: str) -> MessageEncoder:
        """The encoder of ``Axis{axis}_{kind}``, or of the BMS message ``kind`` when axis is None."""
        return self._by_name[kind if axis is None else f"Axis{axis}_{kind}"]

    def known_ids(self) -> set[int]:
        """Every arbitration id of the DBC."""
        return {m.frame_id for m in self.db.messages}

    def schedule_once(self, t: float, produce: Producer) -> None:
        """Call ``produce(t)`` for one frame at ``t`` seconds from the start."""
        self._push(t, produce)

    def add_periodic(self, kind: str, period_s: float, phase_s: float, produce: Producer) -> None:
        """Add a periodic stream: ``produce(t)`` at ``phase_s + k·period_s`` (k = 0, 1, ...)."""
        self._stream_rates[kind] = self._stream_rates.get(kind, 0.0) + 1.0 / period_s
        stream = _Periodic(self, kind, period_s, phase_s, produce)
        self._push(phase_s + self.jitter_s(), stream)

    def raw_frame(
        self, t: float, frame_id: int, data: bytes, extended: bool = False, *, error: bool = False
    ) -> Frame:
        """A frame with the given id and bytes at ``t`` seconds from the start."""
        return Frame(round(self.start_t + t, 6), self.channel, frame_id, data, extended, False, error)

    def bms_frame(self, t: float, pack_current_a: float | None = None) -> Frame:
        """A BMS_Status frame at ``t``; ``pack_current_a`` overrides the measured current (the spike)."""
        motion = self.motion
        current = motion.pack_current(t)
        dt = max(0.0, t - self._soc_t)
        self._soc_t = max(self._soc_t, t)
        motion.soc_pct = max(0.0, motion.soc_pct - current * dt / (PACK_CAPACITY_AH * 36.0))
        self._alive = (self._alive + 1) & 0xFF
        enc = self._by_name["BMS_Status"]
        data = enc.encode(
            {
                "Pack_Current": current if pack_current_a is None else pack_current_a,
                "Pack_Voltage": motion.pack_voltage(current),
                "State_Of_Charge": motion.soc_pct,
                "Present": 1,
                "Fault": 0,
                "Alive_Counter": self._alive,
            }
        )
        return Frame(round(self.start_t + t, 6), self.channel, enc.frame_id, data, enc.is_extended_id)

    # ---------------------------------------------------------------- internals

    def _lookup(self, name: str) -> MessageEncoder:
        enc = self._encoders.get(name)
        if enc is None:
            raise ValueError(f"the DBC has no message {name!r}: the simulator needs ODrive axes and a BMS")
        return enc

    def _push(self, t: float, produce: Producer) -> None:
        self._seq += 1
        heapq.heappush(self._heap, (t, self._seq, produce))

    def _pop_cmd(self) -> tuple[float, Frame]:
        t, _, frame = heapq.heappop(self._cmds)
        return t, frame

    def jitter_s(self) -> float:
        """A random delay of a periodic frame (a real bus' scheduling jitter)."""
        return self.rng.uniform(0.0, JITTER_S)

    def suppressed(self, kind: str, t: float) -> bool:
        """True when a scenario drops the periodic ``kind`` frame due at ``t``."""
        return any(s.suppress(kind, t) for s in self._suppress_hooks)

    def _add_base_streams(self) -> None:
        n = self.axes
        for slot, kind in enumerate(AXIS_KINDS):
            period = self.period_s(kind)
            for ax in self._axes:
                # Spread the axes and kinds over the period so frames do not all collide.
                phase = period * ((ax.index + slot / len(AXIS_KINDS)) / n)
                produce = (self._heartbeat_producer(ax) if kind == "Heartbeat"
                           else self._telemetry_producer(kind, ax))
                self.add_periodic(kind, period, phase, produce)
        self.add_periodic("BMS_Status", self.period_s("BMS_Status"), 0.0, self.bms_frame)
        self.add_periodic(
            "BMS_Temperatures",
            self.period_s("BMS_Temperatures"),
            0.5 * self.period_s("BMS_Status"),
            self._temps,
        )

    # Physics ------------------------------------------------------------------

    def _set_state(self, ax: _Axis, t: float, state: int) -> None:
        if state == ax.state:
            return
        ax.edge_i = self.motion.current(ax, t)
        ax.edge_t = t
        ax.state = state

    def _apply(self, t: float, frame: Frame) -> None:
        """Apply one driver command at simulated time ``t``."""
        axis, kind = self._commands[frame.arbitration_id]
        ax = self._axes[axis]
        if kind == "Estop":
            ax.errors |= ERROR_ESTOP_REQUESTED
            self._set_state(ax, t, AXIS_STATE_IDLE)
        elif kind == "Clear_Errors":
            ax.errors = 0
        elif kind == "Set_Axis_State":
            if len(frame.data) < 4:
                return
            requested = int.from_bytes(frame.data[:4], "little")
            if requested == AXIS_STATE_IDLE:
                self._set_state(ax, t, AXIS_STATE_IDLE)
            elif requested == AXIS_STATE_CLOSED_LOOP and ax.errors == 0:
                self._set_state(ax, t, AXIS_STATE_CLOSED_LOOP)

    # Producers ----------------------------------------------------------------

    def _telemetry(self, kind: str, ax: _Axis, t: float) -> tuple[float, float]:
        """The two float32 signals of an axis' telemetry ``kind`` at ``t``."""
        m = self.motion
        if kind == "Get_Iq":
            return m.setpoint(ax, t), m.measured(ax, t)
        if kind == "Get_Torques":
            return KT_NM_PER_A * m.setpoint(ax, t), KT_NM_PER_A * m.measured(ax, t)
        if kind == "Get_Encoder_Estimates":
            vel = m.velocity(ax, t) if ax.state == AXIS_STATE_CLOSED_LOOP else 0.0
            ax.pos_rev += vel * max(0.0, t - ax.enc_t)
            ax.enc_t = max(ax.enc_t, t)
            return ax.pos_rev, vel
        iq = abs(m.measured(ax, t))  # Get_Bus_Voltage_Current
        return m.pack_voltage(m.pack_current(t)) - 0.1, iq

    def _telemetry_producer(self, kind: str, ax: _Axis) -> Producer:
        enc = self._by_name[f"Axis{ax.index}_{kind}"]
        return lambda t: self.raw_frame(t, enc.frame_id, enc.pack(*self._telemetry(kind, ax, t)))

    def _heartbeat_producer(self, ax: _Axis) -> Producer:
        enc = self._by_name[f"Axis{ax.index}_Heartbeat"]
        fid = enc.frame_id

        def produce(t: float) -> Frame:
            done = int(ax.state != AXIS_STATE_CLOSED_LOOP or self.motion.velocity(ax, t) == 0.0)
            key = (ax.index, ax.errors, ax.state, done)
            data = self._heartbeats.get(key)
            if data is None:
                data = enc.encode(
                    {
                        "Axis_Error": ax.errors,
                        "Axis_State": ax.state,
                        "Procedure_Result": 0,
                        "Trajectory_Done_Flag": done,
                    }
                )
                self._heartbeats[key] = data
            return self.raw_frame(t, fid, data)

        return produce

    def _temps(self, t: float) -> Frame:
        enc = self._by_name["BMS_Temperatures"]
        cell_v = self.motion.pack_voltage(0.0) / PACK_CELLS
        data = enc.encode(
            {
                "Cell_Temp_Min": 27.0 + self.rng.uniform(0, 1),
                "Cell_Temp_Max": 30.0 + self.rng.uniform(0, 1),
                "Cell_Voltage_Min": cell_v - 0.01,
                "Cell_Voltage_Max": cell_v + 0.01,
                "Pack_Temp_Delta": 3.0,
            }
        )
        return self.raw_frame(t, enc.frame_id, data, enc.is_extended_id)
