"""Pre- and post-conditions on any node (BT.CPP 4: gtest_preconditions.cpp / gtest_postconditions.cpp).

``_failureIf`` / ``_successIf`` replace the tick of a node that is not running; ``_onSuccess``,
``_onFailure`` and ``_post`` run after a completed status (also a substituted one);
``_onHalted`` runs when a running node is halted. ``_skipIf`` / ``_while`` and the SKIPPED
status: tests/test_bt_skipped.py.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from py_trees.blackboard import Blackboard

from canguard.bt.context import Context, NullTaskGate
from canguard.bt.dryrun import dry_run
from canguard.bt.loader import load_tree
from canguard.errors import TreeError
from canguard.io.clock import ManualClock
from treekit import ListSink, tick


def tree(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "t.xml"
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="M">\n<BehaviorTree ID="M">\n{body}\n'
                    "</BehaviorTree>\n</root>\n", encoding="utf-8")
    return path


def test_success_if_replaces_the_tick_and_post_conditions_follow(tmp_path: Path) -> None:
    """A true _successIf makes AlwaysFailure succeed without ticking it; _onSuccess and _post run."""
    path = tree(tmp_path, """<Sequence><Script code="A := 1"/>
  <AlwaysFailure _successIf="A == 1" _onSuccess="B := 2" _onFailure="C := 3" _post="D := 4"/></Sequence>""")
    assert dry_run(path, 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"A": 1, "B": 2, "D": 4}}


def test_failure_if_is_checked_before_success_if(tmp_path: Path) -> None:
    """Both true: _failureIf wins (BT.CPP's order); both false: the node is ticked."""
    both = tree(tmp_path, '<AlwaysSuccess _failureIf="true" _successIf="true" _onFailure="F := 1"/>')
    assert dry_run(both, 1, 0.1) == {"ticks": ["FAILURE"], "blackboard": {"F": 1}}
    neither = tree(tmp_path, '<AlwaysFailure _failureIf="false" _successIf="false"/>')
    assert dry_run(neither, 1, 0.1)["ticks"] == ["FAILURE"]


def test_preconditions_are_not_rechecked_while_running(tmp_path: Path) -> None:
    """A running Sleep is not interrupted when its _failureIf becomes true; it is checked at the next start."""
    path = tree(tmp_path, '<Sleep msec="250" _failureIf="stop"/>')
    clock = ManualClock()
    loaded = load_tree(path, Context(clock, {}, sink=ListSink(), task=NullTaskGate()))
    Blackboard.storage["/stop"] = False
    assert tick(loaded).name == "RUNNING"
    Blackboard.storage["/stop"] = True
    clock.set(0.1)
    assert tick(loaded).name == "RUNNING"
    clock.set(0.3)
    assert tick(loaded).name == "SUCCESS"
    clock.set(0.4)
    assert tick(loaded).name == "FAILURE"


def test_on_halted_runs_when_a_running_node_is_halted(tmp_path: Path) -> None:
    """WhileDoElse switches branch and halts the running Sleep: its _onHalted script runs."""
    path = tree(tmp_path, """<WhileDoElse><ScriptCondition code="go"/>
  <Sleep msec="250" _onHalted="halted := true"/><AlwaysSuccess/></WhileDoElse>""")
    clock = ManualClock()
    loaded = load_tree(path, Context(clock, {}, sink=ListSink(), task=NullTaskGate()))
    Blackboard.storage["/go"] = True
    assert tick(loaded).name == "RUNNING"
    assert "/halted" not in Blackboard.storage
    Blackboard.storage["/go"] = False
    clock.set(0.1)
    tick(loaded)
    assert Blackboard.storage["/halted"] == 1.0  # BT.CPP: true is the real 1.0


def test_skip_if_and_while_do_not_parse_either_a_load_error(tmp_path: Path) -> None:
    """_skipIf / _while scripts are parsed at load like the others: a bad one names the line and the attribute."""
    path = tree(tmp_path, '<Sequence>\n<AlwaysSuccess _skipIf="A =="/>\n'
                          '<AlwaysSuccess _while="&amp;&amp;"/>\n</Sequence>')
    with pytest.raises(TreeError) as err:
        dry_run(path, 1, 0.1)
    assert f"{path}:4" in str(err.value) and "_skipIf" in str(err.value)
    assert f"{path}:5" in str(err.value) and "_while" in str(err.value)


def test_a_condition_script_that_does_not_parse_is_a_load_error(tmp_path: Path) -> None:
    """_successIf="A ==" is refused at load with the line and the attribute."""
    path = tree(tmp_path, '<Sequence>\n<AlwaysSuccess _successIf="A =="/>\n</Sequence>')
    with pytest.raises(TreeError) as err:
        dry_run(path, 1, 0.1)
    assert f"{path}:4" in str(err.value) and "_successIf" in str(err.value)


def test_a_condition_script_that_fails_fails_the_node(tmp_path: Path) -> None:
    """Fail-safe for BT.CPP's throw: a pre-condition on a missing entry, or a failing _onSuccess, fails the node."""
    from canguard.bt.dryrun import dry_run

    path = tree(tmp_path, '<Sequence><AlwaysSuccess _skipIf="nope == 1"/><Script code="after := 1"/></Sequence>')
    assert dry_run(path, 1, 0.1) == {"ticks": ["FAILURE"], "blackboard": {}}
    path.write_text(path.read_text().replace('_skipIf="nope == 1"', '_onSuccess="x = 1"'))
    assert dry_run(path, 1, 0.1) == {"ticks": ["FAILURE"], "blackboard": {}}
