"""The engine in-process on a manual clock: frames in, task / stop frames and events out.

No threads and no buses: frames are fed by hand, time moves only when the test
moves it, and every frame the engine sends lands in a :class:`LogSink`.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import cantools
import pytest
import yaml

from canguard.config.loader import load_config
from canguard.engine.core import Engine
from canguard.engine.event_codec import FIRST_KEYS
from canguard.engine.events import EventJournal
from canguard.engine.gate import LogSink, TaskGate
from canguard.io.block import one_block
from canguard.io.clock import ManualClock
from canguard.io.frame import Frame
from checkout import REPO
from test_daemon import read_events

BUNDLED = REPO / "config" / "canguard.yaml"
DBC = REPO / "dbc" / "robot.dbc"

T0 = 1_700_000_000.0
"""Epoch seconds, as candump writes them."""

BMS_ID = 0x18FF50E5
ESTOP_IDS = {node << 5 | 0x02 for node in range(4)}
SET_STATE_IDS = {node << 5 | 0x07 for node in range(4)}
CLOSED_LOOP = (8).to_bytes(4, "little")
IDLE = (1).to_bytes(4, "little")


@functools.lru_cache(maxsize=1)
def _db() -> Any:
    return cantools.database.load_file(str(DBC))


def bms_frame(t: float, current_a: float, present: int = 1) -> Frame:
    """A BMS_Status frame with ``current_a`` on the pack."""
    msg = _db().get_message_by_name("BMS_Status")
    data = msg.encode({"Pack_Current": current_a, "Pack_Voltage": 48.0, "State_Of_Charge": 80.0,
                       "Present": present, "Fault": 0, "Alive_Counter": 0})
    return Frame(t, "can0", msg.frame_id, bytes(data), True)


def iq_frame(t: float, axis: int, current_a: float) -> Frame:
    """An AxisN_Get_Iq frame with ``Iq_Measured = current_a``."""
    msg = _db().get_message_by_name(f"Axis{axis}_Get_Iq")
    data = msg.encode({"Iq_Setpoint": current_a, "Iq_Measured": current_a})
    return Frame(t, "can0", msg.frame_id, bytes(data), False)


def write_config(tmp: Path, **overrides: Any) -> Path:
    """The bundled config with absolute paths into ``tmp`` (and ``overrides`` applied at top level)."""
    doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
    doc["dbc"] = [str(DBC)]
    doc["tree"]["file"] = str((BUNDLED.parent / doc["tree"]["file"]).resolve())
    doc["events"] = str(tmp / "events.jsonl")
    doc["state"]["file"] = str(tmp / "i2t_state.json")
    doc.update(overrides)
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


class ListEvents:
    """An event sink keeping every event in memory."""

    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []

    def write(self, event: Mapping[str, Any]) -> None:
        """Keep the event."""
        self.events.append(dict(event))

    def flush(self) -> None:
        """Nothing to make durable."""

    def named(self, name: str) -> list[dict[str, Any]]:
        """Every event called ``name``, in order."""
        return [e for e in self.events if e.get("event") == name]


class Rig:
    """One engine on a manual clock with its sink and events."""

    def __init__(self, tmp: Path, events: Any = None, heat: Any = None, **overrides: Any) -> None:
        self.cfg = load_config(write_config(tmp, **overrides))
        self.clock = ManualClock(T0)
        self.sink = LogSink(self.clock.now, self.cfg.buses)
        self.events = events if events is not None else ListEvents()
        self.engine = Engine(self.cfg, self.clock, self.sink, events=self.events, heat=heat)
        self.engine.start(T0)
        self.t = T0
        self.last_bms_t = math.nan

    def feed(self, frame: Frame) -> None:
        """Feed one frame on bus ``main``."""
        self.engine.take("main", one_block(frame))
        self.t = max(self.t, frame.t)

    def run(self, until: float, pack_a: float = 10.0, axis0_a: float = 5.0, step_s: float = 0.01) -> None:
        """Feed BMS and axis0 frames every ``step_s`` up to ``until`` (exclusive), then advance to it.

        The default axis0 current (5 A) is a motor at work: a stop is confirmed only once it falls below 1 A.
        """
        t = self.t + step_s
        while t < until - 1e-9:
            self.feed(bms_frame(t, pack_a))
            self.last_bms_t = t
            self.feed(iq_frame(t + 0.0005, 0, axis0_a))
            t += step_s
        self.advance(until)

    def advance(self, t: float) -> None:
        """Move the clock to ``t`` and let the engine run what is due."""
        self.engine.advance(t)
        self.clock.advance_to(t)
        self.t = max(self.t, t)

    def sent(self, ids: set[int], since: float = -math.inf, data: bytes | None = None) -> list[Frame]:
        """Frames sent with one of ``ids`` at or after ``since`` (and with ``data``, when given)."""
        return [f for f in self.sink.frames
                if f.arbitration_id in ids and f.t >= since and (data is None or f.data == data)]

    def running(self) -> None:
        """Bring the task up: fresh, normal currents until task frames flow."""
        self.run(T0 + 0.1)
        assert self.engine.gate.state == TaskGate.RUNNING
        assert self.sent(SET_STATE_IDS, data=CLOSED_LOOP)


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    """A running engine on the bundled config."""
    r = Rig(tmp_path)
    r.running()
    yield r


class TestEngine:
    """Engine: the tick policy, task gating, stop confirmation and the events they write."""

    def test_overcurrent_sends_stop_frames_at_the_frame_time(self, rig: Rig) -> None:
        """An overcurrent frame between two ticks sends every axis' Estop at that frame's own time."""
        t_over = rig.t + 0.0037  # off the 10 ms tick grid
        rig.feed(bms_frame(t_over, 40.0))
        stops = rig.sent(ESTOP_IDS, since=t_over - 0.0037)
        assert {f.arbitration_id for f in stops} == ESTOP_IDS
        assert {f.t for f in stops} == {t_over}
        assert rig.engine.gate.state == TaskGate.STOPPED

    def test_stop_frames_repeat_and_no_task_frames_while_stopped(self, rig: Rig) -> None:
        """While the pack current stays high, Estops repeat every stop.repeat and task frames stay off."""
        t_over = rig.t + 0.001
        rig.feed(bms_frame(t_over, 40.0))
        rig.run(t_over + 0.16, pack_a=40.0, axis0_a=0.2)
        axis0_stops = [f.t for f in rig.sent({0x02}, since=t_over)]
        assert len(axis0_stops) == 4  # at once, +50, +100, +150 ms
        assert axis0_stops[1] - axis0_stops[0] == pytest.approx(0.05)
        assert rig.sent(SET_STATE_IDS, since=t_over, data=CLOSED_LOOP) == []

    def test_recovery_resumes_task_frames(self, rig: Rig) -> None:
        """Back at or below the recovery threshold (25 A) the task frames resume; in between they do not."""
        t_over = rig.t + 0.001
        rig.feed(bms_frame(t_over, 40.0))
        rig.run(t_over + 0.1, pack_a=30.0)  # below the trip level, above the recovery level: hysteresis holds
        assert rig.sent(SET_STATE_IDS, since=t_over, data=CLOSED_LOOP) == []
        t_rec = rig.t + 0.002
        rig.feed(bms_frame(t_rec, 25.0))
        rig.advance(t_rec + rig.engine.period_s)  # resumes at t_rec (tests/test_recover_timing.py)
        resumed = rig.sent(SET_STATE_IDS, since=t_rec, data=CLOSED_LOOP)
        assert {f.arbitration_id for f in resumed} == SET_STATE_IDS
        assert resumed[0].t <= t_rec + rig.engine.period_s
        gate_events = [e["event"] for e in rig.events.events
                       if e["event"] in ("stop", "resume") and e["t"] >= t_over]
        assert gate_events == ["stop", "resume"]
        assert rig.engine.gate.state == TaskGate.RUNNING

    def test_stale_bms_stops_the_task(self, rig: Rig) -> None:
        """No BMS frame for longer than max_age (0.5 s) stops the task and records a stale event."""
        last = rig.last_bms_t
        rig.advance(last + 0.45)
        assert rig.engine.gate.state == TaskGate.RUNNING
        rig.advance(last + 0.6)
        stops = rig.sent(ESTOP_IDS, since=last)
        assert stops, "no stop frames after the BMS went silent"
        assert last + 0.5 <= stops[0].t <= last + 0.5 + rig.engine.period_s + 1e-9
        stale = [e for e in rig.events.named("stale") if e["source"] == "/battery_state"]
        assert stale and stale[0]["read_by_tree"] is True

    def test_unconfirmed_stop_escalates_after_the_deadline(self, rig: Rig) -> None:
        """When axis0's current stays above 1 A, IDLE requests go out 0.2 s after the stop, with an event."""
        t_over = rig.t + 0.001
        rig.feed(bms_frame(t_over, 40.0))
        rig.run(t_over + 0.15, pack_a=40.0, axis0_a=5.0)
        assert rig.sent(SET_STATE_IDS, data=IDLE) == []
        rig.run(t_over + 0.3, pack_a=40.0, axis0_a=5.0)
        idle = rig.sent(SET_STATE_IDS, data=IDLE)
        assert {f.arbitration_id for f in idle} == SET_STATE_IDS
        assert idle[0].t == pytest.approx(t_over + 0.2, abs=1e-6)
        (esc,) = rig.events.named("escalate")
        assert esc["source"] == "axis0" and esc["value"] == pytest.approx(5.0) and esc["threshold"] == 1.0
        assert rig.events.named("confirmed") == []

    def test_confirmed_stop_records_confirmed_and_does_not_escalate(self, rig: Rig) -> None:
        """When axis0's current falls below 1 A within 0.2 s the stop is confirmed and never escalated."""
        t_over = rig.t + 0.001
        rig.feed(bms_frame(t_over, 40.0))
        rig.run(t_over + 0.05, pack_a=40.0, axis0_a=5.0)
        rig.feed(iq_frame(t_over + 0.06, 0, 0.3))
        rig.run(t_over + 0.5, pack_a=40.0, axis0_a=0.3)
        (conf,) = [e for e in rig.events.named("confirmed") if e["t"] >= t_over]
        assert conf["source"] == "axis0" and conf["value"] == pytest.approx(0.3)
        assert t_over + 0.06 <= conf["t"] <= t_over + 0.2
        assert rig.events.named("escalate") == []
        assert rig.sent(SET_STATE_IDS, data=IDLE) == []

    def test_one_frame_spike_between_ticks_still_trips(self, rig: Rig) -> None:
        """A single 40 A frame followed by a normal one before the next tick still stops the task."""
        t_spike = rig.t + 0.002
        rig.feed(bms_frame(t_spike, 40.0))
        rig.feed(bms_frame(t_spike + 0.001, 10.0))
        rig.advance(t_spike + 0.05)
        assert rig.sent(ESTOP_IDS, since=t_spike)
        trips = [e for e in rig.events.named("trip") if e["t"] >= t_spike]
        assert trips and trips[0]["value"] == pytest.approx(40.0) and trips[0]["threshold"] == 35.0

    def test_node_exception_fails_safe_and_engine_keeps_going(self, rig: Rig) -> None:
        """A node that raises fails the tick: stop frames, an error event, and later ticks still run."""
        guard = next(n for n in rig.engine.root.iterate() if type(n).__name__ == "IsCurrentSafe")

        def boom() -> Any:
            raise RuntimeError("sensor table corrupt")

        guard.update = boom
        # Its tick changed after the engine proved it quiet: no longer proven, every tick runs it from now on.
        rig.engine.quiet.loud |= {guard}
        rig.engine.quiet.until = -math.inf
        rig.engine.quiet._fresh = None  # no fixed point to draw the horizon again from
        t_err = rig.t + 0.002
        rig.advance(t_err + 0.01)
        assert rig.sent(ESTOP_IDS, since=t_err)
        errors = rig.events.named("error")
        assert errors and "RuntimeError: sensor table corrupt" in errors[0]["reason"]
        del guard.update  # the node heals: the instance falls back to its class's update
        ticks = rig.engine.stats.ticks
        t_ok = rig.t
        rig.run(t_ok + 0.1)
        assert rig.engine.stats.ticks > ticks
        assert rig.sent(SET_STATE_IDS, since=t_ok, data=CLOSED_LOOP)
        assert rig.engine.gate.state == TaskGate.RUNNING

    def test_events_carry_the_journal_fields(self, tmp_path: Path) -> None:
        """Every journal line has t, event, node, source, value, threshold and reason; a trip fills them."""
        journal = EventJournal(tmp_path / "events.jsonl")
        r = Rig(tmp_path, events=journal)
        r.running()
        t_over = r.t + 0.001
        r.feed(bms_frame(t_over, 40.0))
        r.run(t_over + 0.3, pack_a=40.0, axis0_a=5.0)
        r.engine.finish(reason="test over")
        journal.close()
        lines = (tmp_path / "events.jsonl").read_text(encoding="utf-8").splitlines()
        for line in lines:
            assert tuple(json.loads(line))[: len(FIRST_KEYS)] == FIRST_KEYS
        events = read_events(tmp_path / "events.jsonl")
        names = [e["event"] for e in events]
        assert names[0] == "start" and names[-1] == "exit"
        assert {"trip", "stop", "escalate"} <= set(names)
        trip = next(e for e in events if e["event"] == "trip" and e["t"] == pytest.approx(t_over, abs=1e-6))
        assert trip["node"] and trip["source"] == "/battery_state"
        assert trip["value"] == pytest.approx(40.0) and trip["threshold"] == 35.0 and trip["reason"]
        assert all(T0 <= e["t"] <= r.t + 1e-6 for e in events)  # t is rounded to the microsecond


