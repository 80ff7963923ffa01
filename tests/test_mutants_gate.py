"""The task gate as the journal and the bus see it: stop and resume events, stop time, resets, halts, confirmation.

Written against the mutants ``SCOPE=gate bash scripts/mutation.sh`` left alive in ``engine/gate.py``:
each test asserts an event field a user reads in the journal, a frame on the bus, or the stop time a
summary prints.
"""

from __future__ import annotations

import math
from typing import Any

import pytest
from tests.feed import observe

from canguard.config.schema import FrameSpec, SignalRef, SourceConfig, StopConfig, StopConfirm, TaskConfig
from canguard.engine.gate import BusSink, LogSink, TaskGate
from canguard.io.frame import Sample
from canguard.protect import SourceHealth

STOP = (FrameSpec("main", 0x10, b"\x00", label="Estop"),)
TASK = (FrameSpec("main", 0x20, b"\x01", label="Enable"),)
ESCALATE = (FrameSpec("main", 0x30, b"\x02", label="Idle"),)


class Recorder:
    def __init__(self) -> None:
        self.events: list[tuple[str, float, dict[str, Any]]] = []
        self.frames: list[tuple[str, str]] = []

    def on_event(self, event: str, now: float, **fields: Any) -> None:
        self.events.append((event, now, fields))

    def send(self, frames: Any, origin: str) -> None:
        self.frames.extend((origin, f.label) for f in frames)

    def named(self, name: str) -> list[tuple[float, dict[str, Any]]]:
        return [(t, f) for e, t, f in self.events if e == name]


def gate(rec: Recorder, **stop: Any) -> TaskGate:
    g = TaskGate(TaskConfig(0.02, TASK), StopConfig(0.05, STOP, **stop), rec, on_event=rec.on_event)
    return g


def tick(g: TaskGate, now: float, *, failed: bool = False, task: bool = True, reset: bool = False) -> None:
    g.begin_tick()
    if task:
        g.run("ExecuteTask", now)
    if reset:
        g.reset("ResetStop", now)
    if failed:
        g.stop(now, reason="tree failed at Guard", node="Guard")
    g.end_tick(now, failed, ("Guard", "overcurrent") if failed else ("", ""))


