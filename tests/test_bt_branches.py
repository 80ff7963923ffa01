"""Switch2..Switch6, ParallelAll, TryCatch, after BT.CPP 4's gtest_switch/_parallel/_try_catch.cpp.

The test names follow the gtest cases. BT.CPP's asynchronous test actions (RUNNING for
a while, then SUCCESS or FAILURE) are a Sleep on canguard's manual clock, followed by
AlwaysFailure for the failing ones; a Script records which branch finished.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from py_trees.blackboard import Blackboard

from canguard.bt.context import Context, NullTaskGate
from canguard.bt.dryrun import dry_run
from canguard.bt.loaded import LoadedTree
from canguard.bt.loader import load_tree
from canguard.bt.nodes.builtins import same_case
from canguard.errors import TreeError
from canguard.io.clock import ManualClock
from treekit import ListSink, tick


def tree(tmp_path: Path, body: str, name: str = "t.xml") -> Path:
    path = tmp_path / name
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="Main">\n<BehaviorTree ID="Main">\n{body}\n'
                    "</BehaviorTree>\n</root>\n", encoding="utf-8")
    return path


SWITCH = """<Switch2 variable="{my_var}" case_1="1" case_2="42">
  <Sequence><Sleep msec="200"/><Script code="done := 'action_1'"/></Sequence>
  <Sequence><Sleep msec="200"/><Script code="done := 'action_42'"/></Sequence>
  <Sequence><Sleep msec="200"/><Script code="done := 'action_default'"/></Sequence>
</Switch2>"""


def start(tmp_path: Path, body: str = SWITCH) -> tuple[LoadedTree, ManualClock]:
    clock = ManualClock()
    return load_tree(tree(tmp_path, body), Context(clock, {}, sink=ListSink(), task=NullTaskGate())), clock


def running(loaded: LoadedTree) -> list[int]:
    """Indexes of the root's children that are RUNNING."""
    return [i for i, c in enumerate(loaded.root.children) if c.status.name == "RUNNING"]


class TestSwitch:
    @pytest.mark.parametrize(("value", "branch", "done"), [
        (None, 2, "action_default"),  # DefaultCase: the variable is not set
        ("1", 0, "action_1"),  # Case1
        ("42", 1, "action_42"),  # Case2
        ("none", 2, "action_default"),  # CaseNone
        (42, 1, "action_42"),  # an int entry matches the text case
        ("42.0", 1, "action_42"),  # numbers compare as numbers
    ])
    def test_case(self, tmp_path: Path, value: object, branch: int, done: str) -> None:
        """The matching child runs to its end (the others stay idle); the switch returns its status."""
        loaded, clock = start(tmp_path)
        if value is not None:
            Blackboard.storage["/my_var"] = value
        assert tick(loaded).name == "RUNNING"
        assert running(loaded) == [branch]
        clock.set(0.3)
        assert tick(loaded).name == "SUCCESS"
        assert Blackboard.storage["/done"] == done
        assert running(loaded) == []

    def test_case_switch_to_default(self, tmp_path: Path) -> None:
        """CaseSwitchToDefault: not reactive between ticks; at the next tick the change halts action_1."""
        loaded, clock = start(tmp_path)
        Blackboard.storage["/my_var"] = "1"
        assert tick(loaded).name == "RUNNING"
        clock.set(0.02)
        assert tick(loaded).name == "RUNNING"
        Blackboard.storage["/my_var"] = ""
        assert running(loaded) == [0]  # nothing happens until the next tick
        clock.set(0.04)
        assert tick(loaded).name == "RUNNING"
        assert running(loaded) == [2]
        assert loaded.root.children[0].status.name == "INVALID"  # halted
        clock.set(0.35)
        assert tick(loaded).name == "SUCCESS"
        assert Blackboard.storage["/done"] == "action_default"

    def test_case_switch_to_action2(self, tmp_path: Path) -> None:
        """CaseSwitchToAction2: the variable changes to 42 -> action_1 halted, action_42 runs and ends."""
        loaded, clock = start(tmp_path)
        Blackboard.storage["/my_var"] = "1"
        assert tick(loaded).name == "RUNNING"
        Blackboard.storage["/my_var"] = "42"
        clock.set(0.02)
        assert tick(loaded).name == "RUNNING"
        assert running(loaded) == [1]
        clock.set(0.3)
        assert tick(loaded).name == "SUCCESS"
        assert Blackboard.storage["/done"] == "action_42"

    def test_action_failure(self, tmp_path: Path) -> None:
        """ActionFailure: the matched child fails -> the switch fails, nothing keeps running."""
        loaded, clock = start(tmp_path, """<Switch2 variable="{my_var}" case_1="1" case_2="42">
  <Sequence><Sleep msec="200"/><AlwaysFailure/></Sequence><AlwaysSuccess/><AlwaysSuccess/>
</Switch2>""")
        Blackboard.storage["/my_var"] = "1"
        assert tick(loaded).name == "RUNNING"
        clock.set(0.3)
        assert tick(loaded).name == "FAILURE"
        assert running(loaded) == []

    def test_switch6_last_case_and_constant_variable(self, tmp_path: Path) -> None:
        """Switch6 with a constant variable picks case_6; an unset case never matches."""
        cases = " ".join(f'case_{i}="c{i}"' for i in (1, 2, 3, 4, 6))
        kids = "".join(f"<Script code=\"hit := {i}\"/>" for i in range(1, 8))
        path = tree(tmp_path, f'<Switch6 variable="c6" {cases}>{kids}</Switch6>')
        assert dry_run(path, 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"hit": 6}}

    @pytest.mark.parametrize("kids", [2, 4])
    def test_wrong_number_of_children_is_a_load_error(self, tmp_path: Path, kids: int) -> None:
        """Switch2 needs 3 children (2 cases + default): the load fails naming line and counts."""
        path = tree(tmp_path, '<Switch2 variable="a" case_1="a" case_2="b">' + "<AlwaysSuccess/>" * kids
                    + "</Switch2>")
        with pytest.raises(TreeError, match=rf"t.xml:3.*Switch2 needs 3 children .*has {kids}"):
            dry_run(path, 1, 0.1)

    def test_unknown_case_port_is_a_load_error(self, tmp_path: Path) -> None:
        """case_3 is not a port of Switch2."""
        path = tree(tmp_path, '<Switch2 variable="a" case_3="a"><AlwaysSuccess/><AlwaysSuccess/>'
                              "<AlwaysSuccess/></Switch2>")
        with pytest.raises(TreeError, match="case_3"):
            dry_run(path, 1, 0.1)


