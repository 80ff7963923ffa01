"""`canguard check` warns about guards that are not re-checked while the task runs."""

from __future__ import annotations

from pathlib import Path

import pytest

from canguard.bt.checks import context_for, require_guard_coverage
from canguard.bt.loader import load_tree
from canguard.config.loader import load_config
from canguard.errors import TreeError
from checkout import REPO


def coverage(tmp_path: Path, body: str) -> list[str]:
    """The guards require_guard_coverage() refuses in a one-tree document around ``body`` (the bundled config's
    sources)."""
    xml = tmp_path / "t.xml"
    xml.write_text(
        f'<root BTCPP_format="4" main_tree_to_execute="T"><BehaviorTree ID="T">{body}</BehaviorTree></root>',
        encoding="utf-8",
    )
    cfg = load_config(REPO / "config" / "canguard.yaml")
    try:
        require_guard_coverage(load_tree(xml, context_for(cfg)))
    except TreeError as exc:
        return exc.problems[0].splitlines()
    return []


class TestGuardCoverage:
    """Guards before ExecuteTask under a composite with memory are flagged; reactive ones are not."""

    @pytest.mark.parametrize("control", ["Sequence", "SequenceWithMemory"])
    def test_guard_before_task_under_memory(self, tmp_path: Path, control: str) -> None:
        """Sequence[IsCurrentSafe, ExecuteTask] checks the current once: warned, naming file, line and the fix."""
        [warning] = coverage(
            tmp_path, f'<{control}><IsCurrentSafe topic_name="/battery_state"/><ExecuteTask/></{control}>'
        )
        assert "t.xml:1:" in warning and "IsCurrentSafe" in warning and "ReactiveSequence" in warning

    def test_reactive_sequence_is_fine(self, tmp_path: Path) -> None:
        """ReactiveSequence[IsCurrentSafe, ExecuteTask] re-checks every tick: no warning."""
        assert coverage(
            tmp_path, '<ReactiveSequence><IsCurrentSafe topic_name="/battery_state"/><ExecuteTask/></ReactiveSequence>'
        ) == []

    def test_shipped_trees_are_covered(self) -> None:
        """The bundled and the whole-robot configs guard their task at every tick."""
        for cfg_path in (REPO / "config" / "canguard.yaml", REPO / "config" / "examples" / "robot_guard.yaml"):
            cfg = load_config(cfg_path)
            assert cfg.tree is not None
            require_guard_coverage(load_tree(cfg.tree.file, context_for(cfg), cfg.tree.main))


class TestUncoveredTreeRefused:
    """The daemon and replay refuse a tree whose guard would not be re-checked while the task runs."""

    def test_check_and_replay_exit_2(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """`canguard check` and `canguard replay` on Sequence[IsCurrentSafe, ExecuteTask] exit 2 naming the fix."""
        import yaml

        from canguard.cli.main import main

        xml = tmp_path / "t.xml"
        xml.write_text(
            '<root BTCPP_format="4" main_tree_to_execute="T"><BehaviorTree ID="T"><Sequence>'
            '<IsCurrentSafe topic_name="/battery_state"/><ExecuteTask/></Sequence></BehaviorTree></root>',
            encoding="utf-8",
        )
        doc = yaml.safe_load((REPO / "config" / "canguard.yaml").read_text(encoding="utf-8"))
        doc["dbc"] = [str(REPO / "dbc" / "robot.dbc")]
        doc["tree"] = {"file": str(xml), "main": "T", "tick_hz": 100}
        cfg = tmp_path / "c.yaml"
        cfg.write_text(yaml.safe_dump(doc), encoding="utf-8")
        log = tmp_path / "x.log"
        log.write_text("(1700000000.000000) can0 18FF50E5#0064000000000100\n", encoding="ascii")
        assert main(["check", "-c", str(cfg)]) == 2
        assert "ReactiveSequence" in capsys.readouterr().err
        assert main(["replay", str(log), "-c", str(cfg)]) == 2
        assert "is checked only before ExecuteTask starts" in capsys.readouterr().err