class TestStopAndResume:
    def test_resume_event_names_the_node_and_how_long(self) -> None:
        rec = Recorder()
        g = gate(rec)
        tick(g, 0.0)
        tick(g, 1.0, failed=True)
        tick(g, 3.5)
        [(t, fields)] = rec.named("resume")
        assert t == 3.5 and fields == {"node": "ExecuteTask", "reason": "stopped for 2.500 s"}
        assert g.state == TaskGate.RUNNING and g.stop_since is None

    def test_stop_frames_sent_ahead_go_out_once_and_the_stop_follows_even_without_a_halt(self) -> None:
        """Frames sent ahead of a sure halt are not sent again by it; a tick that does not halt still stops."""
        rec = Recorder()
        g = gate(rec)
        g.halts_next = lambda: True
        tick(g, 0.0)
        for halt in (True, False):
            stops = len(rec.named("stop"))
            g.ahead(1.0)
            assert rec.frames[-1] == ("stop", "Estop") and g.state == TaskGate.RUNNING
            assert len(rec.named("stop")) == stops  # recorded in the tick, after the frames
            g.begin_tick()
            if halt:
                g.halt("ExecuteTask", 1.0)
            g.end_tick(1.0, False)
            assert g.state == TaskGate.STOPPED and rec.frames.count(("stop", "Estop")) == 1
            assert rec.named("stop")[-1][1]["reason"] == ("ExecuteTask halted" if halt else
                                                          "stop frames sent at a guard's trip; the tree did not "
                                                          "halt the task")
            tick(g, 1.1)  # released
            rec.frames.clear()

    def test_stopped_time_adds_up_over_stops(self) -> None:
        rec = Recorder()
        g = gate(rec)
        tick(g, 0.0)
        tick(g, 1.0, failed=True)
        tick(g, 1.25)
        tick(g, 2.0, failed=True)
        assert g.stopped_total(2.5) == pytest.approx(0.75)  # 0.25 closed + 0.5 open
        tick(g, 2.5)
        assert g.stopped_s == pytest.approx(0.75) and g.stops == 2
        assert g.stopped_total(10.0) == pytest.approx(0.75)

    def test_min_stop_is_inclusive(self) -> None:
        rec = Recorder()
        g = gate(rec, min_stop_s=0.5)
        tick(g, 0.0)
        tick(g, 1.0, failed=True)
        tick(g, 1.25)
        assert g.state == TaskGate.STOPPED
        assert rec.named("reason")[-1][1]["reason"] == "stop.min_stop 0.5 s not elapsed"
        tick(g, 1.5)
        assert g.state == TaskGate.RUNNING

    def test_what_holds_the_stop_is_journalled_word_for_word(self) -> None:
        rec = Recorder()
        g = gate(rec, release="manual")
        tick(g, 0.0)
        tick(g, 1.0, failed=True)
        tick(g, 1.1, task=False)
        tick(g, 1.2)
        g.inhibit("bus main", "bus main down: gone", 1.3)
        g.inhibit("source bms", "bms stale", 1.3)
        tick(g, 1.3)
        reasons = [f["reason"] for _t, f in rec.named("reason")]
        assert reasons == ["task not reached in the tree", "stop.release manual: waiting for ResetStop",
                           "bus main down: gone; bms stale"]  # by key: bus main, source bms
        assert rec.named("reason")[0][1]["previous"] == "overcurrent"
        g.release("bus main")
        g.release("source bms")
        assert g._release_rule(1.4, False) and g._release_rule(1.4, True)
        g.begin_tick()
        g.run("ExecuteTask", 1.4)
        g._reset_this_tick = True
        assert not g._release_rule(1.4, False) and g._release_rule(1.4, True)

    def test_a_stop_resets_and_confirmation_state_after_resume(self) -> None:
        rec = Recorder()
        g = gate(rec)
        tick(g, 0.0)
        tick(g, 1.0, failed=True)
        assert g.next_deadline() == pytest.approx(1.05)  # the stop repeat
        tick(g, 1.2)
        assert g.next_deadline() == pytest.approx(1.22)  # the task period again, no stop repeat left


class TestResetAndHalt:
    def test_reset_says_what_it_did(self) -> None:
        rec = Recorder()
        auto = gate(rec)
        assert auto.reset("R", 0.0) == "no stop to reset"
        auto.stop(0.0, reason="x")
        assert auto.reset("R", 0.0) == "stop.release is auto: no reset needed"
        manual = gate(rec, release="manual")
        manual.stop(0.0, reason="x")
        assert manual.reset("R", 0.0) == "reset requested"
        tick(manual, 0.1, reset=False)
        assert manual.state == TaskGate.STOPPED
        tick(manual, 0.2, reset=True)
        assert manual.state == TaskGate.RUNNING

    def test_halt_stops_a_running_task_with_why(self) -> None:
        rec = Recorder()
        g = gate(rec)
        g.halt("ExecuteTask", 0.0)
        assert g.state == TaskGate.IDLE and not rec.named("stop")  # nothing runs: nothing to halt
        tick(g, 0.0)
        g.explain = lambda: "Guard: overcurrent"
        g.halt("ExecuteTask", 0.5)
        [(t, fields)] = rec.named("stop")
        assert t == 0.5 and fields == {"node": "ExecuteTask", "reason": "ExecuteTask halted (Guard: overcurrent)"}
        rec2 = Recorder()
        g2 = gate(rec2)
        tick(g2, 0.0)
        g2.halt("ExecuteTask", 0.5)
        assert rec2.named("stop")[0][1]["reason"] == "ExecuteTask halted"


