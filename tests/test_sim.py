"""The simulated robot: deterministic logs, decodable frames, scenarios that keep promises, a closed loop."""

from __future__ import annotations

import itertools
import math
import struct
import threading
import time
import uuid
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import can
import cantools
import pytest

from canguard.io.frame import Frame
from canguard.io.logs import read_log
from canguard.sim import SCENARIOS, SimRobot, run_on_bus, write_log
from canguard.sim.encode import MessageEncoder
from canguard.sim.robot import (
    AXIS_STATE_CLOSED_LOOP,
    AXIS_STATE_IDLE,
    ERROR_ESTOP_REQUESTED,
    KT_NM_PER_A,
)
from checkout import REPO
from waitkit import WAIT_S

DBC = REPO / "dbc" / "robot.dbc"
START = 1_700_000_000.0


@pytest.fixture(scope="module")
def db() -> cantools.database.Database:
    """The bundled robot DBC."""
    loaded = cantools.database.load_file(str(DBC))
    assert isinstance(loaded, cantools.database.Database)
    return loaded


def _ids(db: cantools.database.Database, name: str) -> int:
    return int(db.get_message_by_name(name).frame_id)


def _floats(frames: Iterable[Frame], frame_id: int, index: int = 1) -> list[tuple[float, float]]:
    """(seconds from start, value) of float ``index`` (1 = Iq_Measured / Torque_Estimate) of a frame id."""
    return [
        (f.t - START, struct.unpack_from("<ff", f.data)[index])
        for f in frames
        if f.arbitration_id == frame_id and len(f.data) == 8 and not f.is_error_frame
    ]


def _pack(db: cantools.database.Database, frames: Iterable[Frame]) -> list[tuple[float, float]]:
    """(seconds from start, Pack_Current) of every well-formed BMS_Status frame."""
    msg = db.get_message_by_name("BMS_Status")
    return [
        (f.t - START, float(msg.decode(f.data)["Pack_Current"]))
        for f in frames
        if f.arbitration_id == msg.frame_id and f.is_extended_id and len(f.data) == 8
    ]


def _heartbeats(
    db: cantools.database.Database, frames: Iterable[Frame], axis: int
) -> list[tuple[float, dict]]:
    msg = db.get_message_by_name(f"Axis{axis}_Heartbeat")
    return [
        (f.t - START, dict(msg.decode(f.data, decode_choices=False)))
        for f in frames
        if f.arbitration_id == msg.frame_id
    ]


def _cmd(db: cantools.database.Database, name: str, t: float, **signals: int) -> Frame:
    msg = db.get_message_by_name(name)
    data = msg.encode(signals) if msg.signals else b""
    return Frame(START + t, "can0", msg.frame_id, bytes(data))


class TestMessageEncoder:
    """The per-message encoders."""

    def test_telemetry_packs_positionally(self, db: cantools.database.Database) -> None:
        """Get_Iq packs (setpoint, measured), in start-bit order, into cantools-decodable bytes."""
        enc = MessageEncoder(db.get_message_by_name("Axis1_Get_Iq"))
        decoded = db.decode_message(enc.frame_id, enc.pack(2.5, -3.0))
        assert enc.by_start == ("Iq_Setpoint", "Iq_Measured")
        assert decoded == {"Iq_Setpoint": 2.5, "Iq_Measured": -3.0}