class StopWitness:
    """A frame sink that, at the first stop frame, notes which events the journal file holds; then sends as ``out``."""

    def __init__(self, out: LogSink, journal: Path) -> None:
        self.out = out
        self.journal = journal
        self.recorded_at_stop: list[str] | None = None
        self.engine: Engine | None = None
        self.trips_at_stop = -1
        """The trips the tree had judged (its guards' ``trip`` events, held or written) at the first stop frame."""

    def send(self, frames: Any, origin: str) -> None:
        """Note the journal's events (and the trips judged) at the first stop frame, then pass the frames on."""
        if origin == "stop" and self.recorded_at_stop is None:
            self.recorded_at_stop = [e["event"] for e in read_events(self.journal)]
            self.trips_at_stop = self.engine.events_seen["trip"] if self.engine is not None else -1
        self.out.send(frames, origin)


GUARD = ('<Condition ID="IsCurrentSafe" topic_name="/battery_state" overcurrent_threshold="35.0" '
         'recovery_threshold="25.0"/>')
TREES = {  # the ReactiveSequence's children: the guard's place in the tree
    "the bundled tree": (GUARD, "ahead"),
    "guard under two Inverters": (f"<Inverter><Inverter>{GUARD}</Inverter></Inverter>", "in the tick"),
    "guard with a pre-condition": (GUARD.replace("/>", ' _skipIf="false"/>'), "in the tick"),
    "trip handled by a Fallback": (f"<Fallback>{GUARD}<AlwaysSuccess/></Fallback>", "no stop"),
}


