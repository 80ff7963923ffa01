"""Stops that end: the one release rule, on every seed tree.

Each seed config (config/canguard.yaml and config/examples/*.yaml, eight in all)
runs in-process on a manual clock over frames written here: a guard trips (or
the tree fails as its design note says) and later passes again. The journal must
show the stop, then the resume when the tree says so, and the frames sent must
never mix: no task frame between a stop and its resume, no stop frame between a
resume and the next stop, never both in one tick.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import cantools
import pytest
import yaml

from canguard.bt import nodes
from canguard.bt.checks import show_tree
from canguard.bt.nodes.actions import ConfiguredAction
from canguard.config.loader import load_config
from canguard.config.schema import Config
from canguard.engine.core import Engine
from canguard.engine.gate import LogSink
from canguard.errors import ConfigError
from canguard.io.block import one_block
from canguard.io.clock import ManualClock
from canguard.io.frame import Frame
from checkout import REPO

DBC = REPO / "dbc" / "robot.dbc"
T0 = 1_700_000_000.0
SEEDS = [*sorted((REPO / "config" / "examples").glob("*.yaml")), REPO / "config" / "canguard.yaml"]


@functools.lru_cache(maxsize=1)
def _db() -> Any:
    return cantools.database.load_file(str(DBC))


def dbc_frame(t: float, name: str, **values: float) -> Frame:
    """Message ``name`` at ``t``: every signal 0 unless given (out-of-range values are encoded as asked)."""
    msg = _db().get_message_by_name(name)
    signals = {s.name: 0 for s in msg.signals} | values
    return Frame(t, "can0", msg.frame_id, bytes(msg.encode(signals, strict=False)), msg.is_extended_frame)


def robot_frames(t: float, pack_a: float = 10.0, efforts: Mapping[int, float] | None = None,
                 bms: bool = True) -> list[Frame]:
    """One 10 ms round of the robot: BMS, four torque estimates, four Iq (0.5 A: a motor at rest)."""
    out = [dbc_frame(t, "BMS_Status", Pack_Current=pack_a, Pack_Voltage=48, Present=1)] if bms else []
    for axis in range(4):
        effort = (efforts or {}).get(axis, 1.0)
        out.append(dbc_frame(t + 0.0001, f"Axis{axis}_Get_Torques", Torque_Estimate=effort))
        out.append(dbc_frame(t + 0.0002, f"Axis{axis}_Get_Iq", Iq_Measured=0.5, Iq_Setpoint=0.5))
    return out


class Events:
    """An event sink keeping every event."""

    def __init__(self) -> None:
        self.events: list[dict[str, Any]] = []

    def write(self, event: Mapping[str, Any]) -> None:
        """Keep it."""
        self.events.append(dict(event))

    def flush(self) -> None:
        """Nothing to make durable."""

    def named(self, *names: str) -> list[dict[str, Any]]:
        """Events called one of ``names``, in order."""
        return [e for e in self.events if e["event"] in names]


class Run:
    """One seed config's engine on a manual clock; frames land in a LogSink with their origins."""

    def __init__(self, cfg: Config) -> None:
        self.cfg = cfg
        self.clock = ManualClock(T0)
        self.sink = LogSink(self.clock.now, cfg.buses)
        self.events = Events()
        self.engine = Engine(cfg, self.clock, self.sink, events=self.events)
        self.engine.start(T0)
        actions = [n for n in self.engine.root.iterate() if isinstance(n, ConfiguredAction)]
        self.task_origins = {"task"} | {n.name for n in actions if n.role == "task"}

    def feed(self, frames: list[Frame]) -> None:
        """Feed frames on bus main."""
        for f in frames:
            self.engine.take("main", one_block(f))

    def until(self, end_s: float, frames: Callable[[float], list[Frame]] | None = None, step_s: float = 0.01) -> None:
        """Up to T0 + ``end_s``: ``frames(seconds)`` every ``step_s`` (or only ticks), then advance to it."""
        s = round(self.engine.clock.now() - T0, 6) - step_s
        while True:
            s += step_s
            if s >= end_s - 1e-9:
                break
            if frames is not None:
                self.feed(frames(s))
            else:
                self.engine.advance(T0 + s)
        self.engine.advance(T0 + end_s)
        self.clock.advance_to(T0 + end_s)

    def times(self, event: str) -> list[float]:
        """Seconds after T0 of every ``event``."""
        return [e["t"] - T0 for e in self.events.named(event)]

    def check_frames_never_mix(self) -> None:
        """No tick sends both kinds; no task frame while stopped; no stop frame while running."""
        kinds: dict[float, set[str]] = {}
        for f, origin in zip(self.sink.frames, self.sink.origins, strict=True):
            kind = "task" if origin in self.task_origins else "stop" if origin in ("stop", "escalate") else ""
            if kind:
                kinds.setdefault(f.t, set()).add(kind)
        assert not [t for t, k in kinds.items() if len(k) > 1], "a tick sent both task and stop frames"
        edges = sorted([(e["t"], e["event"]) for e in self.events.named("stop", "resume")])
        for t, k in kinds.items():
            state = "running"
            for et, name in edges:
                if et <= t:
                    state = "stopped" if name == "stop" else "running"
            if state == "stopped":
                assert "task" not in k, f"task frame at {t - T0:.3f} s while stopped"
            else:
                assert "stop" not in k or t in {et for et, n in edges if n == "stop"}, (
                    f"stop frame at {t - T0:.3f} s while running"
                )