class TestConfirm:
    @staticmethod
    def health() -> SourceHealth:
        ref = SignalRef("current", "main", "M", 0x1, False, "I", "A", None, None)
        return SourceHealth(SourceConfig("axis0", "current", "main", (ref,), 0.5))

    def setup(self, rec: Recorder, op: str = "<", value: float = 1.0) -> tuple[TaskGate, SourceHealth]:
        h = self.health()
        g = TaskGate(TaskConfig(0.02, TASK),
                     StopConfig(0.05, STOP, StopConfirm("axis0", "current", op, value, 0.2), ESCALATE),  # type: ignore[arg-type]
                     rec, health={"axis0": h}, on_event=rec.on_event)
        return g, h

    def test_confirmed_only_by_a_sample_taken_after_the_stop(self) -> None:
        rec = Recorder()
        g, h = self.setup(rec)
        observe(h, Sample("axis0", "current", 0.5, 1.0))  # low already, but at the stop's own time
        g.stop(1.0, reason="x")
        g.service(1.05)
        assert not rec.named("confirmed")
        observe(h, Sample("axis0", "current", -0.5, 1.06))
        g.service(1.07)
        [(t, fields)] = rec.named("confirmed")
        assert t == 1.07 and fields == {"source": "axis0", "value": -0.5, "threshold": 1.0,
                                        "reason": "current < 1.0 after 0.070 s"}
        g.service(1.3)
        assert not rec.named("escalate")

    def test_escalates_at_the_deadline_with_frames(self) -> None:
        rec = Recorder()
        g, h = self.setup(rec)
        g.stop(1.0, reason="x")
        observe(h, Sample("axis0", "current", -20.0, 1.1))  # still pushing: |-20| is not below 1
        g.service(1.1)
        assert not rec.named("escalate")
        assert g.next_deadline() == pytest.approx(1.1 + 0.05)
        g.service(1.2)
        [(t, fields)] = rec.named("escalate")
        assert t == 1.2 and fields["reason"] == "not confirmed within 0.2 s: current < 1.0 does not hold"
        assert fields["value"] == -20.0 and ("escalate", "Idle") in rec.frames
        g.service(1.5)
        assert len(rec.named("escalate")) == 1

    def test_a_stale_source_never_confirms(self) -> None:
        rec = Recorder()
        g, h = self.setup(rec)
        observe(h, Sample("axis0", "current", 0.0, 1.01))
        g.stop(1.0, reason="x")
        g.service(1.6)  # the sample is 0.59 s old: stale (max_age 0.5)
        assert not rec.named("confirmed") and rec.named("escalate")

    def test_equality_compares_the_value_itself(self) -> None:
        rec = Recorder()
        g, h = self.setup(rec, "==", -1.0)
        g.stop(1.0, reason="x")
        observe(h, Sample("axis0", "current", -1.0, 1.05))
        g.service(1.06)
        assert rec.named("confirmed")

    def test_no_pending_confirmation_after_a_resume(self) -> None:
        rec = Recorder()
        g, _h = self.setup(rec)
        tick(g, 0.0)
        tick(g, 1.0, failed=True)
        tick(g, 1.1)
        g.service(2.0)
        assert not rec.named("escalate") and not rec.named("confirmed")


class TestSinks:
    def test_log_sink_counts_and_keeps_with_the_time_and_channel(self) -> None:
        from canguard.config.schema import BusConfig

        now = [2.5]
        sink = LogSink(lambda: now[0], {"main": BusConfig("main", {"interface": "virtual", "channel": "can7"})})
        sink.send(STOP + TASK, "stop")
        assert sink.sent == 2 and sink.origins == ["stop", "stop"]
        assert [(f.t, f.channel, f.arbitration_id, f.data) for f in sink.frames] == [
            (2.5, "can7", 0x10, b"\x00"), (2.5, "can7", 0x20, b"\x01")]
        quiet = LogSink(lambda: 0.0, {}, keep=False)
        quiet.send(STOP, "stop")
        assert quiet.sent == 1 and quiet.frames == []

    def test_bus_sink_counts_refusals_and_says_which(self) -> None:
        sent: list[Any] = []
        errors: list[str] = []
        refused: list[tuple[str, str, str]] = []

        def send(bus: str, msg: Any) -> bool:
            sent.append((bus, msg.arbitration_id, bytes(msg.data), msg.is_extended_id))
            return msg.arbitration_id != 0x20

        sink = BusSink(send, on_error=errors.append,
                       on_refused=lambda b, label, o, held: refused.append((b, label, o)))
        sink.send(STOP + TASK, "task")
        assert sink.sent == 1
        assert sent == [("main", 0x10, b"\x00", False), ("main", 0x20, b"\x01", False)]
        assert errors == ["main"] and refused == [("main", "Enable", "task")]