class TestStopFirst:
    """A trip's stop frames leave before the journal records anything about the trip or the stop."""

    def test_stop_frames_leave_before_the_trip_and_stop_are_recorded(self, tmp_path: Path) -> None:
        """At the stop frame the journal holds neither trip nor stop; when the tick is over it holds both, in
        order, stamped with the time of the overcurrent frame."""
        path = tmp_path / "events.jsonl"
        journal = EventJournal(path)
        cfg = load_config(write_config(tmp_path))
        clock = ManualClock(T0)
        witness = StopWitness(LogSink(clock.now, cfg.buses), path)
        engine = Engine(cfg, clock, witness, events=journal)
        engine.start(T0)
        t = T0
        while engine.gate.state != TaskGate.RUNNING:
            t += 0.01
            engine.take("main", one_block(bms_frame(t, 10.0)))
            engine.take("main", one_block(iq_frame(t, 0, 5.0)))
            engine.advance(t)
        t_over = t + 0.0013  # between two grid ticks: the edge ticks the tree
        engine.take("main", one_block(bms_frame(t_over, 40.0)))
        assert witness.recorded_at_stop is not None, "no stop frame sent"
        assert "trip" not in witness.recorded_at_stop and "stop" not in witness.recorded_at_stop
        events = read_events(path)  # the feed is over, and with it the tick that sent the stop
        names = [e["event"] for e in events]
        assert names[-2:] == ["trip", "stop"]
        assert [e["t"] for e in events[-2:]] == [pytest.approx(t_over, abs=1e-6)] * 2
        journal.close()

    @pytest.mark.parametrize("tree", list(TREES))
    def test_a_trip_the_tree_surely_halts_on_stops_before_the_tree_ticks(self, tmp_path: Path, tree: str) -> None:
        """Where the guard's failure surely halts the task (a ReactiveSequence above it, nothing between), the stop
        frames leave at the trip, before the tree's tick; elsewhere the tick decides; the events are the same."""
        guard, expected = TREES[tree]
        xml = tmp_path / "tree.xml"
        xml.write_text(f'<root main_tree_to_execute="T"><BehaviorTree ID="T"><ReactiveSequence>{guard}'
                       '<Action ID="ExecuteTask"/></ReactiveSequence></BehaviorTree></root>', encoding="utf-8")
        path = tmp_path / "events.jsonl"
        journal = EventJournal(path)
        cfg = load_config(write_config(tmp_path, tree={"file": str(xml), "tick_hz": 100}))
        clock = ManualClock(T0)
        witness = StopWitness(LogSink(clock.now, cfg.buses), path)
        engine = witness.engine = Engine(cfg, clock, witness, events=journal)
        engine.start(T0)
        t = T0
        while engine.gate.state != TaskGate.RUNNING:
            t += 0.01
            engine.take("main", one_block(bms_frame(t, 10.0)))
            engine.advance(t)
        ticks, trips = engine.stats.ticks, engine.events_seen["trip"]
        engine.take("main", one_block(bms_frame(t + 0.0013, 40.0)))
        journal.close()
        names = [e["event"] for e in read_events(path)]
        if expected == "no stop":
            assert engine.gate.state == TaskGate.RUNNING and witness.trips_at_stop == -1
            assert names[-1] == "trip"
            return
        assert witness.trips_at_stop == (trips if expected == "ahead" else trips + 1)
        assert engine.stats.ticks == ticks + 1 and names[-2:] == ["trip", "stop"]
        assert len(witness.out.frames) == len(cfg.stop.frames) + witness.out.origins.count("task")


