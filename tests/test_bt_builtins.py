"""More BehaviorTree.CPP 4 built-ins, and the tree dry-run.

The cases follow the behaviour BT.CPP's own gtests check (gtest_decorator.cpp,
gtest_sequence.cpp, script_parser_test.cpp, gtest_blackboard.cpp): a Script writes the
blackboard and succeeds, ScriptCondition reads it, IfThenElse commits to a branch,
WhileDoElse re-checks and halts the running branch when the condition changes,
KeepRunningUntilFailure turns SUCCESS into RUNNING, Precondition returns ``else``.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from py_trees.blackboard import Blackboard

from canguard.bt.context import Context, NullTaskGate
from canguard.bt.dryrun import dry_run
from canguard.bt.loader import load_tree
from canguard.errors import TreeError
from canguard.io.clock import ManualClock
from clikit import cli
from treekit import ListSink, tick


def tree(tmp_path: Path, body: str, name: str = "t.xml") -> Path:
    path = tmp_path / name
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="Main">\n<BehaviorTree ID="Main">\n{body}\n'
                    "</BehaviorTree>\n</root>\n", encoding="utf-8")
    return path




class TestScriptNodes:
    """Script, ScriptCondition, SetBlackboard, UnsetBlackboard on the root blackboard."""

    def test_script_then_condition(self, tmp_path: Path) -> None:
        """The script's writes are read by the condition in the same tick; the sequence succeeds."""
        path = tree(tmp_path, """<Sequence>
  <Script code="speed := 1.5; count := 3"/>
  <Script code="count += 1; label := 'n' .. 'ok'"/>
  <ScriptCondition code="count == 4 &amp;&amp; speed &lt; 2.0"/>
</Sequence>""")
        assert dry_run(path, 1, 0.1) == {"ticks": ["SUCCESS"],
                                         "blackboard": {"count": 4, "label": "nok", "speed": 1.5}}

    def test_false_condition_fails(self, tmp_path: Path) -> None:
        """ScriptCondition of a false expression is FAILURE (and stops the sequence)."""
        path = tree(tmp_path, """<Sequence>
  <Script code="x := 1"/><ScriptCondition code="x &gt; 1"/><Script code="after := true"/>
</Sequence>""")
        assert dry_run(path, 1, 0.1) == {"ticks": ["FAILURE"], "blackboard": {"x": 1}}

    def test_set_and_unset_blackboard(self, tmp_path: Path) -> None:
        """SetBlackboard writes value under output_key; UnsetBlackboard removes the entry."""
        path = tree(tmp_path, """<Sequence>
  <SetBlackboard value="hello" output_key="greeting"/>
  <SetBlackboard value="42" output_key="answer"/>
  <UnsetBlackboard key="answer"/>
</Sequence>""")
        assert dry_run(path, 1, 0.1)["blackboard"] == {"greeting": "hello"}

    def test_runtime_script_error_is_failure_not_a_crash(self, tmp_path: Path) -> None:
        """Reading an entry that does not exist fails the node (BT.CPP throws; a daemon must not)."""
        path = tree(tmp_path, '<Script code="y := missing + 1"/>')
        assert dry_run(path, 1, 0.1)["ticks"] == ["FAILURE"]

    def test_syntax_error_is_a_load_error(self, tmp_path: Path) -> None:
        """A script that does not parse fails the load, naming the file, line and port."""
        path = tree(tmp_path, '<Sequence>\n<Script code="x := := 2"/>\n</Sequence>')
        with pytest.raises(TreeError) as err:
            dry_run(path, 1, 0.1)
        assert f"{path}:4" in str(err.value) and "code" in str(err.value)