def test_next_deadline_idle_is_never() -> None:
    assert gate(Recorder()).next_deadline() == math.inf


class TestMore:
    def test_a_reload_continues_the_stop(self) -> None:
        rec = Recorder()
        h = TestConfirm.health()
        cfg = StopConfig(0.05, STOP, StopConfirm("axis0", "current", "<", 1.0, 0.2))  # type: ignore[arg-type]
        old = TaskGate(TaskConfig(0.02, TASK), cfg, rec, health={"axis0": h}, on_event=rec.on_event)
        tick(old, 0.0)
        old.inhibit("source bms", "bms stale", 0.5, node="BMS")
        old.begin_tick()
        old.action("Work", "task", TASK, 0.6)
        old.end_tick(0.6, False)
        new = TaskGate(TaskConfig(0.02, TASK), cfg, rec, health={"axis0": h}, on_event=rec.on_event)
        new.adopt(old)
        assert (new.state, new.stop_since, new.stop_reason, new.inhibits, new.stops) == (
            TaskGate.STOPPED, 0.5, "bms stale", {"source bms": "bms stale"}, 1)
        assert new.next_deadline() == pytest.approx(0.55)  # the stop repeat, carried
        new.service(0.7)
        assert rec.named("escalate")  # the confirmation was still pending: carried too
        assert rec.named("stop")[0][1] == {"node": "BMS", "reason": "bms stale"}
        plain = TaskGate(TaskConfig(0.02, TASK), StopConfig(0.05, STOP), rec, on_event=rec.on_event)
        plain.adopt(old)
        assert plain.next_deadline() == pytest.approx(0.55)  # no confirmation configured: none pending

    def test_action_notes(self) -> None:
        rec = Recorder()
        g = gate(rec)
        notes: list[str] = []
        g.begin_tick()
        g.action("Recover", "recovery", ESCALATE, 0.0, notes.append)
        g.action("Work", "task", TASK, 0.0, notes.append)
        g.stop(0.0, reason="x")
        g.end_tick(0.0, True)
        assert notes == ["1 frame(s) sent (recovery)", "1 frame(s) withheld: task stopped"]
        assert ("Recover", "Idle") in rec.frames and ("Work", "Enable") not in rec.frames
        notes.clear()
        g2 = gate(Recorder())
        g2.begin_tick()
        g2.action("Work", "task", TASK, 0.0, notes.append)
        g2.end_tick(0.0, False)
        assert notes == ["1 frame(s) sent"] and g2.state == TaskGate.RUNNING

    def test_a_tree_without_task_nodes_starts_by_not_failing(self) -> None:
        rec = Recorder()
        g = gate(rec)
        tick(g, 0.0, task=False)
        assert g.state == TaskGate.IDLE  # the tree has a task node that was not reached
        g.tree_has_task = False
        tick(g, 0.1, task=False)
        assert g.state == TaskGate.RUNNING

    def test_periodic_frames_fall_due_exactly_at_their_time(self) -> None:
        rec = Recorder()
        g = gate(rec)
        tick(g, 0.0)
        assert rec.frames == [("task", "Enable")]
        g.service(0.019)
        g.service(0.02)
        assert rec.frames == [("task", "Enable")] * 2
        g.stop(0.03, reason="x")
        g.service(0.079)
        g.service(0.08)
        assert rec.frames[-2:] == [("stop", "Estop"), ("stop", "Estop")]
        assert g.stopped_total(0.09) == pytest.approx(0.06)