class TestSimRobot:
    """Frames of the simulated robot under the normal duty cycle."""

    def test_frames_are_time_ordered_and_resume_across_calls(self, db: cantools.database.Database) -> None:
        """Two calls of frames() continue one time-ordered stream on the robot's channel."""
        robot = SimRobot(db, channel="vcan7")
        frames = list(robot.frames(1.0)) + list(robot.frames(1.0))
        times = [f.t for f in frames]
        assert times == sorted(times)
        assert times[0] >= START and times[-1] < START + 2.0
        assert {f.channel for f in frames} == {"vcan7"}
        assert robot.now == pytest.approx(START + 2.0)

    def test_every_frame_decodes_with_the_dbc(self, db: cantools.database.Database) -> None:
        """Outside garbage/errorburst/load, every frame is a DBC message that decodes to finite values."""
        robot = SimRobot(db, scenarios=["normal", "inrush", "spike", "overload", "dropout"], seed=3)
        frames = list(robot.frames(6.0))
        for f in frames:
            msg = db.get_message_by_frame_id(f.arbitration_id)
            assert len(f.data) == msg.length
            values = msg.decode(f.data, decode_choices=False)
            assert all(math.isfinite(v) for v in values.values()), (msg.name, values)

    def test_rates_match_the_promise(self, db: cantools.database.Database) -> None:
        """Iq and torque come at 250 Hz, encoder at 100 Hz, heartbeat at 10 Hz, BMS at 50 Hz."""
        counts = Counter(f.arbitration_id for f in SimRobot(db).frames(2.0))
        for axis in range(4):
            assert counts[_ids(db, f"Axis{axis}_Get_Iq")] == pytest.approx(500, abs=2)
            assert counts[_ids(db, f"Axis{axis}_Get_Torques")] == pytest.approx(500, abs=2)
            assert counts[_ids(db, f"Axis{axis}_Get_Encoder_Estimates")] == pytest.approx(200, abs=2)
            assert counts[_ids(db, f"Axis{axis}_Heartbeat")] == pytest.approx(20, abs=1)
        assert counts[_ids(db, "BMS_Status")] == pytest.approx(100, abs=1)

    def test_normal_duty_stays_below_the_recovery_threshold(self, db: cantools.database.Database) -> None:
        """Under normal duty the BMS pack current never reaches 25 A (max below 18 A) and |Iq| <= 7 A."""
        frames = list(SimRobot(db, seed=11).frames(8.0))  # two 4 s duty cycles of every axis (staggered <= 1.5 s)
        pack = [a for _, a in _pack(db, frames)]
        assert max(pack) < 18.0 and min(pack) > 2.0
        for axis in range(4):
            iq = [abs(a) for _, a in _floats(frames, _ids(db, f"Axis{axis}_Get_Iq"))]
            assert 3.0 < max(iq) <= 7.2

    def test_pack_current_is_base_load_plus_motor_currents(self, db: cantools.database.Database) -> None:
        """Pack current follows 2 A + sum of |Iq|, and pack voltage sags when it rises."""
        frames = list(SimRobot(db, seed=2).frames(4.0))
        bms = db.get_message_by_name("BMS_Status")
        iq = {axis: _floats(frames, _ids(db, f"Axis{axis}_Get_Iq")) for axis in range(4)}
        samples = []
        for f in frames:
            if f.arbitration_id != bms.frame_id:
                continue
            t = f.t - START
            nearest = [min(iq[a], key=lambda s: abs(s[0] - t))[1] for a in range(4)]
            decoded = bms.decode(f.data)
            samples.append(
                (decoded["Pack_Current"], 2.0 + sum(abs(x) for x in nearest), decoded["Pack_Voltage"])
            )
        assert all(abs(p - expected) < 1.0 for p, expected, _ in samples)
        high = max(samples)
        low = min(samples)
        assert high[2] < low[2]
        assert all(
            v == 1
            for v in (bms.decode(f.data)["Present"] for f in frames if f.arbitration_id == bms.frame_id)
        )

    def test_torque_is_kt_times_iq(self, db: cantools.database.Database) -> None:
        """Torque_Target equals Kt times Iq_Setpoint (Kt = 0.0827 N·m/A)."""
        frames = list(SimRobot(db).frames(1.0))
        targets = [v for _, v in _floats(frames, _ids(db, "Axis0_Get_Torques"), index=0)]
        assert max(abs(v) for v in targets) == pytest.approx(7.0 * KT_NM_PER_A, rel=0.16)

    def test_rejects_unknown_scenarios_and_axis_counts(self, db: cantools.database.Database) -> None:
        """An unknown scenario name lists the known ones; axes outside the DBC are refused."""
        with pytest.raises(ValueError, match="known: normal, inrush"):
            SimRobot(db, scenarios=["nosuch"])
        with pytest.raises(ValueError, match="Axis4_"):
            SimRobot(db, axes=5)
        assert set(SCENARIOS) == {
            "normal",
            "inrush",
            "spike",
            "overload",
            "dropout",
            "garbage",
            "errorburst",
            "load",
        }