class TestBranching:
    """IfThenElse and WhileDoElse."""

    def test_if_then_else(self, tmp_path: Path) -> None:
        """SUCCESS takes the second child, FAILURE the third; no third child: FAILURE."""
        ok = tree(tmp_path, """<IfThenElse><AlwaysSuccess/><Script code="b := 'then'"/>
  <Script code="b := 'else'"/></IfThenElse>""", "a.xml")
        assert dry_run(ok, 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"b": "then"}}
        no = tree(tmp_path, """<IfThenElse><AlwaysFailure/><Script code="b := 'then'"/>
  <Script code="b := 'else'"/></IfThenElse>""", "b.xml")
        assert dry_run(no, 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"b": "else"}}
        two = tree(tmp_path, "<IfThenElse><AlwaysFailure/><AlwaysSuccess/></IfThenElse>", "c.xml")
        assert dry_run(two, 1, 0.1)["ticks"] == ["FAILURE"]

    def test_if_then_else_commits_while_running(self, tmp_path: Path) -> None:
        """The condition is not re-checked while the chosen branch runs (BT.CPP IfThenElse)."""
        path = tree(tmp_path, """<IfThenElse><ScriptCondition code="go"/><Sleep msec="250"/>
  <AlwaysFailure/></IfThenElse>""")
        clock = ManualClock()
        loaded = load_tree(path, Context(clock, {}, sink=ListSink(), task=NullTaskGate()))
        Blackboard.storage["/go"] = True
        assert tick(loaded).name == "RUNNING"
        Blackboard.storage["/go"] = False
        clock.set(0.1)
        assert tick(loaded).name == "RUNNING"
        clock.set(0.3)
        assert tick(loaded).name == "SUCCESS"

    def test_while_do_else_switches_and_halts(self, tmp_path: Path) -> None:
        """The condition changes while the do-branch runs: it is halted and the else-branch runs."""
        path = tree(tmp_path, """<WhileDoElse><ScriptCondition code="go"/><Sleep msec="250"/>
  <Script code="switched := true"/></WhileDoElse>""")
        clock = ManualClock()
        loaded = load_tree(path, Context(clock, {}, sink=ListSink(), task=NullTaskGate()))
        Blackboard.storage["/go"] = True
        assert tick(loaded).name == "RUNNING"
        sleep = loaded.root.children[1]
        Blackboard.storage["/go"] = False
        clock.set(0.1)
        assert tick(loaded).name == "SUCCESS"
        assert Blackboard.storage["/switched"] == 1.0  # BT.CPP: true is the real 1.0
        assert sleep.status.name == "INVALID"  # halted

    def test_while_do_else_takes_two_children(self, tmp_path: Path) -> None:
        """Two children, as BT.CPP accepts: the condition's FAILURE fails the node and halts the running branch."""
        path = tree(tmp_path, """<WhileDoElse><ScriptCondition code="go"/>
  <Sleep msec="250" _onHalted="halted := true"/></WhileDoElse>""")
        clock = ManualClock()
        loaded = load_tree(path, Context(clock, {}))
        Blackboard.storage["/go"] = True
        assert tick(loaded).name == "RUNNING"
        Blackboard.storage["/go"] = False
        assert tick(loaded).name == "FAILURE"
        assert Blackboard.storage["/halted"] == 1.0  # BT.CPP: true is the real 1.0

    def test_while_do_else_needs_two_or_three_children(self, tmp_path: Path) -> None:
        """One child: a load error naming the node."""
        path = tree(tmp_path, "<WhileDoElse><AlwaysSuccess/></WhileDoElse>")
        with pytest.raises(TreeError, match="WhileDoElse needs 2 or 3 children"):
            dry_run(path, 1, 0.1)


class TestDecorators:
    """KeepRunningUntilFailure, Precondition, Sleep on the manual clock."""

    def test_keep_running_until_failure(self, tmp_path: Path) -> None:
        """A succeeding child keeps the decorator RUNNING; a failing one ends it with FAILURE."""
        path = tree(tmp_path, """<KeepRunningUntilFailure><Sequence>
  <Script code="n := 1"/></Sequence></KeepRunningUntilFailure>""")
        assert dry_run(path, 3, 0.1)["ticks"] == ["RUNNING"] * 3
        fails = tree(tmp_path, "<KeepRunningUntilFailure><AlwaysFailure/></KeepRunningUntilFailure>", "f.xml")
        assert dry_run(fails, 1, 0.1)["ticks"] == ["FAILURE"]

    @pytest.mark.parametrize(("cond", "other", "expected"), [
        ("true", "FAILURE", "SUCCESS"), ("false", "FAILURE", "FAILURE"), ("false", "SUCCESS", "SUCCESS"),
        ("false", "RUNNING", "RUNNING"),
    ])
    def test_precondition(self, tmp_path: Path, cond: str, other: str, expected: str) -> None:
        """The child runs when `if` holds; otherwise the decorator returns `else`."""
        path = tree(tmp_path, f'<Precondition if="{cond}" else="{other}"><AlwaysSuccess/></Precondition>')
        assert dry_run(path, 1, 0.1)["ticks"] == [expected]

    def test_sleep_counts_the_engine_clock(self, tmp_path: Path) -> None:
        """Sleep 250 ms at 0.1 s per tick: RUNNING, RUNNING, then SUCCESS at 0.3 s (the first tick at or after)."""
        path = tree(tmp_path, '<Sleep msec="250"/>')
        assert dry_run(path, 4, 0.1)["ticks"] == ["RUNNING", "RUNNING", "RUNNING", "SUCCESS"]