def pack_fault(start_s: float, end_s: float, amps: float = 50.0) -> Callable[[float], list[Frame]]:
    """The robot at 10 A, the pack at ``amps`` from ``start_s`` to ``end_s``."""
    return lambda s: robot_frames(T0 + s, pack_a=amps if start_s <= s < end_s else 10.0)


def _resumes_after(run: Run, stop_s: float, resume_s: float, tol_s: float) -> None:
    stops, resumes = run.times("stop"), run.times("resume")
    assert any(abs(t - stop_s) <= tol_s for t in stops), (stops, resumes)
    after = [t for t in resumes if t > stop_s - tol_s]
    assert after and abs(after[0] - resume_s) <= tol_s, (stops, resumes)


class TestEverySeedTreeResumes:
    """Each of the eight seed configs stops when its tree fails and resumes when its tree passes again."""

    def test_there_are_eight_seeds(self) -> None:
        """config/canguard.yaml and the seven examples: the issue's eight seed trees."""
        assert len(SEEDS) == 8

    @pytest.mark.parametrize("name", ["canguard.yaml", "protected_operation.yaml", "robot_guard.yaml",
                                      "multi_current_monitoring.yaml"])
    def test_pack_overcurrent_stops_then_resumes(self, name: str) -> None:
        """50 A on the pack from 1.0 s to 1.5 s: stop at 1.0 s, resume at 1.5 s, task frames again after it."""
        path = next(p for p in SEEDS if p.name == name)
        run = Run(load_config(path))
        run.until(3.0, pack_fault(1.0, 1.5))
        _resumes_after(run, 1.0, 1.5, 0.011)
        resume = T0 + run.times("resume")[0]
        task_after = [f for f, o in zip(run.sink.frames, run.sink.origins, strict=True)
                      if o in run.task_origins and f.t >= resume]
        assert task_after and task_after[0].t == resume  # the task's frames go out in the releasing tick
        assert run.engine.gate.state == "running"
        run.check_frames_never_mix()

    def test_multi_current_withholds_continue_operation_while_stopped(self) -> None:
        """MultiCurrentMonitoring: ContinueOperation is the task; its frames never go out with the e-stop."""
        run = Run(load_config(REPO / "config" / "examples" / "multi_current_monitoring.yaml"))
        run.until(3.0, pack_fault(1.0, 1.5))
        origins = list(zip(run.sink.origins, [f.t - T0 for f in run.sink.frames], strict=True))
        stop_s, resume_s = run.times("stop")[0], run.times("resume")[0]
        assert [s for o, s in origins if o == "ContinueOperation" and stop_s <= s < resume_s] == []
        assert [s for o, s in origins if o == "stop" and s >= resume_s] == []
        assert any(o == "ContinueOperation" for o, s in origins if s >= resume_s)

    def test_cooldown_recovery(self) -> None:
        """CooldownRecovery fails between recoveries and passes again each 10 s: stop, then resume at 10 s.

        (The first tick at or after 10 s in epoch-second floats is the one at 10.1 s: one 10 Hz tick of slack.)
        """
        run = Run(load_config(REPO / "config" / "examples" / "cooldown_recovery.yaml"))
        run.until(21.0)
        _resumes_after(run, 0.1, 10.0, 0.1 + 1e-3)
        resumes = run.times("resume")
        assert len(resumes) == 2  # about 10 s and 20 s
        # PerformRecovery (role: recovery) sends at the first tick and in each tick that ends a stop
        recoveries = sorted({f.t - T0 for f, o in zip(run.sink.frames, run.sink.origins, strict=True)
                             if o == "PerformRecovery"})
        assert recoveries == [0.0, *resumes]
        run.check_frames_never_mix()

    def test_periodic_health_check(self) -> None:
        """PeriodicHealthCheck fails for its first 60 s: stopped from the first tick, resumed at 60 s."""
        run = Run(load_config(REPO / "config" / "examples" / "periodic_health_check.yaml"))
        run.until(61.0)
        _resumes_after(run, 0.0, 60.0, 0.1 + 1e-3)
        run.check_frames_never_mix()

    def test_time_windowed_action(self) -> None:
        """Mission: before 10 s the window is closed (stopped); at 10 s PerformTimedAction runs and the stop ends."""
        run = Run(load_config(REPO / "config" / "examples" / "time_windowed_action.yaml"))
        run.until(12.0)
        _resumes_after(run, 0.0, 10.0, 0.1 + 1e-3)
        sent = zip(run.sink.frames, run.sink.origins, strict=True)
        timed = [f.t - T0 for f, o in sent if o.endswith("PerformTimedAction")]  # Window/PerformTimedAction
        assert timed and min(timed) == run.times("resume")[0]
        run.check_frames_never_mix()

    def test_profiling_latency_warning(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """LatencyWarning: 80 ms of processing from 1 s to 1.5 s fails IsValueBelow; 1 ms again resumes."""
        run = Run(load_config(REPO / "config" / "examples" / "profiling.yaml"))
        fake = {"t": 0.0}

        def perf_counter() -> float:
            s = run.engine.clock.now() - T0
            fake["t"] += 0.08 if 1.0 <= s < 1.5 else 0.0005  # a tick's time is its second read's step
            return fake["t"]

        monkeypatch.setattr(nodes.control, "perf_counter", perf_counter)
        run.until(2.0)
        _resumes_after(run, 1.0, 1.5, 0.021)
        run.check_frames_never_mix()


class TestReleaseRule:
    """What holds a stop beyond the guards: min_stop, a manual reset, a task action failing in the same tick."""

    def _cfg(self, tmp_path: Path, seed: str = "multi_current_monitoring.yaml", **stop: Any) -> Config:
        src = REPO / "config" / "examples" / seed
        doc = yaml.safe_load(src.read_text(encoding="utf-8"))
        doc["dbc"] = [str(DBC)]
        doc["tree"]["file"] = str((src.parent / doc["tree"]["file"]).resolve())
        doc.pop("events", None)
        doc.pop("state", None)
        doc["stop"] = {**doc.get("stop", {}), **stop}
        path = tmp_path / "c.yaml"
        path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        return load_config(path)

    def test_min_stop_holds_the_stop(self, tmp_path: Path) -> None:
        """stop.min_stop 0.5: the guard passes again at 1.1 s, the task resumes only at 1.5 s, and a reason says why."""
        run = Run(self._cfg(tmp_path, min_stop=0.5))
        run.until(2.0, pack_fault(1.0, 1.1))
        assert run.times("stop") == [pytest.approx(1.0, abs=0.011)]
        assert run.times("resume") == [pytest.approx(1.5, abs=0.021)]
        [reason] = run.events.named("reason")
        assert "min_stop" in reason["reason"] and "overcurrent" in reason["previous"]
        run.check_frames_never_mix()

    def test_manual_release_needs_reset_stop(self, tmp_path: Path) -> None:
        """stop.release manual: the guard passing is not enough; ResetStop ticked in a passing tick ends the stop."""
        self._cfg(tmp_path, release="manual")
        tree = tmp_path / "t.xml"
        tree.write_text(
            '<root BTCPP_format="4" main_tree_to_execute="M"><BehaviorTree ID="M"><ReactiveSequence>'
            '<IsCurrentNormal topic_name="/battery_state" max_current="40.0"/>'
            '<Fallback><IsValueBelow value="{now_s}" threshold="2.0"/><ResetStop/></Fallback>'
            '<ContinueOperation/></ReactiveSequence></BehaviorTree></root>', encoding="utf-8")
        doc = yaml.safe_load((tmp_path / "c.yaml").read_text(encoding="utf-8"))
        doc["tree"] = {"file": str(tree), "main": "M", "tick_hz": 50}
        (tmp_path / "c.yaml").write_text(yaml.safe_dump(doc), encoding="utf-8")
        cfg = load_config(tmp_path / "c.yaml")
        run = Run(cfg)
        from py_trees.blackboard import Blackboard

        def frames(s: float) -> list[Frame]:
            Blackboard.storage["/now_s"] = s  # the operator's reset: from 2 s on, ResetStop is ticked
            return pack_fault(1.0, 1.1)(s)

        run.until(3.0, frames)
        assert run.times("stop") == [pytest.approx(1.0, abs=0.011)]
        assert run.times("resume") == [pytest.approx(2.0, abs=0.021)]
        assert "ResetStop" in run.events.named("reason")[-1]["reason"]
        run.check_frames_never_mix()

    def test_withheld_task_frames_are_said(self, tmp_path: Path) -> None:
        """A task action ticked in a tick that fails later sends nothing; the node says so."""
        self._cfg(tmp_path, seed="profiling.yaml")
        doc = yaml.safe_load((tmp_path / "c.yaml").read_text(encoding="utf-8"))
        doc["actions"]["ProcessSensorData"] = {"frames": [{"id": 0x123, "data": "01"}]}
        doc["stop"] = {"frames": [{"id": 0x7, "data": "ff"}]}
        tree = tmp_path / "t.xml"
        tree.write_text(
            '<root BTCPP_format="4" main_tree_to_execute="M"><BehaviorTree ID="M"><Sequence>'
            '<ProcessSensorData/><IsValueBelow value="{load}" threshold="1.0"/></Sequence></BehaviorTree></root>',
            encoding="utf-8")
        doc["tree"] = {"file": str(tree), "main": "M", "tick_hz": 10}
        (tmp_path / "c.yaml").write_text(yaml.safe_dump(doc), encoding="utf-8")
        run = Run(load_config(tmp_path / "c.yaml"))
        from py_trees.blackboard import Blackboard

        Blackboard.storage["/load"] = 5.0
        run.until(1.0)
        node = next(n for n in run.engine.root.iterate() if n.name == "ProcessSensorData")
        assert "1 frame(s) withheld" in node.feedback_message
        assert [o for o in run.sink.origins if o == "ProcessSensorData"] == []
        Blackboard.storage["/load"] = 0.0
        run.until(1.5)
        assert run.times("resume") == [pytest.approx(1.1)]
        assert "sent" in node.feedback_message
        run.check_frames_never_mix()


class TestReasonEvents:
    """While stopped, a change of what holds the stop is a ``reason`` event (t, event, node, reason, previous)."""

    def test_overcurrent_then_stale(self) -> None:
        """The pack trips on overcurrent, then the BMS goes silent: a reason event says stale, previous overcurrent."""
        run = Run(load_config(REPO / "config" / "examples" / "robot_guard.yaml"))

        def frames(s: float) -> list[Frame]:
            return robot_frames(T0 + s, pack_a=50.0 if s >= 1.0 else 10.0, bms=s < 1.2)

        run.until(2.5, frames)
        reasons = run.events.named("reason")
        assert reasons, run.events.named("stop")
        first = reasons[0]
        assert set(first) >= {"t", "event", "node", "reason", "previous"}
        assert first["node"] == "PackCurrent"
        assert "stale" in first["reason"] and "overcurrent" in first["previous"]
        assert 1.69 <= first["t"] - T0 <= 1.72  # max_age 0.5 s after the last BMS frame at 1.19 s
        assert run.times("resume") == []

    def test_one_joint_then_another(self) -> None:
        """Axis 1's effort goes out of range, axis 2's too, then axis 1 is fine again: the reason names axis2."""
        run = Run(load_config(REPO / "config" / "examples" / "multi_current_monitoring.yaml"))

        def frames(s: float) -> list[Frame]:
            bad = {axis: 400.0 for axis, (a, b) in {1: (1.0, 1.5), 2: (1.4, 2.0)}.items() if a <= s < b}
            return robot_frames(T0 + s, efforts=bad)

        run.until(2.5, frames)
        [reason] = run.events.named("reason")
        assert reason["node"] == "IsJointEffortNormal"
        assert "axis2" in reason["reason"] and "axis1" in reason["previous"]
        assert reason["t"] - T0 == pytest.approx(1.5, abs=0.011)
        assert run.times("resume") == [pytest.approx(2.0, abs=0.011)]
        run.check_frames_never_mix()


class TestConfig:
    """The new keys: clear errors naming the key, and every existing config stays valid."""

    @pytest.mark.parametrize(("stop", "key"), [({"min_stop": -1}, "stop.min_stop"),
                                               ({"release": "sometimes"}, "stop.release")])
    def test_bad_stop_keys(self, tmp_path: Path, stop: dict[str, Any], key: str) -> None:
        """A negative min_stop or an unknown release names its key and what was expected."""
        path = tmp_path / "c.yaml"
        path.write_text(yaml.safe_dump({"dbc": [str(DBC)], "stop": stop}), encoding="utf-8")
        with pytest.raises(ConfigError) as err:
            load_config(path)
        assert key in str(err.value) and "expected" in str(err.value)

    def test_bad_role(self, tmp_path: Path) -> None:
        """actions.X.role must be task, recovery or auto."""
        path = tmp_path / "c.yaml"
        path.write_text(yaml.safe_dump({"dbc": [str(DBC)], "actions": {"Go": {"role": "boss"}}}), encoding="utf-8")
        with pytest.raises(ConfigError, match=r"actions\.Go\.role.*task, recovery or auto"):
            load_config(path)

    @pytest.mark.parametrize("path", SEEDS, ids=lambda p: p.name)
    def test_seed_defaults(self, path: Path) -> None:
        """Every seed config loads; min_stop defaults to 0 and release to auto."""
        cfg = load_config(path)
        assert cfg.stop.min_stop_s == 0.0 and cfg.stop.release == "auto"


class TestTreeShowsLatches:
    """`canguard tree` says beside each node what it does to a stop."""

    def test_robot_guard(self) -> None:
        """Guards latch (with how they hold), ClearDriveErrors recovers, ExecuteTask is the task; the rule is stated."""
        lines = show_tree(REPO / "config" / "examples" / "robot_guard.yaml").splitlines()
        line = {ln.split()[1]: ln for ln in lines if ln.strip().startswith("-->")}
        assert "LATCH" in line["PackCurrent"] and "hysteresis" in line["PackCurrent"] and "25 A" in line["PackCurrent"]
        assert "LATCH" in line["Axis0I2t"] and "i2t" in line["Axis0I2t"]
        assert "RECOVERY" in line["ClearDriveErrors"]
        assert "TASK" in line["ExecuteTask"]
        assert lines[-1].startswith("stop: latches") and "min_stop 0 s" in lines[-1]

    def test_multi_current_task_action(self) -> None:
        """Without ExecuteTask, ContinueOperation is the task (withheld while stopped)."""
        text = show_tree(REPO / "config" / "examples" / "multi_current_monitoring.yaml")
        [line] = [ln for ln in text.splitlines() if "ContinueOperation" in ln]
        assert "TASK" in line and "withheld" in line
