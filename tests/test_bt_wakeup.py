"""BehaviorTree.CPP's ``tickOnce()``: the root is ticked again while a node has emitted its wake-up signal.

``Tree::tickRoot(ONCE_UNLESS_WOKEN_UP)`` in bt_factory.cpp; the nodes that emit the signal are
Repeat, RetryUntilSuccessful (repeat_node.cpp, retry_node.cpp), SequenceWithMemory,
AsyncSequence, AsyncFallback (after a child that completed at once) and the timers of Sleep,
Delay and Timeout. ``tickExactlyOnce()`` (``--exactly-once``) ticks once.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from py_trees.blackboard import Blackboard

from canguard.bt.context import Context, NullTaskGate
from canguard.bt.dryrun import dry_run
from canguard.bt.loader import load_tree
from canguard.bt.wakeup import MAX_RETICKS, tick_once
from canguard.cli.main import main
from canguard.io.clock import ManualClock
from checkout import REPO


def tree(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "t.xml"
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="M">\n<BehaviorTree ID="M">\n{body}\n'
                    "</BehaviorTree>\n</root>\n", encoding="utf-8")
    return path


COUNT = '<Sequence><Script code="n := 0"/><Repeat num_cycles="{}"><Script code="n += 1"/></Repeat></Sequence>'
REPEAT = COUNT.format(3)


class TestTickOnce:
    def test_repeat_over_an_instant_child_finishes_in_one_tick(self, tmp_path: Path) -> None:
        """Repeat num_cycles=3 over a Script: one tickOnce() runs the three cycles and succeeds."""
        assert dry_run(tree(tmp_path, REPEAT), 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"n": 3}}

    def test_exactly_once_needs_a_tick_per_cycle(self, tmp_path: Path) -> None:
        """tickExactlyOnce(): Repeat returns RUNNING after each cycle that completed at once."""
        got = dry_run(tree(tmp_path, REPEAT), 3, 0.1, exactly_once=True)
        assert got == {"ticks": ["RUNNING", "RUNNING", "SUCCESS"], "blackboard": {"n": 3}}

    def test_retry_retries_within_the_tick(self, tmp_path: Path) -> None:
        """RetryUntilSuccessful: the failed attempts are retried in the same tickOnce() until one succeeds."""
        body = ('<Sequence><Script code="n := 0"/><RetryUntilSuccessful num_attempts="5">'
                '<Sequence><Script code="n += 1"/><ScriptCondition code="n >= 3"/></Sequence>'
                '</RetryUntilSuccessful></Sequence>')
        assert dry_run(tree(tmp_path, body), 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"n": 3}}
        got = dry_run(tree(tmp_path, body), 1, 0.1, exactly_once=True)
        assert got == {"ticks": ["RUNNING"], "blackboard": {"n": 1}}

    def test_sequence_with_memory_runs_through(self, tmp_path: Path) -> None:
        """SequenceWithMemory yields after each instant child; tickOnce() wakes up and runs them all."""
        body = ('<SequenceWithMemory><Script code="a := 1"/><Script code="b := 2"/><Script code="c := 3"/>'
                '</SequenceWithMemory>')
        assert dry_run(tree(tmp_path, body), 1, 0.1) == {"ticks": ["SUCCESS"], "blackboard": {"a": 1, "b": 2, "c": 3}}
        got = dry_run(tree(tmp_path, body), 1, 0.1, exactly_once=True)
        assert got == {"ticks": ["RUNNING"], "blackboard": {"a": 1}}

    def test_a_running_child_is_not_re_ticked(self, tmp_path: Path) -> None:
        """No wake-up without an instant completion: a Sleep under Repeat leaves the tick RUNNING after one tick."""
        body = '<Repeat num_cycles="2"><Sleep msec="1000"/></Repeat>'
        assert dry_run(tree(tmp_path, body), 2, 0.1)["ticks"] == ["RUNNING", "RUNNING"]

    def test_an_expired_timer_wakes_the_next_tick(self, tmp_path: Path) -> None:
        """A Sleep whose timer expired leaves the wake-up pending: the next tick that runs ticks the root twice.

        As BT.CPP: the timer emits the signal; the tick where the Sleep completes ends with SUCCESS
        (the signal is only read while the root is RUNNING), so the next tickOnce() re-ticks.
        """
        body = ('<Sequence><Script code="n := 0"/>'
                '<ReactiveSequence><Script code="n += 1"/><Sleep msec="100"/></ReactiveSequence></Sequence>')
        assert dry_run(tree(tmp_path, body), 3, 0.1)["blackboard"] == {"n": 2}
        assert dry_run(tree(tmp_path, body), 3, 0.1, exactly_once=True)["blackboard"] == {"n": 1}


class TestBound:
    def _load(self, tmp_path: Path, body: str) -> tuple[Any, list[dict]]:
        events: list[dict] = []
        ctx = Context(ManualClock(), {}, task=NullTaskGate(), on_event=events.append)
        return load_tree(tree(tmp_path, body), ctx), events

    def test_a_tree_that_keeps_waking_itself_is_bounded_and_journalled(self, tmp_path: Path) -> None:
        """Repeat forever over an instant child: each tick stops at the bound, RUNNING; one error event says why."""
        loaded, events = self._load(tmp_path, COUNT.format("-1"))
        first = tick_once(loaded, max_reticks=10)
        assert (first.status.name, Blackboard.storage["/n"]) == ("RUNNING", 11)  # the tick and 10 re-ticks
        assert tick_once(loaded, max_reticks=10).status.name == "RUNNING"
        assert [e["event"] for e in events] == ["error"]
        assert "kept waking itself up: 10 re-ticks" in events[0]["reason"]

    def test_the_default_bound(self, tmp_path: Path) -> None:
        """The engine's bound is MAX_RETICKS re-ticks per tick."""
        assert dry_run(tree(tmp_path, COUNT.format("-1")), 1, 0.1)["blackboard"] == {"n": MAX_RETICKS + 1}

    def test_each_run_of_capped_ticks_is_journalled_once(self, tmp_path: Path) -> None:
        """Repeat of 5 with a bound of 2: capped, then done, then capped again: two error events, not three."""
        loaded, events = self._load(tmp_path, '<Repeat num_cycles="5"><AlwaysSuccess/></Repeat>')
        got = []
        for _ in range(3):
            got.append((tick_once(loaded, max_reticks=2).status.name, len(events)))
        assert got == [("RUNNING", 1), ("SUCCESS", 1), ("RUNNING", 2)]