class TestDryRunCommand:
    """`canguard tree TREE.xml --tick N --dt S --json`."""

    def test_json_is_exactly_ticks_and_blackboard(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """The documented shape: upper-case statuses, the root blackboard as JSON values."""
        path = tree(tmp_path, """<Sequence><Script code="count := 0; ratio := 0.5"/>
  <Sleep msec="150"/></Sequence>""")
        code, out, err = cli(capsys, "tree", path, "--tick", "3", "--dt", "0.1", "--json")
        assert code == 0, err
        assert json.loads(out) == {"ticks": ["RUNNING", "RUNNING", "SUCCESS"],
                                   "blackboard": {"count": 0, "ratio": 0.5}}

    def test_a_tree_that_does_not_load_is_exit_2_with_lines(self, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
        """An unknown node and a bad port: exit 2, each with file:line."""
        path = tree(tmp_path, '<Sequence>\n<Nope/>\n<Sleep msecs="3"/>\n</Sequence>')
        code, out, err = cli(capsys, "tree", path, "--tick", "1", "--json")
        assert code == 2 and out == ""
        assert f"{path}:4" in err and "Nope" in err
        assert f"{path}:5" in err and "msecs" in err

    def test_guard_without_config_says_what_to_do(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """A guard needs a configured source: the error names it (a dry run has no config)."""
        path = tree(tmp_path, '<IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="3" '
                              'recovery_threshold="2"/>')
        code, _, err = cli(capsys, "tree", path, "--tick", "1")
        assert code == 2 and "/battery_state" in err

    def test_tick_without_a_file_is_refused(self, capsys: pytest.CaptureFixture[str]) -> None:
        """--tick belongs to TREE.xml: with a config it is exit 2 saying how to use it."""
        code, _, err = cli(capsys, "tree", "--tick", "2")
        assert code == 2 and "canguard tree TREE.xml --tick N" in err


class TestCounts:
    """Repeat / RetryUntilSuccessful counts BT.CPP accepts."""

    def test_retry_zero_attempts_fails_without_ticking(self, tmp_path: Path) -> None:
        """num_attempts="0": FAILURE at once, the child never ticked (retry_node.cpp)."""
        path = tree(tmp_path, '<RetryUntilSuccessful num_attempts="0"><Script code="ticked := 1"/>'
                              "</RetryUntilSuccessful>")
        assert dry_run(path, 1, 0.1) == {"ticks": ["FAILURE"], "blackboard": {}}

    def test_repeat_zero_cycles_succeeds_without_ticking(self, tmp_path: Path) -> None:
        """num_cycles="0": SUCCESS at once, the child never ticked (repeat_node.cpp)."""
        path = tree(tmp_path, '<Repeat num_cycles="0"><Script code="ticked := 1"/></Repeat>')
        assert dry_run(path, 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {}}

    def test_counts_and_flags_computed_by_scripts(self, tmp_path: Path) -> None:
        """Script results are reals (1 + 1 is 2.0, true is 1.0): int and bool ports take them, as BT.CPP casts them."""
        path = tree(tmp_path, '<Sequence><Script code="k := 1 + 1; n := 0; skip := false"/>'
                              '<Repeat num_cycles="{k}"><Script code="n += 1"/></Repeat>'
                              '<RunOnce then_skip="{skip}"><Script code="once := 1"/></RunOnce></Sequence>')
        got = dry_run(path, 2, 0.1)
        assert got["ticks"] == ["SUCCESS", "SUCCESS"]
        assert got["blackboard"] == {"k": 2.0, "n": 2, "once": 1, "skip": 0.0}


class TestSetBlackboardTypes:
    def test_text_into_a_typed_entry_is_parsed_to_its_type(self, tmp_path: Path) -> None:
        """SetBlackboard value="7" over an integer entry writes the integer 7; words there fail the node."""
        path = tree(tmp_path, '<Sequence><Script code="a := 1"/><SetBlackboard output_key="a" value="7"/>'
                              '<Script code="b := a * 2"/></Sequence>')
        assert dry_run(path, 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"a": 7, "b": 14.0}}
        path.write_text(path.read_text().replace('value="7"', 'value="seven"'))
        assert dry_run(path, 1, 0.1) == {"ticks": ["FAILURE"], "blackboard": {"a": 1}}

    def test_a_text_entry_on_an_int_port_is_parsed(self, tmp_path: Path) -> None:
        """k := '2' drives Repeat num_cycles="{k}" (BT.CPP parses a string entry to the port's type); 'two' fails."""
        path = tree(tmp_path, '<Sequence><Script code="k := \'2\'; n := 0"/>'
                              '<Repeat num_cycles="{k}"><Script code="n += 1"/></Repeat></Sequence>')
        # the entry is an int, as Repeat's port declared it: the script's '2' is parsed (BT.CPP's converter)
        assert dry_run(path, 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"k": 2, "n": 2}}
        path.write_text(path.read_text().replace("'2'", "'two'"))
        assert dry_run(path, 1, 0.1) == {"ticks": ["FAILURE"], "blackboard": {}}  # the script fails