class TestSinkOutput:
    def test_emit_lines_are_candump_with_the_bus_channel_extended_and_fd(self) -> None:
        import io

        from canguard.config.schema import BusConfig

        out = io.StringIO()
        sink = LogSink(lambda: 1.5, {"main": BusConfig("main", {"interface": "virtual", "channel": "can3"})},
                       out=out, keep=False)
        sink.send((FrameSpec("main", 0x18FF50E5, b"\x01\x02", is_extended_id=True, label="Ext"),), "task")
        sink.send((FrameSpec("other", 0x123, bytes(12), is_fd=True, label="Fd"),), "stop")
        assert sink.sent == 2 and sink.frames == []
        assert out.getvalue() == ("(1.500000) can3 18FF50E5#0102\n"
                                  "(1.500000) other 123##0" + "00" * 12 + "\n")

    def test_bus_sink_hands_over_extended_and_fd_and_logs_which_frame(self, caplog: pytest.LogCaptureFixture) -> None:
        import logging

        got: list[tuple[bool, bool]] = []

        def send(bus: str, msg: Any) -> bool:
            got.append((msg.is_extended_id, msg.is_fd))
            return bus == "main"

        sink = BusSink(send)
        frames = (FrameSpec("main", 0x18FF50E5, b"\x01", is_extended_id=True, label="A"),
                  FrameSpec("main", 0x1, bytes(12), is_fd=True, label="B"),
                  FrameSpec("gone", 0x2, b"", label="C"))
        caplog.set_level(logging.WARNING, logger="canguard.engine.gate")
        sink.send(frames, "stop")
        assert got == [(True, False), (False, True), (False, False)]
        assert sink.sent == 2
        assert [r.getMessage() for r in caplog.records] == ["could not send C (stop) on bus gone"]


class TestScheduleAndConfirm:
    def test_task_frames_keep_their_grid_and_restart_after_a_late_service(self) -> None:
        rec = Recorder()
        g = gate(rec)
        tick(g, 0.0)
        assert g.next_deadline() == pytest.approx(0.02)
        g.service(0.021)  # a little late: the next stays on the grid
        assert g.next_deadline() == pytest.approx(0.04)
        g.service(0.1)  # far behind: restart from now, no burst
        assert g.next_deadline() == pytest.approx(0.12)
        assert len(rec.frames) == 3

    def test_not_equal_compares_the_value_itself(self) -> None:
        rec = Recorder()
        g, h = TestConfirm().setup(rec, "!=", 1.0)
        g.stop(1.0, reason="x")
        observe(h, Sample("axis0", "current", -1.0, 1.05))  # |-1| == 1, but -1 != 1: confirmed
        g.service(1.06)
        assert rec.named("confirmed")

    def test_only_the_confirm_signal_must_be_fresh(self) -> None:
        ref_i = SignalRef("current", "main", "M", 0x1, False, "I", "A", None, None)
        ref_v = SignalRef("voltage", "main", "M", 0x2, False, "V", "V", None, None)
        h = SourceHealth(SourceConfig("axis0", "current", "main", (ref_i, ref_v), 0.5))
        rec = Recorder()
        g = TaskGate(TaskConfig(0.02, TASK),
                     StopConfig(0.05, STOP, StopConfirm("axis0", "current", "<", 1.0, 0.5)),  # type: ignore[arg-type]
                     rec, health={"axis0": h}, on_event=rec.on_event)
        observe(h, Sample("axis0", "voltage", 48.0, 0.0))  # stale by 1.2
        g.stop(1.0, reason="x")
        observe(h, Sample("axis0", "current", 0.2, 1.1))
        g.service(1.2)
        assert rec.named("confirmed") and not rec.named("escalate")