def test_switch_string_equality_rejects_trailing_characters() -> None:
    """SwitchStringEquality.RejectsTrailingCharacters."""
    for a, b in [("5", "5"), ("5", "5.0"), ("42", "42"), ("-7", "-7"), ("", "")]:
        assert same_case(a, b), (a, b)
    for a, b in [("5abc", "5"), ("42xxxx", "42"), ("1.0junk", "1.0"), ("5 ", "5"), ("none", "1"), ("1", "2")]:
        assert not same_case(a, b), (a, b)


class TestParallelAll:
    BAD = '<Sequence><Sleep msec="100"/><AlwaysFailure/></Sequence>'
    GOOD = '<Sequence><Sleep msec="300"/><Script code="good += 1"/></Sequence>'

    @pytest.mark.parametrize(("max_failures", "result"), [("1", "FAILURE"), ("2", "SUCCESS"), ("-1", "SUCCESS")])
    def test_parallel_all(self, tmp_path: Path, max_failures: str, result: str) -> None:
        """Parallel.ParallelAll: every child runs to its end, then max_failures decides (-1 = all)."""
        path = tree(tmp_path, f'<Sequence><Script code="good := 0"/><ParallelAll max_failures="{max_failures}">'
                              f"{self.BAD}{self.GOOD}{self.GOOD}</ParallelAll></Sequence>")
        out = dry_run(path, 4, 0.1)
        assert out["ticks"] == ["RUNNING", "RUNNING", "RUNNING", result]
        assert out["blackboard"] == {"good": 2}  # both good children finished despite the early failure

    def test_all_fail_with_minus_one(self, tmp_path: Path) -> None:
        """max_failures=-1 fails only when every child failed."""
        path = tree(tmp_path, '<ParallelAll max_failures="-1"><AlwaysFailure/><AlwaysFailure/></ParallelAll>')
        assert dry_run(path, 1, 0.1)["ticks"] == ["FAILURE"]

    def test_finished_children_are_not_ticked_again(self, tmp_path: Path) -> None:
        """A child that finished waits for the others (it is not re-run each tick)."""
        path = tree(tmp_path, '<Sequence><Script code="n := 0"/><ParallelAll><Script code="n += 1"/>'
                              '<Sleep msec="150"/></ParallelAll></Sequence>')
        assert dry_run(path, 3, 0.1) == {"ticks": ["RUNNING", "RUNNING", "SUCCESS"], "blackboard": {"n": 1}}

    def test_threshold_above_children_is_a_load_error(self, tmp_path: Path) -> None:
        """BT.CPP: 'Number of children is less than threshold. Can never fail.'"""
        path = tree(tmp_path, '<ParallelAll max_failures="3"><AlwaysFailure/><AlwaysFailure/></ParallelAll>')
        with pytest.raises(TreeError, match=r"max_failures.*can never fail"):
            dry_run(path, 1, 0.1)


