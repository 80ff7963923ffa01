"""The shipped trees and example configs load with the real config loader and check clean."""

from __future__ import annotations

from pathlib import Path

import pytest

from canguard.bt.checks import check_tree, load_config_tree, show_tree
from canguard.config.loader import load_config
from canguard.errors import TreeError
from checkout import REPO
from treekit import TREES

EXAMPLES = sorted((REPO / "config" / "examples").glob("*.yaml"))


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_config_checks_clean(path: Path) -> None:
    """Each example config's tree loads, every topic_name matches, every configured source is read."""
    cfg = load_config(path)
    report = check_tree(cfg)
    assert report.warnings == []
    assert report.text.startswith(f"tree: {load_config_tree(cfg).main_id} from ")


def test_check_names_the_configured_sources_the_tree_does_not_read() -> None:
    """The bundled config's tree reads /battery_state only: every other source is a warning of its own."""
    report = check_tree(load_config(REPO / "config" / "canguard.yaml"))
    assert report.warnings[0] == (
        "source '/joint_states' is configured but the tree does not read it (only stale events)")
    assert [w.split("'")[1] for w in report.warnings] == ["/joint_states", "axis0", "axis1", "axis2", "axis3"]


def test_every_shipped_tree_has_an_example() -> None:
    """Each file of config/trees is run by some example config (or the bundled one)."""
    configs = [*EXAMPLES, REPO / "config" / "canguard.yaml"]
    used = {load_config(p).tree.file.resolve() for p in configs}  # type: ignore[union-attr]
    assert {p.resolve() for p in TREES.glob("*.xml")} <= used


def test_bundled_config_runs_current_protected_operation() -> None:
    """config/canguard.yaml points at CurrentProtectedOperation in protected_operation.xml."""
    cfg = load_config(REPO / "config" / "canguard.yaml")
    loaded = load_config_tree(cfg)
    assert loaded.main_id == "CurrentProtectedOperation"
    assert [g.node for g in loaded.guards()] == ["IsCurrentSafe"]
    view = loaded.guards()[0]
    assert (view.source, view.role, view.kind, view.threshold()) == ("/battery_state", "current", "threshold", 35.0)


def test_guard_views_of_a_joints_guard() -> None:
    """A joints guard gives one view per joint."""
    cfg = load_config(REPO / "config" / "examples" / "multi_current_monitoring.yaml")
    views = load_config_tree(cfg).guards()
    assert [(v.node, v.role) for v in views] == [
        ("IsCurrentNormal", "current"),
        *[("IsJointEffortNormal", f"axis{i}") for i in range(4)],
    ]
    assert views[1].threshold() == 150.0 and views[1].snapshot().tripped is False


def test_show_tree_and_dot(tmp_path: Path) -> None:
    """show_tree draws the config's tree and, asked, writes a .dot file."""
    text = show_tree(REPO / "config" / "canguard.yaml", dot=tmp_path / "tree.dot")
    assert "IsCurrentSafe" in text and f"wrote {tmp_path / 'tree.dot'}" in text
    assert (tmp_path / "tree.dot").read_text().startswith("digraph")


def test_check_tree_rejects_a_topic_of_the_wrong_kind(tmp_path: Path) -> None:
    """A topic_name naming a source of the wrong kind is a TreeError naming the sources."""
    tree = tmp_path / "t.xml"
    tree.write_text('<root><BehaviorTree ID="T"><IsJointEffortNormal topic_name="axis0"/></BehaviorTree></root>')
    cfg_text = (
        (REPO / "config" / "canguard.yaml")
        .read_text()
        .replace(
            "tree: {file: trees/protected_operation.xml, main: CurrentProtectedOperation, tick_hz: 100}",
            f"tree: {{file: {tree}, main: T}}",
        )
    )
    cfg_path = tmp_path / "cfg.yaml"
    cfg_path.write_text(cfg_text.replace("../dbc/robot.dbc", str(REPO / "dbc" / "robot.dbc")))
    with pytest.raises(TreeError, match=r"t\.xml:1: node IsJointEffortNormal .*port topic_name: source 'axis0'"):
        check_tree(load_config(cfg_path))