class TestOneByOne:
    """Written against the survivors of the one-by-one pass (docs/mutants.md, "The guard nodes")."""

    def test_a_stop_or_inhibit_nobody_named_has_an_empty_node(self) -> None:
        """The daemon's exit stop and a stale source's inhibit name no node: the stop event's node is ""."""
        rec = Recorder()
        g = gate(rec)
        g.stop(1.0, reason="end")
        rec2 = Recorder()
        g2 = gate(rec2)
        tick(g2, 0.0)
        g2.inhibit("bus main", "bus main down: gone", 0.5)
        assert rec.named("stop")[0][1] == {"node": "", "reason": "end"}
        assert rec2.named("stop")[0][1] == {"node": "", "reason": "bus main down: gone"}

    def test_a_reload_keeps_what_holds_the_stop(self) -> None:
        """After a reload, a new hold is journalled as a change from the cause noted before it."""
        rec = Recorder()
        old = gate(rec, release="manual")
        tick(old, 0.0)
        tick(old, 1.0, failed=True)
        new = gate(rec, release="manual")
        new.adopt(old)
        tick(new, 1.1)
        [(t, fields)] = rec.named("reason")
        assert t == 1.1 and fields == {"node": "", "reason": "stop.release manual: waiting for ResetStop",
                                       "previous": "overcurrent"}

    def test_a_failed_tick_without_a_named_cause_says_tree_failed(self) -> None:
        """A FAILURE nobody is named for holds the stop as "tree failed" (the reason event's previous)."""
        rec = Recorder()
        g = gate(rec)
        tick(g, 0.0)
        g.stop(1.0, reason="x")
        g.begin_tick()
        g.end_tick(1.0, True)
        tick(g, 1.1, task=False)
        [(_t, fields)] = rec.named("reason")
        assert fields["previous"] == "tree failed" and fields["reason"] == "task not reached in the tree"

    def test_a_confirmation_done_before_a_reload_is_not_repeated(self) -> None:
        """An escalation already sent is not sent again by the reloaded gate."""
        rec = Recorder()
        g, h = TestConfirm().setup(rec)
        g.stop(1.0, reason="x")
        g.service(1.2)
        assert len(rec.named("escalate")) == 1
        new = TaskGate(g.task_cfg, g.stop_cfg, rec, health={"axis0": h}, on_event=rec.on_event)
        new.adopt(g)
        new.service(1.3)
        assert len(rec.named("escalate")) == 1 and rec.frames.count(("escalate", "Idle")) == 1

    def test_after_an_escalation_the_next_deadline_is_the_stop_repeat(self) -> None:
        """Once the confirmation is settled its deadline is no longer due (no busy loop on a past time)."""
        rec = Recorder()
        g, _h = TestConfirm().setup(rec)
        g.stop(1.0, reason="x")
        g.service(1.2)
        assert rec.named("escalate")
        assert g.next_deadline() == pytest.approx(1.25)

    def test_a_confirmation_is_journalled_once(self) -> None:
        """A confirmed stop is not confirmed again at the next service."""
        rec = Recorder()
        g, h = TestConfirm().setup(rec)
        g.stop(1.0, reason="x")
        observe(h, Sample("axis0", "current", 0.1, 1.05))
        g.service(1.06)
        g.service(1.1)
        g.service(1.15)
        assert len(rec.named("confirmed")) == 1
        assert g.next_deadline() == pytest.approx(1.2)  # the stop repeat

    def test_a_task_action_alone_sends_no_execute_task_frames(self) -> None:
        """A task started by a task action sends that action's frames, not the periodic task frames."""
        rec = Recorder()
        g = gate(rec)
        g.begin_tick()
        g.action("Work", "task", TASK, 0.0)
        g.end_tick(0.0, False)
        assert g.state == TaskGate.RUNNING
        assert rec.frames == [("Work", "Enable")] and g.next_deadline() == math.inf

    def test_a_tree_without_task_nodes_resumes_with_an_empty_node(self) -> None:
        """The resume event of a tree without ExecuteTask or task action names no node ("")."""
        rec = Recorder()
        g = gate(rec)
        g.tree_has_task = False
        tick(g, 0.0, task=False)
        g.stop(1.0, reason="x")
        tick(g, 1.5, task=False)
        [(t, fields)] = rec.named("resume")
        assert t == 1.5 and fields == {"node": "", "reason": "stopped for 0.500 s"}

    def test_a_service_exactly_one_period_late_sends_one_frame(self) -> None:
        """Late by exactly one period: one task frame, the next a full period later (no burst)."""
        rec = Recorder()
        g = gate(rec)
        tick(g, 0.0)
        g.service(0.04)
        assert g.next_deadline() == pytest.approx(0.06)
        g.service(0.04)
        assert rec.frames == [("task", "Enable")] * 2

    def test_a_gap_in_time_before_the_start_and_after_a_resume(self) -> None:
        """skip_to (a gap in a log or a stall) works idle and after a resume; the stop repeat is kept after."""
        rec = Recorder()
        g = gate(rec)
        g.skip_to(5.0)
        tick(g, 5.0)
        tick(g, 6.0, failed=True)
        tick(g, 6.5)
        g.skip_to(10.0)
        assert g.next_deadline() == pytest.approx(10.0)  # the task frame due in the gap, now
        g.stop(11.0, reason="x")
        assert g.next_deadline() == pytest.approx(11.05)
