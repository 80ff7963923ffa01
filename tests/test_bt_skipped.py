"""BehaviorTree.CPP 4's SKIPPED status and the nodes that use it, tick by tick through ``canguard tree --tick``.

The behaviour of BT.CPP's own gtest cases (gtest_skipping.cpp, gtest_decorator.cpp's
RunOnce, gtest_updates.cpp, the Async controls of sequence_node.cpp / fallback_node.cpp,
parallel_node.cpp's skipped count), written here as trees a user would write: the root
status after each tick (SKIPPED printed as BT.CPP prints it) and the blackboard after.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from canguard.bt.dryrun import dry_run
from canguard.cli.main import main


def tree(tmp_path: Path, body: str, extra: str = "") -> Path:
    path = tmp_path / "t.xml"
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="M">\n<BehaviorTree ID="M">\n{body}\n'
                    f"</BehaviorTree>\n{extra}</root>\n", encoding="utf-8")
    return path


def ticks(tmp_path: Path, body: str, n: int, extra: str = "") -> dict:
    return dry_run(tree(tmp_path, body, extra), n, 0.1)


class TestSkipIf:
    def test_a_skipped_child_is_passed_over(self, tmp_path: Path) -> None:
        """gtest SkippingLogic.Sequence: _skipIf wins when _failureIf/_successIf are false; the next child runs."""
        got = ticks(tmp_path, '<Sequence><Script code="A:=1"/>'
                              '<Script code="a:=1" _successIf="A==2" _failureIf="A!=1" _skipIf="A==1"/>'
                              '<Script code="b:=1"/></Sequence>', 1)
        assert got == {"ticks": ["SUCCESS"], "blackboard": {"A": 1, "b": 1}}

    def test_all_children_skipped_the_sequence_is_skipped(self, tmp_path: Path) -> None:
        """gtest SkippingLogic.SkipAll: none of the children runs; the root returns SKIPPED."""
        body = ('<Sequence><Script code="a:=1" _skipIf="1==1"/><Script code="b:=1" _skipIf="1&lt;2"/>'
                '<Script code="c:=1" _skipIf="3&gt;0"/></Sequence>')
        got = ticks(tmp_path, f'<Sequence><Script code="A:=1"/><Fallback>{body}<Script code="f:=1"/></Fallback>'
                              "</Sequence>", 1)
        # the inner sequence is skipped, so the fallback goes on to its next child
        assert got == {"ticks": ["SUCCESS"], "blackboard": {"A": 1, "f": 1}}
        root_skipped = tmp_path / "r"
        root_skipped.mkdir()
        assert dry_run(tree(root_skipped, body), 2, 0.1)["ticks"] == ["SKIPPED", "SKIPPED"]

    def test_skip_if_on_a_subtree_element(self, tmp_path: Path) -> None:
        """gtest SkippingLogic.SkipSubtree: _skipIf on <SubTree> skips it (BT.CPP accepts it; canguard refused it)."""
        sub = '<BehaviorTree ID="sub"><Script code="@in_sub:=1"/></BehaviorTree>\n'
        path = tree(tmp_path, '<Sequence><Script code="data:=true"/><SubTree ID="sub" _skipIf="data"/></Sequence>', sub)
        assert dry_run(path, 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"data": 1.0}}
        path.write_text(path.read_text().replace("data:=true", "data:=false"))
        assert dry_run(path, 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"data": 0.0, "in_sub": 1}}

    def test_reactive_sequence_goes_on_past_a_skipped_guard(self, tmp_path: Path) -> None:
        """gtest SkippingLogic.SkippingReactiveSequence: the skipped node is never ticked, the task runs."""
        got = ticks(tmp_path, '<ReactiveSequence><Script code="value:=10"/>'
                              '<AlwaysFailure _skipIf="value &lt; 25"/><Sleep msec="150"/></ReactiveSequence>', 3)
        assert got["ticks"] == ["RUNNING", "RUNNING", "SUCCESS"]  # Sleep 150 ms, ticks 100 ms apart
        single = tmp_path / "single"
        single.mkdir()
        assert dry_run(tree(single, '<ReactiveSequence><AlwaysSuccess _skipIf="true"/></ReactiveSequence>'),
                       1, 0.1)["ticks"] == ["SKIPPED"]

    def test_fallback_and_parallel_count_skipped_children(self, tmp_path: Path) -> None:
        """A fallback passes over a skipped child; a Parallel with success_count=-1 counts it as done."""
        got = ticks(tmp_path, '<Sequence><Fallback><AlwaysSuccess _skipIf="true"/><Script code="f:=1"/></Fallback>'
                              '<Parallel success_count="-1"><Script code="p:=1"/><AlwaysFailure _skipIf="true"/>'
                              "</Parallel></Sequence>", 1)
        assert got == {"ticks": ["SUCCESS"], "blackboard": {"f": 1, "p": 1}}

    @pytest.mark.parametrize("decorator", ["Inverter", "ForceSuccess", "ForceFailure"])
    def test_decorators_pass_skipped_on(self, tmp_path: Path, decorator: str) -> None:
        """BT.CPP's Inverter / ForceSuccess / ForceFailure return a skipped child's SKIPPED."""
        got = ticks(tmp_path, f'<Sequence><{decorator}><AlwaysFailure _skipIf="true"/></{decorator}>'
                              '<Script code="next:=1"/></Sequence>', 1)
        assert got == {"ticks": ["SUCCESS"], "blackboard": {"next": 1}}

    def test_keep_running_until_failure_stays_running_over_a_skipped_child(self, tmp_path: Path) -> None:
        """keep_running_until_failure_node.h: a SKIPPED child leaves it RUNNING."""
        got = ticks(tmp_path, '<KeepRunningUntilFailure><AlwaysFailure _skipIf="true"/></KeepRunningUntilFailure>', 2)
        assert got["ticks"] == ["RUNNING", "RUNNING"]

    def test_precondition_else_skipped(self, tmp_path: Path) -> None:
        """Precondition else="SKIPPED": a false condition skips it."""
        got = ticks(tmp_path, '<Sequence><Precondition if="false" else="SKIPPED"><Script code="x:=1"/></Precondition>'
                              '<Script code="y:=1"/></Sequence>', 1)
        assert got == {"ticks": ["SUCCESS"], "blackboard": {"y": 1}}


class TestWhile:
    def test_while_false_before_the_start_skips(self, tmp_path: Path) -> None:
        """gtest SkippingLogic.WhileSkip: doit false: the node is skipped, the sequences still succeed."""
        ran = ticks(tmp_path, '<Sequence><Script code="doit:=true"/><Sequence><Script code="x:=1" _while="doit"/>'
                              "</Sequence></Sequence>", 1)
        assert ran == {"ticks": ["SUCCESS"], "blackboard": {"doit": True, "x": 1}}
        other = tmp_path / "b"
        other.mkdir()
        skipped = dry_run(tree(other, '<Sequence><Script code="doit:=false"/><Sequence>'
                                      '<Script code="x:=1" _while="doit"/></Sequence></Sequence>'), 1, 0.1)
        assert skipped == {"ticks": ["SUCCESS"], "blackboard": {"doit": False}}

    def test_while_false_halts_a_running_node(self, tmp_path: Path) -> None:
        """_while turning false while the node runs halts it (_onHalted runs) and skips it."""
        body = ('<ReactiveSequence><RunOnce><Script code="t:=0"/></RunOnce><Script code="t += 1; go := t &lt; 3"/>'
                '<Sleep msec="10000" _while="go" _onHalted="halted := true"/></ReactiveSequence>')
        got = ticks(tmp_path, body, 3)
        assert got == {"ticks": ["RUNNING", "RUNNING", "SUCCESS"], "blackboard": {"go": False, "halted": True, "t": 3}}


class TestRunOnce:
    def test_then_skip(self, tmp_path: Path) -> None:
        """The child runs once; afterwards RunOnce is skipped (a sequence of only it is skipped too)."""
        got = ticks(tmp_path, '<Sequence><RunOnce><Script code="n:=1"/></RunOnce></Sequence>', 3)
        assert got == {"ticks": ["SUCCESS", "SKIPPED", "SKIPPED"], "blackboard": {"n": 1}}

    def test_then_repeat_the_status(self, tmp_path: Path) -> None:
        """then_skip=false: the child's first status forever, the child not ticked again."""
        got = ticks(tmp_path, '<Sequence><RunOnce><Script code="n:=0"/></RunOnce>'
                              '<RunOnce then_skip="false"><Script code="n += 1"/></RunOnce>'
                              '<RunOnce then_skip="false"><AlwaysFailure/></RunOnce></Sequence>', 3)
        assert got == {"ticks": ["FAILURE", "FAILURE", "FAILURE"], "blackboard": {"n": 1}}


