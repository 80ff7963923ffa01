"""BT.CPP 4's ``<SubTree _autoremap="true">`` (gtest_subtree.cpp): the subtree shares the parent's entries by name."""

from __future__ import annotations

from pathlib import Path

import pytest

from canguard.bt.dryrun import dry_run
from canguard.errors import TreeError

INNER = """
  <BehaviorTree ID="Inner">
    <Sequence><Script code="n += 1" _skipIf="variable != 'test'"/></Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Setter">
    <LoopInt queue="{q}" value="{out}"><AlwaysSuccess/></LoopInt>
  </BehaviorTree>
"""


def tree(tmp_path: Path, main: str) -> Path:
    path = tmp_path / "t.xml"
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="Outer">\n<BehaviorTree ID="Outer">\n{main}\n'
                    f"</BehaviorTree>{INNER}</root>\n", encoding="utf-8")
    return path


def test_entries_are_shared_by_name(tmp_path: Path) -> None:
    """gtest SubtreeIssue592: the subtree reads and writes the parent's entries (n counted twice, in the root)."""
    got = dry_run(tree(tmp_path, '<Sequence><Script code="variable := \'test\'; n := 0"/>'
                                 '<SubTree ID="Inner" _autoremap="true"/><SubTree ID="Inner" _autoremap="1"/>'
                                 "</Sequence>"), 1, 0.1)
    assert got == {"ticks": ["SUCCESS"], "blackboard": {"n": 2, "variable": "test"}}


def test_explicit_remaps_win_over_the_names(tmp_path: Path) -> None:
    """out -> the parent's {result}; q a constant: the subtree's {q} reads it."""
    got = dry_run(tree(tmp_path, '<SubTree ID="Setter" _autoremap="true" out="{result}" q="7;8"/>'), 3, 0.1)
    assert got == {"ticks": ["RUNNING", "RUNNING", "SUCCESS"], "blackboard": {"result": 8}}


def test_conditions_on_an_autoremapped_subtree(tmp_path: Path) -> None:
    """_skipIf on the SubTree element: the subtree is skipped as a node would be."""
    got = dry_run(tree(tmp_path, '<Sequence><Script code="variable := \'test\'; n := 0; off := true"/>'
                                 '<SubTree ID="Inner" _autoremap="true" _skipIf="off"/></Sequence>'), 1, 0.1)
    assert got["blackboard"]["n"] == 0 and got["ticks"] == ["SUCCESS"]


def test_without_autoremap_the_subtree_keeps_its_own_entries(tmp_path: Path) -> None:
    """The default (false): the subtree's n is its own, the root's stays 0."""
    got = dry_run(tree(tmp_path, '<Sequence><Script code="variable := \'test\'; n := 0"/>'
                                 '<ForceSuccess><SubTree ID="Inner"/></ForceSuccess></Sequence>'), 1, 0.1)
    assert got["blackboard"]["n"] == 0


def test_a_cycle_of_autoremapped_subtrees_is_a_load_error(tmp_path: Path) -> None:
    path = tmp_path / "c.xml"
    path.write_text('<root BTCPP_format="4" main_tree_to_execute="A">\n'
                    '<BehaviorTree ID="A"><Sequence><SubTree ID="B" _autoremap="true"/></Sequence></BehaviorTree>\n'
                    '<BehaviorTree ID="B"><Sequence><SubTree ID="A" _autoremap="true"/></Sequence></BehaviorTree>\n'
                    "</root>\n", encoding="utf-8")
    with pytest.raises(TreeError) as err:
        dry_run(path, 1, 0.1)
    assert "SubTree cycle" in str(err.value) and f"{path}:" in str(err.value)


def test_v3_subtree_remaps_by_bare_name(tmp_path: Path) -> None:
    """BTCPP_format 3: <SubTree ID="X" out="result"/> maps the port to the parent's entry result (v4: {result})."""
    path = tmp_path / "v3.xml"
    path.write_text('<root main_tree_to_execute="Outer">\n<BehaviorTree ID="Outer">\n'
                    '<SubTree ID="Setter" out="result" q="queue_text"/>\n</BehaviorTree>\n'
                    '<BehaviorTree ID="Setter"><LoopInt queue="{q}" value="{out}"><AlwaysSuccess/></LoopInt>'
                    "</BehaviorTree>\n</root>\n", encoding="utf-8")
    text = path.read_text(encoding="utf-8").replace('<SubTree ID="Setter"', '<Sequence><Script code="queue_text := '
                                                     "'3;4'\"/><SubTree ID=\"Setter\"").replace(
        'q="queue_text"/>', 'q="queue_text"/></Sequence>')
    path.write_text(text, encoding="utf-8")
    got = dry_run(path, 3, 0.1)
    assert got["blackboard"]["result"] == 4 and got["ticks"] == ["RUNNING", "RUNNING", "SUCCESS"]


def test_private_keys_are_not_remapped(tmp_path: Path) -> None:
    """BT.CPP: _autoremap never maps a key starting with '_': the subtree's _p and _q are its own."""
    path = tmp_path / "p.xml"
    path.write_text("""<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <Sequence><Script code="_p := 1; shared := 1"/><SubTree ID="S" _autoremap="true"/>
      <Script code="after := _p"/></Sequence>
  </BehaviorTree>
  <BehaviorTree ID="S">
    <Sequence><Script code="_p := 100; shared := shared + 1"/>
      <LoopInt queue="7" value="{_q}"><Script code="got := _q"/></LoopInt></Sequence>
  </BehaviorTree>
</root>""", encoding="utf-8")
    got = dry_run(path, 2, 0.1)
    assert got == {"ticks": ["RUNNING", "SUCCESS"], "blackboard": {"_p": 1, "after": 1, "got": 7, "shared": 2}}


def test_a_script_follows_a_port_remapped_on_the_element(tmp_path: Path) -> None:
    """_autoremap with inside="{x}": a script's inside is the parent's x (BT.CPP's remapping entry)."""
    path = tmp_path / "r.xml"
    path.write_text("""<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <Sequence><Script code="x := 3"/><SubTree ID="C" _autoremap="true" inside="{x}" k="10"/></Sequence>
  </BehaviorTree>
  <BehaviorTree ID="C"><Script code="inside += 1; z := inside + k"/></BehaviorTree>
</root>""", encoding="utf-8")
    assert dry_run(path, 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"x": 4, "z": 14.0}}