class TestScenarios:
    """Each scenario delivers the figures its docstring promises."""

    def test_inrush_is_25_a_for_80_ms_on_axis1_and_pack_stays_below_35_a(
        self, db: cantools.database.Database
    ) -> None:
        """Axis 1 is still until 1.5 s, at 25 A from 1.5 to 1.58 s, back to its duty within 60 ms."""
        frames = list(SimRobot(db, scenarios=["inrush"]).frames(3.0))
        iq = _floats(frames, _ids(db, "Axis1_Get_Iq"))
        assert all(abs(a) < 0.2 for t, a in iq if t < 1.5)
        assert all(abs(a - 25.0) < 0.2 for t, a in iq if 1.5 <= t < 1.58)
        assert all(abs(a) <= 7.2 for t, a in iq if t > 1.64)
        pack = [a for _, a in _pack(db, frames)]
        assert 25.0 < max(pack) < 35.0

    def test_spike_is_exactly_one_bms_frame_above_35_a(self, db: cantools.database.Database) -> None:
        """One 60 A BMS frame at 1.51 s, between normal frames at 1.50 and 1.52 s."""
        pack = _pack(db, SimRobot(db, scenarios=["spike"]).frames(3.0))
        high = [(t, a) for t, a in pack if a > 35.0]
        assert len(high) == 1
        t_spike, amps = high[0]
        assert amps == pytest.approx(60.0) and t_spike == pytest.approx(1.51, abs=1e-4)
        i = pack.index(high[0])
        assert pack[i - 1][1] < 25.0 and pack[i + 1][1] < 25.0
        assert pack[i + 1][0] - pack[i - 1][0] == pytest.approx(0.02, abs=1e-4)

    def test_spike_offset_moves_it(self, db: cantools.database.Database) -> None:
        """``spike@2`` puts the spike 2 s later, at 3.51 s."""
        pack = _pack(db, SimRobot(db, scenarios=["spike@2"]).frames(4.0))
        assert [round(t, 3) for t, a in pack if a > 35.0] == [3.51]

    def test_overload_is_20_a_on_axis0_and_a_leaky_i2t_trips_at_3_s(
        self, db: cantools.database.Database
    ) -> None:
        """Axis 0 at 20 A from 2.0 to 5.0 s; a 10 A / 20 A / 1 s leaky I²t trips at 3.0 s; pack < 35 A."""
        frames = list(SimRobot(db, scenarios=["overload"]).frames(6.0))
        iq = _floats(frames, _ids(db, "Axis0_Get_Iq"))
        assert all(abs(a) <= 7.2 for t, a in iq if t < 2.0)
        assert all(abs(a - 20.0) < 0.2 for t, a in iq if 2.0 <= t < 5.0)
        assert all(abs(a) <= 7.2 for t, a in iq if t >= 5.0)
        # The leaky bucket: A += (I² − Icont²)·dt, floored at 0, trips at (Ipeak² − Icont²)·tpeak.
        bucket, trip, last = 0.0, None, iq[0][0]
        for t, a in iq:
            bucket = max(0.0, bucket + (a * a - 100.0) * (t - last))
            last = t
            if trip is None and bucket >= 300.0:
                trip = t
        assert trip == pytest.approx(3.0, abs=0.01)
        assert max(a for _, a in _pack(db, frames)) < 35.0

    def test_dropout_leaves_a_bms_gap_of_1_5_s(self, db: cantools.database.Database) -> None:
        """No BMS frame between 2.0 and 3.5 s; the gap is 1.52 s; the data elsewhere is normal."""
        frames = list(SimRobot(db, scenarios=["dropout"]).frames(5.0))
        times = [t for t, _ in _pack(db, frames)]
        gaps = [(b - a, a) for a, b in itertools.pairwise(times)]
        longest, at = max(gaps)
        assert longest == pytest.approx(1.52, abs=1e-3) and at == pytest.approx(1.98, abs=1e-3)
        assert sorted(g for g, _ in gaps)[-2] < 0.021
        bms_temps = _ids(db, "BMS_Temperatures")
        assert not [f for f in frames if f.arbitration_id == bms_temps and 2.0 <= f.t - START < 3.5]

    def test_garbage_frames_are_nan_inf_wrong_length_and_unknown(
        self, db: cantools.database.Database
    ) -> None:
        """Seven bad frames from 1.0 s every 50 ms; every other frame still decodes."""
        frames = list(SimRobot(db, scenarios=["garbage"], seed=5).frames(2.0))
        bad = []
        for f in frames:
            try:
                msg = db.get_message_by_frame_id(f.arbitration_id)
            except KeyError:
                bad.append((round(f.t - START, 3), "unknown"))
                continue
            if len(f.data) != msg.length:
                bad.append((round(f.t - START, 3), f"{msg.name}:len{len(f.data)}"))
                continue
            values = msg.decode(f.data, decode_choices=False)
            if not all(math.isfinite(v) for v in values.values()):
                bad.append((round(f.t - START, 3), msg.name))
        assert [t for t, _ in bad] == [1.0, 1.05, 1.1, 1.15, 1.2, 1.25, 1.3]
        assert bad[:6] == [
            (1.0, "Axis2_Get_Iq"),
            (1.05, "Axis2_Get_Iq"),
            (1.1, "Axis2_Get_Iq:len4"),
            (1.15, "BMS_Status:len3"),
            (1.2, "Axis2_Get_Torques"),
            (1.25, "unknown"),
        ]
        assert bad[6][1].startswith("Axis2_Get_Error:len")
        odd = [(round(t, 3), a) for t, a in _floats(frames, _ids(db, "Axis2_Get_Iq")) if not math.isfinite(a)]
        assert [t for t, _ in odd] == [1.0, 1.05]
        assert math.isnan(odd[0][1]) and odd[1][1] == math.inf

    def test_errorburst_is_32_error_frames_in_6_4_ms(self, db: cantools.database.Database) -> None:
        """32 error frames from 1.0 s, 0.2 ms apart (bus errors, then a controller warning)."""
        errors = [f for f in SimRobot(db, scenarios=["errorburst"]).frames(2.0) if f.is_error_frame]
        assert len(errors) == 32
        assert errors[0].t - START == pytest.approx(1.0, abs=1e-5)
        assert errors[-1].t - errors[0].t == pytest.approx(31 * 0.0002, abs=1e-5)
        assert all(f.is_extended_id and len(f.data) == 8 for f in errors)
        assert errors[-1].arbitration_id == 0x84 and {f.arbitration_id for f in errors[:-1]} == {0x88}

    def test_load_reaches_8000_frames_per_second_on_unconfigured_ids(
        self, db: cantools.database.Database
    ) -> None:
        """With ``load`` the bus carries 8,000 frames/s ±10 %; the extra ids are not in the DBC."""
        frames = list(SimRobot(db, scenarios=["load"]).frames(2.0))
        assert len(frames) / 2.0 == pytest.approx(8000, rel=0.1)
        known = {m.frame_id for m in db.messages}
        extra = {f.arbitration_id for f in frames} - known
        assert len(extra) == 40 and all(0x200 <= i < 0x800 for i in extra)
        per_second = Counter(int(f.t - START) for f in frames)
        assert all(v == pytest.approx(8000, rel=0.1) for v in per_second.values())