class TestFinish:
    """What the engine sends and writes on its way out (SIGTERM, end of a demo)."""

    def test_exit_while_running_stops(self, tmp_path: Path) -> None:
        """Finishing a running task sends the stop frames and ends with an exit event."""
        rig = Rig(tmp_path)
        rig.running()
        before = len(rig.sent(ESTOP_IDS))
        rig.engine.finish(reason="SIGTERM")
        assert len(rig.sent(ESTOP_IDS)) == before + len(ESTOP_IDS)
        assert rig.events.named("exit")[-1]["reason"] == "SIGTERM"

    def test_exit_while_stopped_repeats_the_stop(self, tmp_path: Path) -> None:
        """Finishing while already stopped sends the stop frames once more, so the drives hear a stop last."""
        rig = Rig(tmp_path)
        rig.running()
        rig.feed(bms_frame(rig.t + 0.001, 60.0))
        assert rig.engine.gate.state == TaskGate.STOPPED
        before = len(rig.sent(ESTOP_IDS))
        rig.engine.finish(reason="SIGTERM")
        assert len(rig.sent(ESTOP_IDS)) == before + len(ESTOP_IDS)
        assert rig.sink.frames[-1].arbitration_id in ESTOP_IDS


class TestStopConfirmationMagnitude:
    """stop.confirm's below / above look at the magnitude of a signed current."""

    def test_negative_current_is_not_below(self, tmp_path: Path) -> None:
        """A drive still pushing -20 A after the stop does not confirm "below 1 A": the stop escalates."""
        rig = Rig(tmp_path)
        rig.running()
        t_stop = rig.t + 0.001
        rig.feed(bms_frame(t_stop, 60.0))
        assert rig.engine.gate.state == TaskGate.STOPPED
        rig.run(t_stop + 0.3, pack_a=30.0, axis0_a=-20.0)  # 30 A: the pack guard stays tripped
        assert not rig.events.named("confirmed")
        assert rig.events.named("escalate")


