"""canguard against BehaviorTree.CPP itself: every tree of ``tests/data/btcpp/`` ticked as BT.CPP ticked it.

Each ``NAME.xml`` there was loaded and ticked by BehaviorTree.CPP built from source
(``scripts/btcpp_oracle/``: ``driver.cpp`` ticks it with ``tree.tickOnce()``, or with
``tickExactlyOnce()`` where its ``<!-- oracle: ticks=N exactly-once -->`` line says so;
``record.sh`` rebuilds BT.CPP and re-records the whole corpus); ``NAME.json`` is what BT.CPP
did. Here canguard runs the same file through :func:`canguard.bt.dryrun.dry_run`, what
``canguard tree NAME.xml --tick N --json`` (``--exactly-once`` for the others) prints (a test
below holds the command to it), in-process, and must give the same root status after each
tick and the same root blackboard, entry by entry, each value as BT.CPP prints it (integers as
digits, reals with ``%f``, booleans as 1/0, queues as ``a;b;c``; entries that exist without a
value are not compared). A file BT.CPP refuses to load canguard must refuse with an error
naming the file; where BT.CPP threw out of a tick, canguard's root must return FAILURE at that
tick (its documented fail-safe for a node that raises) and the blackboard must be the same, or,
where BT.CPP threw at the very first tick, canguard may refuse the file at load instead (both
refuse to run it; canguard says so before the robot moves).

Trees where canguard does not yet do what BT.CPP does are listed in ``KNOWN_DIFFERENCES`` with
the reason; they are strict xfails, so a tree that starts to agree fails until it leaves the table.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest

from canguard.bt.dryrun import dry_run
from canguard.cli.main import main
from canguard.errors import CanguardError

CORPUS = Path(__file__).resolve().parent / "data" / "btcpp"
# What BehaviorTree.CPP 4.10's BehaviorTreeFactory registers (src/bt_factory.cpp; SequenceStar only
# with USE_BTCPP3_OLD_NAMES): the corpus must use each of them.
BTCPP_BUILTINS = (
    "Fallback", "AsyncFallback", "Sequence", "AsyncSequence", "SequenceWithMemory", "Parallel", "ParallelAll",
    "ReactiveSequence", "ReactiveFallback", "IfThenElse", "WhileDoElse", "TryCatch", "Inverter",
    "RetryUntilSuccessful", "KeepRunningUntilFailure", "Repeat", "Timeout", "Delay", "RunOnce", "ForceSuccess",
    "ForceFailure", "AlwaysSuccess", "AlwaysFailure", "Script", "ScriptCondition", "SetBlackboard", "Sleep",
    "UnsetBlackboard", "SubTree", "Precondition", "Switch2", "Switch3", "Switch4", "Switch5", "Switch6",
    "LoopInt", "LoopBool", "LoopDouble", "LoopString", "WasEntryUpdated", "SkipUnlessUpdated", "WaitValueUpdate",
)
DT_S = 0.1
"""Seconds between ticks: ``canguard tree``'s default (the corpus's timing nodes do not depend on it)."""
ORACLE_LINE = re.compile(r"<!-- oracle: ticks=(\d+)( exactly-once)? -->")

SET_TEXT_ANY = ("SetBlackboard writing text into an entry that has no port type (a Script's, or one it copies "
                "from a Script's): BT.CPP parses the text with that type, which leaves the entry without a "
                "value; canguard writes the text")

# tree -> why canguard does not (yet) do what BehaviorTree.CPP does with it
KNOWN_DIFFERENCES: dict[str, str] = {
    "action_set_blackboard_copy_string": SET_TEXT_ANY,
    "action_set_blackboard_copy_string_read": SET_TEXT_ANY,
    "action_set_blackboard_overwrite_bad": SET_TEXT_ANY,
    "action_set_blackboard_overwrite_int": SET_TEXT_ANY,
    "load_duplicate_tree_id": ("BT.CPP accepts two BehaviorTrees with one ID (the last one wins); canguard refuses "
                               "the file"),
    "repeat_real_cycles": "BT.CPP reads num_cycles=\"2.5\" as an int; canguard refuses the file",
}


def _oracle_line(tree: Path) -> tuple[int, bool]:
    """The ticks and the tick mode the tree's ``<!-- oracle: ... -->`` line asks for."""
    found = ORACLE_LINE.search(tree.read_text(encoding="utf-8"))
    assert found is not None, f"{tree}: no <!-- oracle: ticks=N --> line"
    return int(found.group(1)), found.group(2) is not None


def _trees() -> list[Any]:
    params = []
    for tree in sorted(CORPUS.glob("*.xml")):
        marks = ()
        if tree.stem in KNOWN_DIFFERENCES:
            marks = (pytest.mark.xfail(strict=True, reason=KNOWN_DIFFERENCES[tree.stem]),)
        params.append(pytest.param(tree, id=tree.stem, marks=marks))
    return params


def btcpp_text(value: Any) -> str | None:
    """A value of ``canguard tree --json``'s blackboard as BT.CPP converts it to a string."""
    if value is None:
        return None
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return f"{value:f}" if math.isfinite(value) else str(value)  # std::to_string: "%f"
    if isinstance(value, list):
        return ";".join(str(btcpp_text(item)) for item in value)
    return str(value)