class TestEntryUpdated:
    def test_was_entry_updated_counts_writes(self, tmp_path: Path) -> None:
        """gtest_updates: SUCCESS after a write since the last look (the same value written again counts)."""
        body = ('<Sequence><RunOnce><Script code="x:=1; hx:=0; hy:=0"/></RunOnce><Script code="y := 7"/>'
                '<ForceSuccess><Sequence><WasEntryUpdated entry="x"/><Script code="hx += 1"/></Sequence></ForceSuccess>'
                '<ForceSuccess><Sequence><WasEntryUpdated entry="{y}"/><Script code="hy += 1"/></Sequence>'
                "</ForceSuccess></Sequence>")
        got = ticks(tmp_path, body, 3)
        assert got["blackboard"]["hx"] == 1 and got["blackboard"]["hy"] == 3
        missing = tmp_path / "m"
        missing.mkdir()
        assert dry_run(tree(missing, '<WasEntryUpdated entry="nothing"/>'), 1, 0.1)["ticks"] == ["FAILURE"]

    def test_skip_unless_updated(self, tmp_path: Path) -> None:
        """The child runs after each write of the entry; otherwise the decorator is skipped."""
        got = ticks(tmp_path, '<Sequence><RunOnce><Script code="x:=1; runs:=0"/></RunOnce><SkipUnlessUpdated '
                              'entry="x"><Script code="runs += 1"/></SkipUnlessUpdated></Sequence>', 3)
        assert got == {"ticks": ["SUCCESS", "SKIPPED", "SKIPPED"], "blackboard": {"runs": 1, "x": 1}}

    def test_wait_value_update(self, tmp_path: Path) -> None:
        """RUNNING until the entry is written; then the child runs."""
        body = ('<Sequence><RunOnce><Script code="t:=0"/></RunOnce><Script code="t += 1"/>'
                '<ForceSuccess><Precondition if="t == 3"><Script code="x := 5"/></Precondition></ForceSuccess>'
                '<WaitValueUpdate entry="x"><Script code="seen := x"/></WaitValueUpdate></Sequence>')
        got = ticks(tmp_path, body, 4)
        # AsyncSequence-free Sequence: resumes at the RUNNING WaitValueUpdate, so t stays 1 until it completes
        assert got["ticks"][0] == "RUNNING"
        assert "seen" not in got["blackboard"]