class TestStopConfirmationAfterTheStop:
    """Only a sample taken after the stop can confirm it."""

    def test_sample_from_before_the_stop_does_not_confirm(self, tmp_path: Path) -> None:
        """axis0 at 0.5 A before the trip and silent after it: not confirmed, the stop escalates."""
        rig = Rig(tmp_path)
        rig.running()
        rig.feed(iq_frame(rig.t + 0.0005, 0, 0.5))  # below 1 A, but before the stop
        t_stop = rig.t + 0.001
        rig.feed(bms_frame(t_stop, 60.0))
        assert rig.engine.gate.state == TaskGate.STOPPED
        t = t_stop
        while t < t_stop + 0.3:  # BMS stays tripped (30 A: hysteresis holds); axis0 says nothing new
            t += 0.01
            rig.feed(bms_frame(t, 30.0))
        rig.advance(t)
        assert not rig.events.named("confirmed")
        assert rig.events.named("escalate")


class TestGapInTime:
    """A long gap (a silent log, a stalled daemon) is ticked through where it matters, then jumped."""

    def test_stale_trip_at_its_own_time_inside_a_long_gap(self, tmp_path: Path) -> None:
        """BMS silent from 1 s to 12 s: the stale stop is at ~1.5 s (max_age after), and lasts ~10.5 s."""
        rig = Rig(tmp_path)
        rig.running()
        rig.run(T0 + 1.0)
        last = rig.last_bms_t
        rig.feed(bms_frame(T0 + 12.0, 10.0))
        [stop] = rig.events.named("stop")
        assert last + 0.5 <= stop["t"] <= last + 0.5 + 0.011  # within one tick of the staleness deadline
        assert rig.engine.stats.skipped_ticks > 0
        assert rig.engine.gate.stopped_total(T0 + 12.0) == pytest.approx(T0 + 12.0 - stop["t"], abs=0.02)


