"""Profile (transparent timing, reset on halt) and the action nodes (task gate, stop frames, actions)."""

from __future__ import annotations

from pathlib import Path

import py_trees
import pytest

import canguard.bt.nodes.control as profile_module
from treekit import F, R, Rig, S, find, frame, install_scripted, xml_tree

BB = py_trees.blackboard.Blackboard


@pytest.fixture
def log(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, str]]:
    """The Scripted leaf's log."""
    return install_scripted(monkeypatch)


class TestProfile:
    """Profile: the child's status unchanged, statistics, reset on halt only."""

    def test_transparent(self, tmp_path: Path, log: list) -> None:
        """RUNNING, FAILURE, SUCCESS of the child come out unchanged."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree('<Profile><Scripted name="A" script="R,F,S,R"/></Profile>'))
        assert [rig.tick() for _ in range(4)] == [R, F, S, R]

    def test_statistics_and_outputs(self, tmp_path: Path, log: list, monkeypatch: pytest.MonkeyPatch) -> None:
        """last/avg/max in ms and count are written to the wired keys."""
        readings = iter([0.0, 0.004, 1.0, 1.010, 2.0, 2.001])
        monkeypatch.setattr(profile_module, "perf_counter", lambda: next(readings))
        rig = Rig()
        rig.load_text(
            tmp_path,
            xml_tree(
                '<Profile last_ms="{l}" avg_ms="{a}" max_ms="{m}" count="{c}"><Scripted name="A" script="S"/></Profile>'
            ),
        )
        for _ in range(3):
            rig.tick()
        assert BB.get("/l") == pytest.approx(1.0)
        assert BB.get("/a") == pytest.approx(5.0)
        assert BB.get("/m") == pytest.approx(10.0)
        assert BB.get("/c") == 3 and isinstance(BB.get("/c"), int)

    def test_unwired_outputs_are_not_written(self, tmp_path: Path, log: list) -> None:
        """Only the outputs given in the XML reach the blackboard; the rest are attributes."""
        rig = Rig()
        loaded = rig.load_text(tmp_path, xml_tree('<Profile last_ms="{l}"><Scripted name="A" script="S"/></Profile>'))
        rig.tick()
        assert BB.exists("/l")
        assert not [k for k in BB.storage if k.endswith(("avg_ms", "max_ms", "count"))]
        assert loaded.root.count == 1  # type: ignore[attr-defined]

    def test_reset_on_halt(self, tmp_path: Path, log: list) -> None:
        """Interrupted while RUNNING, the statistics restart (note 003's halt())."""
        rig = Rig()
        loaded = rig.load_text(
            tmp_path,
            xml_tree(
                '<ReactiveSequence><Scripted name="G" script="S,S,S,F,S"/>'
                '<Profile count="{c}"><Scripted name="A" script="R"/></Profile></ReactiveSequence>'
            ),
        )
        profile = find(loaded, "Profile")
        for _ in range(3):
            rig.tick()
        assert profile.count == 3
        assert rig.tick() == F
        assert profile.count == 0 and profile.max_ms == 0.0 and ("A", "halt") in log
        rig.tick()
        assert profile.count == 1 and BB.get("/c") == 1

    def test_not_reset_when_the_parent_starts_over(self, tmp_path: Path, log: list) -> None:
        """A finished Profile under a Sequence keeps counting though py_trees re-initialises it each run."""
        rig = Rig()
        loaded = rig.load_text(
            tmp_path,
            xml_tree(
                '<Sequence><Profile><Scripted name="A" script="S"/></Profile><Scripted name="B" script="S"/></Sequence>'
            ),
        )
        for _ in range(5):
            assert rig.tick() == S
        assert find(loaded, "Profile").count == 5

    def test_measures_the_child(self, tmp_path: Path, log: list) -> None:
        """The measured time covers the child's work (a 2 ms busy child reads >= 2 ms)."""
        import time

        rig = Rig()
        loaded = rig.load_text(tmp_path, xml_tree('<Profile><Scripted name="A" script="S"/></Profile>'))
        child = loaded.root.children[0]
        original = child.update

        def slow() -> py_trees.common.Status:
            end = time.perf_counter() + 0.002
            while time.perf_counter() < end:
                pass
            return original()

        child.update = slow  # type: ignore[method-assign]
        rig.tick()
        assert loaded.root.last_ms >= 2.0  # type: ignore[attr-defined]


class TestExecuteTask:
    """ExecuteTask drives the task gate."""

    def test_runs_while_ticked_halts_once(self, tmp_path: Path, log: list) -> None:
        """run() at every tick while RUNNING; one halt() when a guard interrupts it; runs again after."""
        rig = Rig()
        rig.load_text(
            tmp_path,
            xml_tree('<ReactiveSequence><Scripted name="G" script="S,S,F,F,S"/><ExecuteTask/></ReactiveSequence>'),
        )
        statuses = []
        for _ in range(5):
            statuses.append(rig.tick())
            rig.advance(0.01)
        assert statuses == [R, R, F, F, R]
        assert [c[0] for c in rig.task.calls] == ["run", "run", "halt", "run"]
        assert rig.task.calls[2] == ("halt", "ExecuteTask", pytest.approx(1000.02))

    def test_whole_tree_halt(self, tmp_path: Path) -> None:
        """Halting the whole tree (its root) stops a running task."""
        rig = Rig()
        loaded = rig.load_text(tmp_path, xml_tree("<ExecuteTask/>"))
        rig.tick()
        loaded.root.stop(py_trees.common.Status.INVALID)
        assert [c[0] for c in rig.task.calls] == ["run", "halt"]


class TestFrameActions:
    """EmitStop and the config's actions hand frames to the sink."""

    def test_emit_stop(self, tmp_path: Path) -> None:
        """EmitStop sends ctx.stop_frames with its name as origin; SUCCESS."""
        stops = (frame("Axis0_Estop"), frame("Axis1_Estop"))
        rig = Rig(stop_frames=stops)
        rig.load_text(tmp_path, xml_tree('<EmitStop name="panic"/>'))
        assert rig.tick() == S
        assert rig.sink.sent == [("panic", stops[0]), ("panic", stops[1])]

    def test_config_action_frames_and_output_time(self, tmp_path: Path) -> None:
        """An actions: entry sends its frames each tick and writes output_time only when wired."""
        rig = Rig()
        rig.load_text(
            tmp_path,
            xml_tree('<Sequence><PerformRecovery output_time="{done}"/><PerformDiagnostics name="diag"/></Sequence>'),
        )
        assert rig.tick() == S
        assert [(o, f.label) for o, f in rig.sink.sent] == [
            ("PerformRecovery", "PerformRecovery"),
            ("diag", "PerformDiagnostics"),
        ]
        assert BB.get("/done") == 1000.0
        assert not [k for k in BB.storage if k.endswith("output_time")]

    def test_action_without_frames(self, tmp_path: Path) -> None:
        """An action with no frames succeeds and sends nothing."""
        from canguard.config.schema import ActionConfig

        rig = Rig(actions=())
        rig.ctx.actions["Noop"] = ActionConfig("Noop")
        rig.load_text(tmp_path, xml_tree("<Noop/>"))
        assert rig.tick() == S and rig.sink.sent == []