class TestTryCatch:
    """After gtest_try_catch.cpp; a Script in the catch child records that it ran."""

    CATCH = "<Script code=\"caught := true\"/>"

    @pytest.mark.parametrize(("tries", "result", "caught"), [
        ("<AlwaysSuccess/><AlwaysSuccess/>", "SUCCESS", False),  # AllTryChildrenSucceed
        ("<AlwaysFailure/><Script code=\"later := 1\"/>", "FAILURE", True),  # FirstChildFails_CatchExecuted
        ("<AlwaysSuccess/><AlwaysFailure/>", "FAILURE", True),  # SecondChildFails_CatchExecuted
        ("<AlwaysSuccess/><AlwaysSuccess/><AlwaysFailure/><AlwaysSuccess/>", "FAILURE", True),  # ManyTryChildren
        ("<AlwaysSuccess/>", "SUCCESS", False),  # SingleTryChild_Success
    ])
    def test_try_children(self, tmp_path: Path, tries: str, result: str, caught: bool) -> None:
        """The try children run as a sequence; a failure runs the catch child and fails the node."""
        out = dry_run(tree(tmp_path, f"<TryCatch>{tries}{self.CATCH}</TryCatch>"), 1, 0.1)
        assert out["ticks"] == [result]
        assert ("caught" in out["blackboard"]) is caught
        assert "later" not in out["blackboard"]

    @pytest.mark.parametrize("catch", ["<AlwaysFailure/>", "<AlwaysSuccess/>"])
    def test_catch_result_does_not_matter(self, tmp_path: Path, catch: str) -> None:
        """CatchReturnsFailure/CatchReturnsSuccess_NodeStillReturnsFAILURE."""
        out = dry_run(tree(tmp_path, f"<TryCatch><AlwaysFailure/>{catch}</TryCatch>"), 1, 0.1)
        assert out["ticks"] == ["FAILURE"]

    def test_try_and_catch_child_running(self, tmp_path: Path) -> None:
        """TryChildRunning / CatchChildRunning: RUNNING is passed up; the catch runs to its end."""
        body = ('<TryCatch><Sequence><Sleep msec="150"/><AlwaysFailure/></Sequence>'
                '<Sequence><Sleep msec="150"/><Script code="caught := true"/></Sequence></TryCatch>')
        out = dry_run(tree(tmp_path, body), 5, 0.1)  # try fails at 0.2 s, catch sleeps 0.2 .. 0.35 s
        assert out["ticks"] == ["RUNNING", "RUNNING", "RUNNING", "RUNNING", "FAILURE"]
        assert out["blackboard"] == {"caught": True}

    def test_minimum_two_children(self, tmp_path: Path) -> None:
        """MinimumTwoChildren_ParseTimeValidation: one child is a load error."""
        with pytest.raises(TreeError, match="TryCatch needs at least 2 children"):
            dry_run(tree(tmp_path, "<TryCatch><AlwaysSuccess/></TryCatch>"), 1, 0.1)

    @pytest.mark.parametrize(("flag", "caught"), [("false", False), ("true", True)])
    def test_catch_on_halt(self, tmp_path: Path, flag: str, caught: bool) -> None:
        """CatchOnHalt_Disabled/_Enabled: a halt while trying ticks the catch child only when asked."""
        body = (f'<ReactiveSequence><ScriptCondition code="go"/><TryCatch catch_on_halt="{flag}">'
                f'<Sleep msec="500"/>{self.CATCH}</TryCatch></ReactiveSequence>')
        loaded, clock = start(tmp_path, body)
        Blackboard.storage["/go"] = True
        assert tick(loaded).name == "RUNNING"
        Blackboard.storage["/go"] = False
        clock.set(0.1)
        assert tick(loaded).name == "FAILURE"  # the condition halts the TryCatch
        assert ("/caught" in Blackboard.storage) is caught

    def test_re_execute_after_failure(self, tmp_path: Path) -> None:
        """ReExecuteAfterFailure: the next tick starts again from the first try child."""
        body = f'<TryCatch><Script code="n += 1"/><ScriptCondition code="n &gt; 1"/>{self.CATCH}</TryCatch>'
        loaded, _ = start(tmp_path, body)
        Blackboard.storage["/n"] = 0
        assert tick(loaded).name == "FAILURE"
        assert tick(loaded).name == "SUCCESS"
        assert Blackboard.storage["/n"] == 2


def test_nodes_model_declares_the_new_controls_as_groot2_does() -> None:
    """The Groot2 model lists Switch2..6 with their case ports and TryCatch's bool default as 'false'."""
    import xml.etree.ElementTree as ET

    from canguard.bt.checks import nodes_model_xml

    model = ET.fromstring(nodes_model_xml(None)).find("TreeNodesModel")
    assert model is not None
    by_id = {e.get("ID"): e for e in model}
    assert [p.get("name") for p in by_id["Switch4"]
            if p.tag == "input_port"] == ["variable", "case_1", "case_2", "case_3", "case_4"]
    catch = by_id["TryCatch"].find("input_port")
    assert catch is not None and catch.get("default") == "false" and by_id["TryCatch"].tag == "Control"
    assert by_id["ParallelAll"].tag == "Control"