class TestInhibits:
    """Backstops the tree cannot talk its way around: a bus down, a stale source the tree reads."""

    def test_bus_down_stops_and_holds_until_it_is_back(self, tmp_path: Path) -> None:
        """A bus error stops the task at once (bus_error event) and task frames resume only after bus_up."""
        rig = Rig(tmp_path)
        rig.running()
        rig.engine.bus_down("main", "OSError: Network is down")
        assert rig.engine.gate.state == TaskGate.STOPPED
        assert rig.events.named("bus_error")[-1]["source"] == "main"
        t_down = rig.t
        rig.run(t_down + 0.2)  # healthy data keeps coming (another bus, say): still stopped
        assert not rig.sent(SET_STATE_IDS, since=t_down + 0.001, data=CLOSED_LOOP)
        rig.engine.bus_up("main")
        rig.run(rig.t + 0.05)
        assert rig.sent(SET_STATE_IDS, since=t_down + 0.2, data=CLOSED_LOOP)

    def test_stale_source_stops_even_a_tree_that_masks_its_guard(self, tmp_path: Path) -> None:
        """ForceSuccess around the guard hides its failure; the stale BMS still stops the task."""
        xml = tmp_path / "masked.xml"
        xml.write_text(
            '<root BTCPP_format="4" main_tree_to_execute="M"><BehaviorTree ID="M"><ReactiveSequence>'
            '<ForceSuccess><IsCurrentSafe topic_name="/battery_state"/></ForceSuccess><ExecuteTask/>'
            '</ReactiveSequence></BehaviorTree></root>',
            encoding="utf-8",
        )
        rig = Rig(tmp_path, tree={"file": str(xml), "main": "M", "tick_hz": 100})
        rig.running()
        last = rig.last_bms_t
        rig.advance(last + 1.0)  # BMS silent for 1 s (max_age 0.5 s)
        [stop] = rig.events.named("stop")
        assert "source /battery_state" in stop["reason"]
        assert last + 0.5 <= stop["t"] <= last + 0.5 + 0.011
        assert not rig.sent(SET_STATE_IDS, since=stop["t"] + 0.001, data=CLOSED_LOOP)


class TestReloadCarryOver:
    """A config reload (SIGHUP) continues the running task; it does not start over blind."""

    def test_running_task_goes_on_and_a_trip_right_after_stops_it(self, tmp_path: Path) -> None:
        """After the reload the task is still running, counters are kept, and an overcurrent stops it at once."""
        rig = Rig(tmp_path)
        rig.running()
        rig.feed(bms_frame(rig.t + 0.001, 60.0))  # one trip and stop before the reload
        rig.run(rig.t + 0.1)  # back to normal: the task resumed
        old = rig.engine
        assert old.gate.state == TaskGate.RUNNING and old.gate.stops == 1
        new = Engine(rig.cfg, rig.clock, rig.sink, events=rig.events, previous=old)
        new.start(rig.t)
        new.adopt(old)
        rig.engine = new
        assert new.gate.state == TaskGate.RUNNING and new.gate.stops == 1 and len(new.stats.trips) == 1
        rig.run(rig.t + 0.05)  # the new tree judges the carried-over data: no stop, no no-data failure
        assert new.gate.state == TaskGate.RUNNING
        t_trip = rig.t + 0.001
        rig.feed(bms_frame(t_trip, 60.0))  # within max_age of the reload: no start-up grace
        assert new.gate.state == TaskGate.STOPPED
        assert rig.sent(ESTOP_IDS, since=t_trip)

    def test_trip_between_the_thresholds_survives_the_reload(self, tmp_path: Path) -> None:
        """Tripped at 60 A, then 30 A (between 25 and 35) across a reload: the task stays stopped until 25 A."""
        rig = Rig(tmp_path)
        rig.running()
        rig.feed(bms_frame(rig.t + 0.001, 60.0))
        rig.run(rig.t + 0.05, pack_a=30.0, axis0_a=0.0)
        old = rig.engine
        assert old.gate.state == TaskGate.STOPPED
        new = Engine(rig.cfg, rig.clock, rig.sink, events=rig.events, previous=old)
        new.start(rig.t)
        new.adopt(old)
        rig.engine = new
        rig.run(rig.t + 0.1, pack_a=30.0, axis0_a=0.0)
        assert new.gate.state == TaskGate.STOPPED
        rig.run(rig.t + 0.05, pack_a=20.0, axis0_a=0.0)
        assert new.gate.state == TaskGate.RUNNING


