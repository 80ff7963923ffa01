"""Groot2 / BT.CPP palettes: trees using node types canguard does not implement.

A palette (``<TreeNodesModel>``, the format Groot2 and BT.CPP's writeTreeNodesModelXML
write, as Nav2's nav2_tree_nodes.xml) declares IDs and ports; ``canguard tree`` and
``canguard check`` validate the tree against it with file:line errors; running needs
each declared node bound to a config action or a ``canguard.nodes`` plug-in. The palette
and tree in tests/data/palette/ are small ones written here in Nav2's format.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from canguard.cli.main import main
from checkout import REPO

DATA = REPO / "tests" / "data" / "palette"
PALETTE = DATA / "nav_nodes.xml"
NAVIGATE = DATA / "navigate.xml"
DECLARED = ("ComputePathToPose", "FollowPath", "GoalUpdated", "RateController", "PipelineSequence")
"""The declared nodes navigate.xml uses (the palette declares one more, PersistentSequence)."""


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    try:
        code = main(argv)
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


def edited(tmp_path: Path, old: str, new: str) -> Path:
    path = tmp_path / "navigate.xml"
    text = NAVIGATE.read_text(encoding="utf-8")
    assert old in text
    path.write_text(text.replace(old, new), encoding="utf-8")
    return path


class TestValidation:
    def test_a_tree_valid_against_its_palette(self, capsys: pytest.CaptureFixture[str]) -> None:
        """Exit 0; the nodes that still need binding are named with their lines."""
        code, out, err = run(["tree", str(NAVIGATE), "--nodes", str(PALETTE)], capsys)
        assert code == 0, err
        assert "is valid; to run it, bind these nodes" in out
        for node_id in DECLARED:
            assert f"node {node_id} is declared by a palette" in out
        assert f"{NAVIGATE}:6: node ComputePathToPose" in out

    def test_without_the_palette_every_unknown_id_is_an_error_with_its_line(
        self, capsys: pytest.CaptureFixture[str]
    ) -> None:
        code, _, err = run(["tree", str(NAVIGATE)], capsys)
        assert code == 2
        assert f"{NAVIGATE}:4: unknown node ID 'PipelineSequence'" in err
        assert f"{NAVIGATE}:6: unknown node ID 'ComputePathToPose'" in err
        assert f"{NAVIGATE}:12: unknown node ID 'FollowPath'" in err

    @pytest.mark.parametrize(("old", "new", "line", "expected"), [
        ('planner_id="GridBased"/>', 'planner_id="GridBased" tolerance="0.5"/>', 6,
         "unknown port 'tolerance'; ports of ComputePathToPose: goal, planner_id, path"),
        ('<FollowPath path="{path}" controller_id="FollowPath"/>', '<FollowPath controller_id="FollowPath"/>', 12,
         'missing required port path (declared required="true")'),
        ("<GoalUpdated/>", "<GoalUpdated><AlwaysSuccess/></GoalUpdated>", 10,
         "condition nodes take no children, found 1"),
        ("</RateController>", "<AlwaysSuccess/></RateController>", 5, "a decorator takes exactly one child, found 2"),
    ])
    def test_against_the_declarations(self, tmp_path: Path, capsys: pytest.CaptureFixture[str], old: str, new: str,
                                      line: int, expected: str) -> None:
        """Unknown port, missing required port, children: exit 2 naming file:line and the declaration."""
        path = edited(tmp_path, old, new)
        code, _, err = run(["tree", str(path), "--nodes", str(PALETTE)], capsys)
        assert code == 2
        assert f"{path}:{line}: node " in err and expected in err, err
        assert f"declared at {PALETTE}:" in err

    def test_several_mistakes_at_once(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        path = edited(tmp_path, 'planner_id="GridBased"/>', 'planner_id="GridBased" tolerance="0.5"/>')
        path.write_text(path.read_text(encoding="utf-8").replace('<FollowPath path="{path}" ', "<FollowPath "),
                        encoding="utf-8")
        code, _, err = run(["tree", str(path), "--nodes", str(PALETTE)], capsys)
        assert code == 2 and "tolerance" in err and "missing required port path" in err

    def test_the_model_inside_the_tree_file(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """A <TreeNodesModel> in the tree file declares the same as --nodes."""
        model = PALETTE.read_text(encoding="utf-8")
        model = model[model.index("<TreeNodesModel>"):model.index("</TreeNodesModel>") + len("</TreeNodesModel>")]
        path = edited(tmp_path, "</root>", model + "\n</root>")
        code, out, err = run(["tree", str(path)], capsys)
        assert code == 0, err
        assert "node FollowPath is declared by a palette" in out
        bad = edited(tmp_path, "<FollowPath path=\"{path}\" ", "<FollowPath ")
        bad.write_text(bad.read_text(encoding="utf-8").replace("</root>", model + "\n</root>"), encoding="utf-8")
        assert run(["tree", str(bad)], capsys)[0] == 2


class TestPaletteFiles:
    @pytest.mark.parametrize(("text", "expected"), [
        ("<root><TreeNodesModel><Action/></TreeNodesModel></root>", ':1: <Action> in <TreeNodesModel> without ID'),
        ('<root><TreeNodesModel><Widget ID="W"/></TreeNodesModel></root>', ":1: <Widget> in <TreeNodesModel>"),
        ('<root>\n<TreeNodesModel>\n<Action ID="A"><input_port/></Action></TreeNodesModel></root>',
         ':3: <input_port> of A without name'),
        ("<root><BehaviorTree ID='x'/></root>", ":1: no <TreeNodesModel> in the palette file"),
        ("<root><TreeNodesModel>", ":1: not well-formed XML"),
    ])
    def test_a_bad_palette_names_its_line(self, tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str,
                                          expected: str) -> None:
        palette = tmp_path / "p.xml"
        palette.write_text(text, encoding="utf-8")
        code, _, err = run(["tree", str(NAVIGATE), "--nodes", str(palette)], capsys)
        assert code == 2 and f"{palette}{expected}" in err, err


class TestRunning:
    def test_ticking_an_unbound_declared_node_is_refused_with_both_ways_to_bind_it(
        self, capsys: pytest.CaptureFixture[str]
    ) -> None:
        code, _, err = run(["tree", str(NAVIGATE), "--nodes", str(PALETTE), "--tick", "3"], capsys)
        assert code == 2
        assert f"{NAVIGATE}:6: node ComputePathToPose is declared by a palette" in err
        assert "actions: ComputePathToPose:" in err and "canguard.nodes" in err

    def test_a_declared_node_bound_to_a_config_action_runs(self, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
        """check -c CONFIG --nodes: the palette's ports are checked; the config action sends its frames."""
        palette = tmp_path / "beep.xml"
        palette.write_text('<root BTCPP_format="4"><TreeNodesModel><Action ID="Beep">'
                           '<input_port name="volume" default="3"/></Action></TreeNodesModel></root>',
                           encoding="utf-8")
        tree = tmp_path / "tree.xml"

        def config(beep: str) -> Path:
            tree.write_text(
                '<root BTCPP_format="4" main_tree_to_execute="M"><BehaviorTree ID="M"><ReactiveSequence>'
                '<IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="40" recovery_threshold="30"/>'
                f"{beep}<ExecuteTask/></ReactiveSequence></BehaviorTree></root>", encoding="utf-8")
            doc = yaml.safe_load((REPO / "config" / "canguard.yaml").read_text(encoding="utf-8"))
            doc["dbc"] = [str(REPO / "dbc" / "robot.dbc")]
            doc["tree"] = {"file": str(tree), "main": "M", "tick_hz": 100}
            doc["actions"] = {"Beep": {"frames": [{"message": "Axis0_Clear_Errors"}]}}
            for key in ("events", "state"):
                doc.pop(key, None)
            path = tmp_path / "cfg.yaml"
            path.write_text(yaml.safe_dump(doc), encoding="utf-8")
            return path

        cfg = config('<Beep volume="5"/>')
        code, out, err = run(["check", "-c", str(cfg), "--nodes", str(palette)], capsys)
        assert code == 0, err
        assert "Beep" in out
        code, _, err = run(["check", "-c", str(config('<Beep loudness="5"/>')), "--nodes", str(palette)], capsys)
        assert code == 2 and "unknown port 'loudness'; ports of Beep: volume" in err