def canguard_tree(tree: Path, ticks: int, exactly_once: bool) -> tuple[dict[str, Any] | None, str]:
    """What ``canguard tree TREE --tick N --json [--exactly-once]`` prints, or why it refuses the file.

    :func:`dry_run` is the command's work without its argument parser (a third of the command's CPU
    per tree); ``test_the_command_prints_what_the_oracle_compares`` holds the command to it.
    """
    try:
        result = dry_run(tree, ticks, DT_S, exactly_once=exactly_once)
    except CanguardError as exc:  # the command prints it and exits 2
        return None, str(exc)
    return json.loads(json.dumps(result)), ""


@pytest.mark.parametrize("tree", _trees())
def test_canguard_ticks_the_tree_as_btcpp_does(tree: Path) -> None:
    """Root status per tick and root blackboard entries are BT.CPP's; a file BT.CPP refuses, canguard refuses."""
    recorded = json.loads(tree.with_suffix(".json").read_text(encoding="utf-8"))
    ticks, exactly_once = _oracle_line(tree)
    error = recorded["error"]
    expected_ticks = list(recorded["ticks"])
    if error is not None and error["phase"] == "tick":
        expected_ticks.append("FAILURE")
        ticks = len(expected_ticks)
    got, refusal = canguard_tree(tree, ticks, exactly_once)
    refused = got is None and tree.name in refusal
    if error is not None and (error["phase"] == "load" or (error["tick"] == 1 and refused)):
        # BT.CPP refused the file, or threw during its first tick (a missing port, a wrong number
        # of children, ...) and canguard refused the file: both refuse to run it.
        assert refused, f"BT.CPP refuses {tree.name} ({error['message']}); canguard ran it: {got}{refusal}"
        return
    assert got is not None, f"BT.CPP loads {tree.name}; canguard: {refusal}"
    assert got["ticks"] == expected_ticks
    want_bb = {k: v for k, v in recorded["blackboard"].items() if v is not None}
    got_bb = {k: btcpp_text(v) for k, v in got["blackboard"].items() if v is not None}
    assert got_bb == want_bb


@pytest.mark.parametrize("name", ["action_set_blackboard_copy_int", "async_sequence_exactly_once",
                                  "typed_loop_double_to_int_port"])
def test_the_command_prints_what_the_oracle_compares(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    """``canguard tree TREE --tick N --json`` prints the oracle's result, or exits 2 naming the file it refuses."""
    tree = CORPUS / f"{name}.xml"
    ticks, exactly_once = _oracle_line(tree)
    got, refusal = canguard_tree(tree, ticks, exactly_once)
    argv = ["tree", str(tree), "--tick", str(ticks), "--json", "--dt", str(DT_S)]
    capsys.readouterr()
    code = main([*argv, "--exactly-once"] if exactly_once else argv)
    out, err = capsys.readouterr()
    if got is None:
        assert code == 2 and tree.name in err and refusal.splitlines()[0] in err
    else:
        assert code == 0 and json.loads(out) == got


class TestCorpus:
    def test_every_tree_is_recorded(self) -> None:
        """Each tree has its BT.CPP recording and each recording its tree; the corpus holds at least 150 trees."""
        trees = {p.stem for p in CORPUS.glob("*.xml")}
        recordings = {p.stem for p in CORPUS.glob("*.json")}
        assert trees == recordings
        assert len(trees) >= 150

    def test_every_btcpp_builtin_node_is_ticked(self) -> None:
        """Each node type BT.CPP's factory registers appears in a tree of the corpus that BT.CPP loaded."""
        used: set[str] = set()
        for tree in CORPUS.glob("*.xml"):
            if json.loads(tree.with_suffix(".json").read_text(encoding="utf-8"))["error"] is None:
                used.update(element.tag for element in ET.parse(tree).iter())
        assert set(BTCPP_BUILTINS) - used == set()

    def test_recordings_follow_the_oracle_line(self) -> None:
        """Each recording used the tick mode its tree asks for and stopped only at its tick count or at an error."""
        for tree in sorted(CORPUS.glob("*.xml")):
            recorded = json.loads(tree.with_suffix(".json").read_text(encoding="utf-8"))
            ticks, exactly_once = _oracle_line(tree)
            assert recorded["mode"] == ("tickExactlyOnce" if exactly_once else "tickOnce"), tree.name
            if recorded["error"] is None:
                assert len(recorded["ticks"]) == ticks, tree.name
            else:
                assert len(recorded["ticks"]) < ticks or recorded["error"]["phase"] == "load", tree.name

    def test_one_btcpp_recorded_the_whole_corpus(self) -> None:
        """Every recording names the same BehaviorTree.CPP version and commit."""
        sources = {json.loads(p.read_text(encoding="utf-8"))["btcpp"] for p in CORPUS.glob("*.json")}
        assert len(sources) == 1
        assert re.fullmatch(r"BehaviorTree\.CPP 4\.\d+\.\d+ [0-9a-f]{40}", sources.pop())

    def test_known_differences_name_recorded_trees(self) -> None:
        """The table of known differences names only trees of the corpus, each with a reason."""
        trees = {p.stem for p in CORPUS.glob("*.xml")}
        assert set(KNOWN_DIFFERENCES) <= trees
        assert all(reason.strip() for reason in KNOWN_DIFFERENCES.values())
