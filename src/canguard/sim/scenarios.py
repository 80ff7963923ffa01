"""The simulator's scenarios: what goes wrong, on which axis, and when.

Times are seconds from the start plus ``offset_s`` (``"spike@10"``). Figures are chosen against the bundled
config: the pack trips above 35 A, recovers below 25 A, ``max_age`` 0.5 s; I²t 10 A continuous, 20 A for 1 s.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, ClassVar, Protocol

if TYPE_CHECKING:
    import cantools.database

    from canguard.io.frame import Frame
    from canguard.sim.encode import MessageEncoder

Producer = Callable[[float], "Frame | None"]


class RobotHandle(Protocol):
    """What a scenario asks of the simulated robot (:class:`canguard.sim.robot.SimRobot` is one)."""

    axes: int
    rng: random.Random
    db: cantools.database.Database
    stream_rates_hz: dict[str, float]

    def period_s(self, kind: str) -> float: ...
    def encoder(self, axis: int | None, kind: str) -> MessageEncoder: ...
    def schedule_once(self, t: float, produce: Producer) -> None: ...
    def add_periodic(self, kind: str, period_s: float, phase_s: float, produce: Producer) -> None: ...
    def raw_frame(self, t: float, frame_id: int, data: bytes, extended: bool = False, *,
                  error: bool = False) -> Frame: ...
    def bms_frame(self, t: float, pack_current_a: float | None = None) -> Frame: ...

# linux/can/error.h: error classes and their details.
CAN_ERR_CRTL = 0x00000004
CAN_ERR_PROT = 0x00000008
CAN_ERR_BUSERROR = 0x00000080
CAN_ERR_CRTL_RX_WARNING = 0x04
CAN_ERR_CRTL_TX_WARNING = 0x08
CAN_ERR_PROT_BIT = 0x01
CAN_ERR_PROT_FORM = 0x02


def _noise(robot: RobotHandle, frame_id: int, dlc: int) -> Producer:
    """A producer of ``dlc`` fresh random bytes (the robot's seeded generator) on ``frame_id``."""
    return lambda t: robot.raw_frame(t, frame_id, robot.rng.randbytes(dlc))


def _at_steps(robot: RobotHandle, t0: float, step_s: float, frames: list[tuple[int, bytes, bool, bool]]) -> None:
    """Schedule fixed ``frames`` (id, data, extended, error), ``step_s`` apart from ``t0``."""
    for i, (fid, data, ext, error) in enumerate(frames):
        robot.schedule_once(t0 + i * step_s, partial(robot.raw_frame, frame_id=fid, data=data, extended=ext,
                                                     error=error))


class Scenario:
    """A named disturbance over the normal duty cycle (hooks, ``t`` in seconds from the start)."""

    summary: ClassVar[str] = ""
    """One line for ``--help`` and the demo; the scenario's name is its class name in lower case."""
    setup_last: ClassVar[bool] = False
    """True for scenarios that must see every other stream first (``load``)."""

    def __init__(self, offset_s: float = 0.0) -> None:
        self.offset_s = float(offset_s)

    def setup(self, robot: RobotHandle) -> None:
        """Schedule this scenario's own frames on ``robot`` (called once, before the first frame)."""

    def setpoint(self, axis: int, t: float, iq_a: float) -> float:
        """The current setpoint of ``axis`` at ``t`` given the duty cycle's ``iq_a``."""
        return iq_a

    def suppress(self, kind: str, t: float) -> bool:
        """True to drop the periodic ``kind`` frame due at ``t``."""
        return False


class Normal(Scenario):
    """The duty cycle only (4 s moves at up to 7 A, the axes 0.5 s apart; pack < 18 A): never trips."""

    summary = "duty cycle only: |Iq| <= 7 A per axis, pack < 18 A; must never trip"


class Inrush(Scenario):
    """Motor start on axis 1 at 1.5 s: Iq = 25 A for 80 ms, then a τ 10 ms decay into its move (0 A before); the
    other axes hold at most 1 A meanwhile (−20 ms to +200 ms): the pack reaches ≈ 30 A, below the 35 A trip."""

    summary = "axis1 starts at 1.5 s: Iq 25 A for 80 ms, then its move; pack ~30 A, < 35 A"
    AXIS = 1
    START_S = 1.5
    PEAK_A = 25.0
    DURATION_S = 0.08
    SETTLE_TAU_S = 0.01
    HOLD_A = 1.0

    def setpoint(self, axis: int, t: float, iq_a: float) -> float:
        """Zero before the start, the inrush plateau, then a fast decay into the duty cycle."""
        dt = t - self.offset_s - self.START_S
        if axis != self.AXIS:
            if -0.02 <= dt < 0.2:
                return max(-self.HOLD_A, min(self.HOLD_A, iq_a))
            return iq_a
        if dt < 0:
            return 0.0
        if dt < self.DURATION_S:
            return self.PEAK_A
        return iq_a + (self.PEAK_A - iq_a) * math.exp(-(dt - self.DURATION_S) / self.SETTLE_TAU_S)


class Spike(Scenario):
    """One BMS_Status frame of 60 A between the 50 Hz ones due at 1.5 and 1.52 s: IsCurrentSafe must trip."""

    summary = "one BMS frame of 60 A at 1.51 s between two normal ones"
    AT_S = 1.5
    CURRENT_A = 60.0

    def setup(self, robot: RobotHandle) -> None:
        """Schedule the spike half a BMS period after the BMS frame due at ``AT_S``."""
        t = self.offset_s + self.AT_S + robot.period_s("BMS_Status") / 2
        robot.schedule_once(t, lambda tt: robot.bms_frame(tt, pack_current_a=self.CURRENT_A))


class Overload(Scenario):
    """Axis 0 at 20 A (2× continuous) from 2.0 s to 5.0 s: a leaky I²t trips at 3.0 s, the thermal image (warm
    from the duty cycle) at ≈ 2.97 s; the pack stays below 35 A. Resumed before 5.0 s, it overloads again."""

    summary = "axis0 at 20 A (2x continuous 10 A) from 2.0 s to 5.0 s: leaky I2t trips at 3.0 s"
    AXIS = 0
    START_S = 2.0
    END_S = 5.0
    CURRENT_A = 20.0

    def setpoint(self, axis: int, t: float, iq_a: float) -> float:
        """``CURRENT_A`` on ``AXIS`` inside the overload window."""
        if axis == self.AXIS and self.START_S <= t - self.offset_s < self.END_S:
            return self.CURRENT_A
        return iq_a


class Dropout(Scenario):
    """No BMS frame from 2.0 s to 3.5 s: with ``max_age`` 0.5 s the battery is stale from ≈ 2.48 s to 3.5 s."""

    summary = "no BMS frames from 2.0 s to 3.5 s (stale after max_age 0.5 s)"
    START_S = 2.0
    END_S = 3.5

    def suppress(self, kind: str, t: float) -> bool:
        """Drop every BMS frame inside the window."""
        return kind.startswith("BMS_") and self.START_S <= t - self.offset_s < self.END_S


class Garbage(Scenario):
    """Bad payloads on configured messages, one every 50 ms from 1.0 s (axis 2, or the last)."""

    summary = "NaN/inf Iq, wrong-length Iq and BMS frames, NaN torque, random bytes, from 1.0 s (axis2)"
    AT_S = 1.0
    STEP_S = 0.05
    UNKNOWN_ID = 0x7E5

    def setup(self, robot: RobotHandle) -> None:
        """Schedule the seven bad frames."""
        axis = min(2, robot.axes - 1)
        t0 = self.offset_s + self.AT_S
        nan, inf = float("nan"), float("inf")
        iq = robot.encoder(axis, "Get_Iq")
        tq = robot.encoder(axis, "Get_Torques")
        bms = robot.encoder(None, "BMS_Status")
        err = robot.encoder(axis, "Get_Error")
        rng = robot.rng
        _at_steps(robot, t0, self.STEP_S, [
            (iq.frame_id, iq.pack(1.0, nan), False, False),
            (iq.frame_id, iq.pack(1.0, inf), False, False),
            (iq.frame_id, iq.pack(1.0, 1.0)[:4], False, False),
            (bms.frame_id, bms.encode({"Pack_Current": 5.0, "Present": 1})[:3], True, False),
            (tq.frame_id, tq.pack(0.1, nan), False, False),
            (self.UNKNOWN_ID, bytes(rng.getrandbits(8) for _ in range(8)), False, False),
            (err.frame_id, bytes(rng.getrandbits(8) for _ in range(rng.randrange(1, 8))), False, False),
        ])


class ErrorBurst(Scenario):
    """32 CAN error frames 0.2 ms apart from 1.0 s (a loose connector): bus errors, the counters rising by 8 a
    frame, ending in a controller warning (read back with the class bits, without CAN_ERR_FLAG, as the id)."""

    summary = "32 error frames 0.2 ms apart from 1.0 s"
    AT_S = 1.0
    COUNT = 32
    STEP_S = 0.0002

    def setup(self, robot: RobotHandle) -> None:
        """Schedule the burst."""
        burst = []
        for i in range(self.COUNT):
            counter = min(255, 8 * (i + 1))
            if i == self.COUNT - 1:
                warning = CAN_ERR_CRTL_RX_WARNING | CAN_ERR_CRTL_TX_WARNING
                burst.append((CAN_ERR_CRTL | CAN_ERR_BUSERROR, bytes([0, warning, 0, 0, 0, 0, counter, counter])))
            else:
                kind = CAN_ERR_PROT_BIT if i % 2 == 0 else CAN_ERR_PROT_FORM
                burst.append((CAN_ERR_PROT | CAN_ERR_BUSERROR, bytes([0, 0, kind, 0x0A, 0, 0, counter, counter // 2])))
        _at_steps(robot, self.offset_s + self.AT_S, self.STEP_S, [(arb, data, True, True) for arb, data in burst])


class Load(Scenario):
    """Background traffic on 40 unused ids up to 8,000 frames/s in all (a full 1 Mbit/s bus), split unevenly."""

    summary = "background frames on 40 unconfigured ids: 8,000 frames/s in total"
    setup_last = True
    TARGET_FPS = 8000.0
    IDS = 40

    def setup(self, robot: RobotHandle) -> None:
        """Add the background streams."""
        rng = robot.rng
        extra = self.TARGET_FPS - sum(robot.stream_rates_hz.values())
        if extra <= 0:
            return
        known = {m.frame_id for m in robot.db.messages}
        ids = rng.sample([i for i in range(0x200, 0x800) if i not in known], self.IDS)
        weights = [rng.uniform(0.5, 1.5) for _ in ids]
        total = sum(weights)
        for fid, w in zip(ids, weights, strict=True):
            rate = extra * w / total
            dlc = rng.randrange(0, 9)
            robot.add_periodic(f"load_{fid:03X}", 1.0 / rate, self.offset_s + rng.uniform(0, 1.0 / rate),
                               _noise(robot, fid, dlc))


SCENARIO_CLASSES: dict[str, type[Scenario]] = {
    cls.__name__.lower(): cls for cls in (Normal, Inrush, Spike, Overload, Dropout, Garbage, ErrorBurst, Load)
}
"""Every scenario by name, in the order ``--help`` and the demo list them."""

SCENARIOS: dict[str, str] = {name: cls.summary for name, cls in SCENARIO_CLASSES.items()}
"""Scenario name -> one-line description (for ``--help`` and the demo)."""


def parse_scenario(spec: str) -> Scenario:
    """The scenario of ``"name"`` or ``"name@offset_s"``; ValueError naming the known ones, or the bad offset."""
    name, _, offset = spec.strip().partition("@")
    cls = SCENARIO_CLASSES.get(name)
    if cls is None:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(SCENARIO_CLASSES)}")
    try:
        offset_s = float(offset) if offset else 0.0
    except ValueError:
        raise ValueError(f"scenario {spec!r}: offset after '@' must be seconds, got {offset!r}") from None
    if not math.isfinite(offset_s) or offset_s < 0:
        raise ValueError(f"scenario {spec!r}: offset must be a finite number of seconds >= 0")
    return cls(offset_s)