class TestAsync:
    def test_async_sequence_yields_after_each_instant_success(self, tmp_path: Path) -> None:
        """AsyncSequence: RUNNING after each child that succeeded at once; tickOnce wakes up and finishes it."""
        path = tree(tmp_path, '<AsyncSequence><Script code="a:=1"/><Script code="b:=1"/></AsyncSequence>')
        assert dry_run(path, 1, 0.1, exactly_once=True) == {"ticks": ["RUNNING"], "blackboard": {"a": 1}}
        assert dry_run(path, 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"a": 1, "b": 1}}

    def test_async_fallback_yields_after_each_instant_failure(self, tmp_path: Path) -> None:
        """AsyncFallback: RUNNING after a child that failed at once; tickOnce ticks it again in the same tick."""
        path = tree(tmp_path, '<AsyncFallback><AlwaysFailure/><Script code="b:=1"/></AsyncFallback>')
        assert dry_run(path, 2, 0.1, exactly_once=True) == {"ticks": ["RUNNING", "SUCCESS"], "blackboard": {"b": 1}}
        assert dry_run(path, 2, 0.1) == {"ticks": ["SUCCESS", "SUCCESS"], "blackboard": {"b": 1}}


def test_tree_command_prints_skipped(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``canguard tree FILE --tick N --json``: a skipped root reads "SKIPPED", as BT.CPP prints it."""
    path = tree(tmp_path, '<Sequence><AlwaysSuccess _skipIf="true"/></Sequence>')
    assert main(["tree", str(path), "--tick", "2", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"ticks": ["SKIPPED", "SKIPPED"], "blackboard": {}}


class TestBranches:
    def test_a_skipped_branch_skips_the_if(self, tmp_path: Path) -> None:
        got = ticks(tmp_path, '<Sequence><IfThenElse><AlwaysSuccess/><AlwaysFailure _skipIf="true"/></IfThenElse>'
                              '<Script code="after:=1"/></Sequence>', 1)
        assert got == {"ticks": ["SUCCESS"], "blackboard": {"after": 1}}

    def test_a_skipped_condition_is_an_error_as_in_bt_cpp(self, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
        """BT.CPP throws (if_then_else_node.cpp); a raising tick is a FAILURE that says why (the engine: a stop)."""
        path = tree(tmp_path, '<IfThenElse><AlwaysSuccess _skipIf="true"/><AlwaysSuccess/></IfThenElse>')
        assert dry_run(path, 1, 0.1)["ticks"] == ["FAILURE"]
        assert "its condition (first child) was skipped" in capsys.readouterr().err