class TestReceive:
    """The drivers answer canguard's Estop, Clear_Errors and Set_Axis_State like an ODrive."""

    def test_estop_idles_the_axis_and_its_current_falls_below_1_a_within_10_ms(
        self, db: cantools.database.Database
    ) -> None:
        """Estop at 2.5 s during the 20 A overload: Iq < 1 A from 2.51 s, heartbeat IDLE with the error."""
        robot = SimRobot(db, scenarios=["overload"])
        list(robot.frames(2.5))
        robot.receive(_cmd(db, "Axis0_Estop", 2.5))
        after = list(robot.frames(0.3))
        iq = _floats(after, _ids(db, "Axis0_Get_Iq"))
        assert all(abs(a) < 1.0 for t, a in iq if t >= 2.51)
        assert all(abs(a) < 0.05 for t, a in iq if t >= 2.52)
        beat = _heartbeats(db, after, 0)[0]
        assert beat[0] < 2.6
        assert beat[1]["Axis_State"] == AXIS_STATE_IDLE and beat[1]["Axis_Error"] == ERROR_ESTOP_REQUESTED
        assert robot.drives[1].state == AXIS_STATE_CLOSED_LOOP
        assert [abs(a) for t, a in _floats(after, _ids(db, "Axis1_Get_Iq"))][-1] > 0.5

    def test_closed_loop_request_is_refused_until_errors_are_cleared(
        self, db: cantools.database.Database
    ) -> None:
        """Set_Axis_State 8 alone keeps the axis idle; Clear_Errors then 8 resumes the 20 A within 0.1 s."""
        robot = SimRobot(db, scenarios=["overload"])
        robot.receive(_cmd(db, "Axis0_Estop", 2.5))
        robot.receive(_cmd(db, "Axis0_Set_Axis_State", 2.7, Axis_Requested_State=8))
        list(robot.frames(2.8))
        assert robot.drives[0].state == AXIS_STATE_IDLE
        robot.receive(_cmd(db, "Axis0_Clear_Errors", 2.8))
        robot.receive(_cmd(db, "Axis0_Set_Axis_State", 2.81, Axis_Requested_State=8))
        after = list(robot.frames(0.4))
        iq = _floats(after, _ids(db, "Axis0_Get_Iq"))
        assert all(abs(a - 20.0) < 0.3 for t, a in iq if t >= 2.91)
        states = [hb["Axis_State"] for t, hb in _heartbeats(db, after, 0) if t > 2.85]
        assert states and set(states) == {AXIS_STATE_CLOSED_LOOP}
        assert robot.drives[0].errors == 0

    def test_idle_request_stops_without_error_and_other_frames_are_ignored(
        self, db: cantools.database.Database
    ) -> None:
        """Set_Axis_State 1 idles axis 3 with no error; unknown ids, short and error frames change nothing."""
        robot = SimRobot(db)
        list(robot.frames(0.5))
        robot.receive(Frame(START + 0.5, "can0", 0x123, b"\x01"))
        robot.receive(Frame(START + 0.5, "can0", _ids(db, "Axis3_Estop"), b"", is_error_frame=True))
        robot.receive(Frame(START + 0.5, "can0", _ids(db, "Axis3_Set_Axis_State"), b"\x01"))
        assert robot.drives[3].state == AXIS_STATE_CLOSED_LOOP
        robot.receive(_cmd(db, "Axis3_Set_Axis_State", 0.5, Axis_Requested_State=1))
        assert robot.drives[3].state == AXIS_STATE_IDLE and robot.drives[3].errors == 0
        list(robot.frames(0.05))
        assert abs(robot.current(robot.drives[3], robot._now)) < 1e-6