class TestCommand:
    def test_tree_command_ticks_once_unless_woken_up(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """``canguard tree FILE --tick 1 --json`` finishes the Repeat; ``--exactly-once`` does not."""
        path = tree(tmp_path, REPEAT)
        assert main(["tree", str(path), "--tick", "1", "--json"]) == 0
        assert json.loads(capsys.readouterr().out) == {"ticks": ["SUCCESS"], "blackboard": {"n": 3}}
        assert main(["tree", str(path), "--tick", "1", "--json", "--exactly-once"]) == 0
        assert json.loads(capsys.readouterr().out) == {"ticks": ["RUNNING"], "blackboard": {"n": 1}}

    def test_a_failing_script_is_named(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """A script that fails at run time fails its node, and the dry run names the node, line and script."""
        path = tree(tmp_path, '<Sequence><Script code="n := 1"/><Script name="Bad" code="missing = 3"/></Sequence>')
        assert main(["tree", str(path), "--tick", "1", "--json"]) == 0
        captured = capsys.readouterr()
        assert json.loads(captured.out)["ticks"] == ["FAILURE"]
        assert f"{path}:3: node Bad: script code 'missing = 3'" in captured.err
        assert "doesn't exist yet" in captured.err


class TestEngine:
    def test_the_engine_ticks_once_unless_woken_up_and_journals_a_capped_tick(self, tmp_path: Path) -> None:
        """The daemon's tick is tickOnce(): a Repeat of 3 over a Script finishes in one tick; a tree that keeps
        waking itself is cut at the bound and one error event says so, and the loop goes on."""
        import yaml
        from py_trees.blackboard import Blackboard

        from canguard.config.loader import load_config
        from canguard.engine.core import Engine
        from canguard.engine.gate import LogSink

        repo = REPO
        bundled = repo / "config" / "canguard.yaml"
        xml = tmp_path / "tree.xml"
        xml.write_text('<root BTCPP_format="4" main_tree_to_execute="T"><BehaviorTree ID="T"><Sequence>'
                       '<Script code="n := 0"/><Repeat num_cycles="3"><Script code="n += 1"/></Repeat>'
                       '<Repeat num_cycles="-1"><AlwaysSuccess/></Repeat></Sequence></BehaviorTree></root>',
                       encoding="utf-8")
        doc = yaml.safe_load(bundled.read_text(encoding="utf-8"))
        doc["dbc"] = [str(repo / "dbc" / "robot.dbc")]
        doc["tree"] = {"file": str(xml), "main": "T", "tick_hz": 100}
        doc["events"] = str(tmp_path / "events.jsonl")
        doc["state"]["file"] = str(tmp_path / "i2t.json")
        cfg_path = tmp_path / "c.yaml"
        cfg_path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        cfg = load_config(cfg_path)
        clock = ManualClock(1000.0)
        events: list[dict[str, Any]] = []
        engine = Engine(cfg, clock, LogSink(clock.now, cfg.buses), on_event=events.append)
        engine.start(1000.0)
        engine.advance(1000.0)
        assert engine.stats.ticks == 1
        assert Blackboard.storage["/n"] == 3  # the three cycles in the first tick
        for i in range(1, 4):
            engine.advance(1000.0 + i * 0.01)
            clock.advance_to(1000.0 + i * 0.01)
        assert engine.stats.ticks == 4  # capped ticks return: the loop is not starved
        capped = [e for e in events if e.get("event") == "error" and "kept waking itself" in str(e.get("reason"))]
        assert len(capped) == 1
