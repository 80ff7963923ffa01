"""LoopInt / LoopDouble / LoopString / LoopBool, after BT.CPP 4's gtest_loop.cpp.

The test names follow the gtest cases; BT.CPP's recording action is a Script that
appends what it is ticked with to a blackboard entry.
"""

from __future__ import annotations

from collections.abc import Callable
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
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="Main">\n<BehaviorTree ID="Main">\n{body}\n'
                    "</BehaviorTree>\n</root>\n", encoding="utf-8")
    return path


def run(tmp_path: Path, body: str, ticks: int, setup: Callable[[], None] | None = None) -> tuple[list[str], dict]:
    """Tick the tree ``ticks`` times (stopping after the first non-RUNNING); statuses and root entries."""
    Blackboard.storage.clear()
    loaded = load_tree(tree(tmp_path, body), Context(ManualClock(), {}, sink=ListSink(), task=NullTaskGate()))
    Blackboard.storage["/seen"] = ""
    if setup:
        setup()
    out = []
    for _ in range(ticks):
        out.append(tick(loaded).name)
        if out[-1] != "RUNNING":
            break
    return out, {k[1:]: v for k, v in Blackboard.storage.items() if k.count("/") == 1}


RECORD = '<Script code="seen := seen .. \'[\' .. val .. \']\'"/>'


@pytest.mark.parametrize(("node", "queue", "seen"), [
    ("LoopInt", "1;2;3;4;5", "[1][2][3][4][5]"),  # StaticIntQueue
    ("LoopDouble", "1.5;2.5;3.5", "[1.500000][2.500000][3.500000]"),  # StaticDoubleQueue (.. as BT.CPP)
    ("LoopString", "hello;world;test", "[hello][world][test]"),  # StaticStringQueue
])
def test_static_queue(tmp_path: Path, node: str, queue: str, seen: str) -> None:
    """One element per tick, in order, RUNNING until the queue is empty, then SUCCESS."""
    n = queue.count(";") + 1
    ticks, board = run(tmp_path, f'<{node} queue="{queue}" value="{{val}}">{RECORD}</{node}>', 10)
    assert ticks == ["RUNNING"] * n + ["SUCCESS"]
    assert board["seen"] == seen


def test_bool_queue(tmp_path: Path) -> None:
    """BoolQueue: true/false/1/0 become booleans (the child sees them as such)."""
    body = '<LoopBool queue="true;false;1;0" value="{val}"><Script code="n := n + 1"/></LoopBool>'
    ticks, board = run(tmp_path, body, 10, lambda: Blackboard.storage.update({"/n": 0}))
    assert ticks == ["RUNNING"] * 4 + ["SUCCESS"]
    assert board["n"] == 4 and board["val"] is False


@pytest.mark.parametrize(("if_empty", "status"), [("SUCCESS", "SUCCESS"), ("FAILURE", "FAILURE")])
def test_empty_queue_returns(tmp_path: Path, if_empty: str, status: str) -> None:
    """EmptyQueue_ReturnsSuccess / _ReturnsFailure: the child is never ticked."""
    body = f'<LoopInt queue="" if_empty="{if_empty}" value="{{val}}"><Script code="ticked := 1"/></LoopInt>'
    ticks, board = run(tmp_path, body, 3)
    assert ticks == [status]
    assert "ticked" not in board


def test_empty_queue_skipped(tmp_path: Path) -> None:
    """if_empty="SKIPPED" (BT.CPP accepts it): an exhausted loop is skipped and its Sequence goes on."""
    body = ('<Sequence><LoopInt queue="1" if_empty="SKIPPED" value="{val}"><Script code="ticked := val"/></LoopInt>'
            '<Script code="after := 1"/></Sequence>')
    path = tree(tmp_path, body)
    assert dry_run(path, 2, 0.1) == {"ticks": ["RUNNING", "SUCCESS"], "blackboard": {"after": 1, "ticked": 1,
                                                                                   "val": 1}}
    path.write_text(path.read_text().replace('queue="1"', 'queue=""'))
    assert dry_run(path, 1, 0.1)["ticks"] == ["SUCCESS"]
    path.write_text(path.read_text().replace("<Sequence>", "").replace("</Sequence>", "")
                    .replace('<Script code="after := 1"/>', ""))
    assert dry_run(path, 1, 0.1) == {"ticks": ["SKIPPED"], "blackboard": {}}


def test_skipped_child_keeps_the_loop_running(tmp_path: Path) -> None:
    """A skipped child does not skip the loop (loop_node.h): it takes the next element at the next tick."""
    body = '<LoopInt queue="1;2" value="{val}"><Script code="n := val" _skipIf="val == 1"/></LoopInt>'
    ticks, board = run(tmp_path, body, 5)
    assert ticks == ["RUNNING", "RUNNING", "SUCCESS"]
    assert board["n"] == 2


def test_child_failure_stops_loop(tmp_path: Path) -> None:
    """ChildFailure_StopsLoop: the child fails on the third element -> FAILURE, no fourth tick."""
    body = f'<LoopInt queue="1;2;3;4" value="{{val}}"><Sequence>{RECORD}<ScriptCondition code="val != 3"/>' \
           "</Sequence></LoopInt>"
    ticks, board = run(tmp_path, body, 10)
    assert ticks == ["RUNNING", "RUNNING", "FAILURE"]
    assert board["seen"] == "[1][2][3]"


def test_dynamic_queue_from_blackboard(tmp_path: Path) -> None:
    """DynamicQueueFromBlackboard / VectorInput: a list entry is consumed in place."""
    ticks, board = run(tmp_path, f'<LoopInt queue="{{q}}" value="{{val}}">{RECORD}</LoopInt>', 10,
                       lambda: Blackboard.storage.update({"/q": [7, 8]}))
    assert ticks == ["RUNNING", "RUNNING", "SUCCESS"]
    assert board["seen"] == "[7][8]" and board["q"] == []


def test_string_entry_is_parsed(tmp_path: Path) -> None:
    """A ';'-separated string in the entry is a queue too."""
    ticks, board = run(tmp_path, f'<LoopString queue="{{q}}" value="{{val}}">{RECORD}</LoopString>', 10,
                       lambda: Blackboard.storage.update({"/q": "a;b"}))
    assert ticks == ["RUNNING", "RUNNING", "SUCCESS"]
    assert board["seen"] == "[a][b]"


def test_restart_after_completion(tmp_path: Path) -> None:
    """RestartAfterCompletion: a static queue starts over when the loop is ticked again."""
    path = tree(tmp_path, '<LoopInt queue="1;2" value="{val}"><AlwaysSuccess/></LoopInt>')
    assert dry_run(path, 6, 0.1)["ticks"] == ["RUNNING", "RUNNING", "SUCCESS"] * 2


def test_missing_entry_fails_safe(tmp_path: Path) -> None:
    """An entry that holds nothing: FAILURE (BT.CPP throws), the child is not ticked."""
    ticks, board = run(tmp_path, '<LoopInt queue="{q}" value="{val}"><Script code="t := 1"/></LoopInt>', 3)
    assert ticks == ["FAILURE"] and "t" not in board


def test_bad_static_element_is_a_load_error(tmp_path: Path) -> None:
    """ConvertFromString_Int: 'x' is not an int: the load fails naming the line and the port."""
    path = tree(tmp_path, '<LoopInt queue="1;x" value="{val}"><AlwaysSuccess/></LoopInt>')
    with pytest.raises(TreeError, match=r"t.xml:3.*queue"):
        dry_run(path, 1, 0.1)