class TestWriteLog:
    """Candump -L files of the simulator."""

    def test_same_arguments_give_identical_bytes(
        self, db: cantools.database.Database, tmp_path: Path
    ) -> None:
        """Two runs with the same seed write byte-identical files; another seed differs."""
        kwargs = {"db": db, "scenarios": ["overload", "spike", "garbage", "errorburst"], "seed": 7}
        n1 = write_log(tmp_path / "a.log", 3.0, **kwargs)
        n2 = write_log(tmp_path / "b.log", 3.0, **kwargs)
        write_log(tmp_path / "c.log", 3.0, **{**kwargs, "seed": 8})
        a = (tmp_path / "a.log").read_bytes()
        assert n1 == n2 == a.count(b"\n") > 7000
        assert a == (tmp_path / "b.log").read_bytes()
        assert a != (tmp_path / "c.log").read_bytes()

    def test_gzip_logs_are_deterministic_too(self, db: cantools.database.Database, tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
        """A ``.gz`` path writes gzip whose bytes depend only on the arguments, not on when it was written."""
        write_log(tmp_path / "a.log.gz", 1.0, db=cantools.database.load_file(DBC))
        an_hour_later = time.time() + 3600.0
        monkeypatch.setattr(time, "time", lambda: an_hour_later)  # a gzip header with a wall-clock mtime would differ
        write_log(tmp_path / "b.log.gz", 1.0, db=cantools.database.load_file(DBC))
        assert (tmp_path / "a.log.gz").read_bytes() == (tmp_path / "b.log.gz").read_bytes()

    def test_python_can_reads_the_log_back(self, db: cantools.database.Database, tmp_path: Path) -> None:
        """python-can's candump reader gets every frame, extended ids and error frames included."""
        path = tmp_path / "sim.log"
        n = write_log(path, 2.0, db=db, scenarios=["errorburst"], channel="can1")
        msgs = list(can.LogReader(str(path)))
        assert len(msgs) == n
        assert sum(m.is_error_frame for m in msgs) == 32
        bms = [m for m in msgs if m.arbitration_id == _ids(db, "BMS_Status")]
        assert len(bms) == 100 and all(m.is_extended_id and m.channel == "can1" for m in bms)
        assert path.read_text().splitlines()[1].startswith("(1700000000.0")

    def test_replay_reads_back_exactly_the_simulated_frames(
        self, db: cantools.database.Database, tmp_path: Path
    ) -> None:
        """canguard's own log reader returns the very frames the robot made, garbage and errors included."""
        kwargs = {"db": db, "scenarios": ["garbage", "errorburst", "load", "spike"], "seed": 4}
        path = tmp_path / "all.log"
        write_log(path, 1.6, **kwargs)
        expected = list(SimRobot(**kwargs).frames(1.6))
        assert list(read_log(path)) == expected
        assert sum(f.is_error_frame for f in expected) == 32


class TestRunOnBus:
    """The robot live on python-can's virtual bus."""

    def test_frames_flow_and_an_estop_from_the_bus_stops_the_axis(
        self, db: cantools.database.Database
    ) -> None:
        """Over ~0.6 s of real time frames come at the real rate and an Estop sent at 0.25 s idles axis 0."""
        channel = f"sim-{uuid.uuid4().hex}"
        iq_id, hb_id = _ids(db, "Axis0_Get_Iq"), _ids(db, "Axis0_Heartbeat")
        with (
            can.Bus(interface="virtual", channel=channel) as sim_bus,
            can.Bus(interface="virtual", channel=channel) as ctl,
        ):
            result: list[int] = []
            thread = threading.Thread(
                target=lambda: result.append(run_on_bus(sim_bus, 0.6, db=db)), daemon=True
            )
            t0 = time.time()
            thread.start()
            received: list[can.Message] = []
            estop_at = None
            # until the run ends (on a busy machine it may take longer than its 0.6 s), within WAIT_S
            while time.time() - t0 < WAIT_S and (thread.is_alive() or estop_at is None):
                msg = ctl.recv(0.01)
                if msg is not None:
                    received.append(msg)
                if estop_at is None and time.time() - t0 > 0.25:
                    ctl.send(
                        can.Message(arbitration_id=_ids(db, "Axis0_Estop"), is_extended_id=False, data=b"")
                    )
                    estop_at = time.time()
            thread.join(WAIT_S)
            while (msg := ctl.recv(0)) is not None:
                received.append(msg)
        assert estop_at is not None and result and result[0] == len(received)
        elapsed = received[-1].timestamp - received[0].timestamp
        assert 0.5 < elapsed < 1.5
        assert len(received) == pytest.approx(0.6 * 2571, rel=0.05)
        iq = [
            (m.timestamp, struct.unpack_from("<ff", m.data)[1]) for m in received if m.arbitration_id == iq_id
        ]
        assert max(abs(a) for t, a in iq if t < estop_at) > 0.5
        assert iq[-1][0] > estop_at + 0.1
        assert all(abs(a) < 0.05 for t, a in iq if t > estop_at + 0.05)
        states = [m.data[4] for m in received if m.arbitration_id == hb_id and m.timestamp > estop_at + 0.1]
        assert states and set(states) == {AXIS_STATE_IDLE}

    def test_stop_event_ends_a_run_at_once(self, db: cantools.database.Database) -> None:
        """A set stop_event ends the run before its first frame."""
        channel = f"sim-{uuid.uuid4().hex}"
        with can.Bus(interface="virtual", channel=channel) as bus:
            stop = threading.Event()
            stop.set()
            assert run_on_bus(bus, 10.0, stop_event=stop, db=db) == 0