class TestTripMemoryBound:
    """Trips are counted without end but kept in memory only up to a bound."""

    def test_trips_beyond_the_bound_are_counted_not_kept(self, tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
        """With room for one trip, two trips give trip_count 2 and one kept event."""
        import canguard.engine.core as engine_module

        monkeypatch.setattr(engine_module, "MAX_KEPT_TRIPS", 1)
        rig = Rig(tmp_path)
        rig.running()
        for _ in range(2):
            rig.feed(bms_frame(rig.t + 0.001, 60.0))
            rig.run(rig.t + 0.05, pack_a=10.0)
        assert rig.engine.stats.trip_count == 2
        assert len(rig.engine.stats.trips) == 1
        assert "trips 2" in rig.engine.status_line()


class TestStopReasons:
    """Stop events say which guard failed and why."""

    def test_halt_names_the_failing_guard(self, tmp_path: Path) -> None:
        """An overcurrent stop's reason names IsCurrentSafe, the overcurrent and the value."""
        rig = Rig(tmp_path)
        rig.running()
        rig.feed(bms_frame(rig.t + 0.001, 60.0))
        [stop] = rig.events.named("stop")
        assert "IsCurrentSafe" in stop["reason"] and "overcurrent" in stop["reason"] and "60" in stop["reason"]


class TestBusSink:
    """Frames the bus refuses are counted and reported, never raised."""

    def test_refused_frame_reaches_on_error(self, tmp_path: Path) -> None:
        """A send that fails calls on_error with the bus name (the metrics hook, which counts it)."""
        from canguard.engine.gate import BusSink

        cfg = load_config(write_config(tmp_path))
        errors: list[str] = []
        sink = BusSink(lambda bus, msg: False, on_error=errors.append)
        sink.send(cfg.stop.frames, "stop")
        assert sink.sent == 0
        assert errors == ["main"] * len(cfg.stop.frames)


class TestTickOnARowsTime:
    """A replay's column path runs a tick due at a row's own time before that row, as frame by frame does."""

    def test_source_back_on_the_tick_it_goes_stale(self, tmp_path: Path) -> None:
        """BMS silent and back on the very tick where it is 0.516 s old (max_age 0.5 s): that tick trips it stale."""
        from test_replay_columns import DBC, ROBOT_GUARD, compare, sim_lines

        doc = yaml.safe_load(ROBOT_GUARD.read_text(encoding="utf-8"))
        doc["dbc"] = [str(DBC)]
        doc["tree"]["file"] = str((ROBOT_GUARD.parent / doc["tree"]["file"]).resolve())
        doc["tree"]["tick_hz"] = 64  # ticks 1/64 s apart from a whole second: exact in binary and in 6 decimals
        doc["events"] = str(tmp_path / "events.jsonl")
        doc["state"]["file"] = str(tmp_path / "i2t_state.json")
        cfg_path = tmp_path / "tick64.yaml"
        cfg_path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        bms = f"{cantools.database.load_file(str(DBC)).get_message_by_name('BMS_Status').frame_id:03X}#"
        sim = sim_lines(1.75, "can0", ["normal"], 3)
        t0 = 1_700_000_000.0
        rows = [(round(t - sim[0][0] + t0, 6), line[line.index(")"):]) for t, line in sim]
        last = max(t for t, rest in rows if bms in rest and t <= t0 + 1.0)  # then silent
        back = t0 + (math.floor((last + 0.5 - t0) * 64) + 1) / 64  # the first tick that finds it over 0.5 s old
        returning = next(rest for t, rest in rows if bms in rest and t > back)
        kept = [(t, rest) for t, rest in rows if bms not in rest or not last < t <= back + 0.1]
        assert back not in {t for t, _ in kept}, "the returning frame must be the only row on that tick"
        log = tmp_path / "bms-back-on-a-tick.log"
        log.write_text("".join(f"({t:.6f}{rest}\n" for t, rest in sorted([*kept, (back, returning)],
                                                                         key=lambda row: row[0])), encoding="ascii")
        [col] = compare(load_config(cfg_path), log, tmp_path / "runs", (4096,))
        trips = json.loads(col.summary)["trips"]
        assert [(t["node"], t["reason"], t["t"]) for t in trips] == [("PackCurrent", "stale", back)]


HEAT_TREE = ('<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main"><ReactiveSequence>'
             '<IsCurrentSafe topic_name="/battery_state"/>'
             '<IsI2tSafe name="Heat" topic_name="axis0" model="leaky" continuous_current="6" peak_current="12" '
             'peak_time="1"/><ExecuteTask/></ReactiveSequence></BehaviorTree></root>')
"""The pack guarded, axis0 under a leaky I²t of S = 108 A²s (its ``level`` not wired), the task."""


def heat_block(rig: Rig, pulse: range, current_a: float, ref: Any) -> tuple[Any, list[tuple[float, float]]]:
    """299 ms of axis0 at 1 kHz after ``rig.t`` (``current_a`` at the samples of ``pulse``, else 0 A) and the pack
    every 10 ms, as one block; fed to the reference ``ref`` too: (the block, (time, level % after) per sample)."""
    from canguard.io.block import Block

    frames, levels = [], []
    for k in range(1, 300):
        t = rig.t + k * 0.001 + 0.0005
        current = current_a if k in pulse else 0.0
        frames.append(iq_frame(t, 0, current))
        if k % 10 == 0:
            frames.append(bms_frame(t + 0.0001, 10.0))
        ref.update(current, t)
        levels.append((t, 100.0 * ref.acc / ref.trip_level))
    return Block.of_frames(frames), levels


class TestI2tAcrossQuietTicks:
    """A block's rows run on across quiet ticks with an I²t guard: its peak is the model's own, heat saves exact."""

    def test_a_pulse_between_two_ticks_is_its_peak(self, tmp_path: Path) -> None:
        """A 3 ms pulse of 30 A between two 10 ms ticks: the peak is the heat at its end, above any tick's level.

        The reference maths fed the same samples gives the peak. The levels the ticks saw are all
        lower: sampled at ticks, the figure would under-report such a pulse.
        """
        from tests.reference_models import RefI2t

        (tmp_path / "heat.xml").write_text(HEAT_TREE, encoding="utf-8")
        rig = Rig(tmp_path, tree={"file": str(tmp_path / "heat.xml"), "main": "Main", "tick_hz": 100})
        rig.running()
        ref = RefI2t(kind="leaky", continuous_a=6.0, peak_a=12.0, peak_time_s=1.0)
        block, levels = heat_block(rig, range(100, 103), 30.0, ref)
        rig.engine.take("main", block)
        peak = rig.engine.stats.max_level_pct["Heat"]
        assert peak == pytest.approx(100.0 * ref.peak / ref.trip_level, rel=1e-12) and peak > 0.0
        at_ticks = [[level for t, level in levels if t < tick][-1] for tick in (T0 + k * 0.01 for k in range(11, 40))]
        assert peak > max(at_ticks)

    def test_heat_saved_at_a_tick_is_the_heat_of_its_time(self, tmp_path: Path) -> None:
        """The daemon saves heat every 50 ms: each save holds the heat of the samples before its tick, not after."""
        from tests.reference_models import RefI2t

        from canguard.protect.state import HeatStore

        (tmp_path / "heat.xml").write_text(HEAT_TREE, encoding="utf-8")
        saved: list[tuple[float, float]] = []
        heat = HeatStore(tmp_path / "heat.json")
        save = heat.save

        def recorded(models: Any, now: float) -> None:
            save(models, now)
            saved.append((now, models["Heat"].accumulator))

        heat.save = recorded  # type: ignore[method-assign]
        rig = Rig(tmp_path, heat=heat, tree={"file": str(tmp_path / "heat.xml"), "main": "Main", "tick_hz": 100},
                  state={"file": str(tmp_path / "heat.json"), "save_period": 0.05})
        rig.running()
        ref = RefI2t(kind="leaky", continuous_a=6.0, peak_a=12.0, peak_time_s=1.0)
        block, levels = heat_block(rig, range(1, 300), 9.0, ref)
        saved.clear()
        rig.engine.take("main", block)
        assert len(saved) >= 4
        for now, acc in saved:
            assert acc == pytest.approx([level for t, level in levels if t < now][-1] * ref.trip_level / 100.0,
                                        rel=1e-12)
