"""Time conditions and timers, on the manual clock only."""

from __future__ import annotations

from pathlib import Path

import py_trees
import pytest

from treekit import F, Rig, S, find, xml_tree

BB = py_trees.blackboard.Blackboard


def at(rig: Rig, *offsets: float, start: float = 1000.0) -> list[object]:
    """Tick at start + each offset."""
    out = []
    for dt in offsets:
        rig.clock.set(start + dt)
        out.append(rig.tick())
    return out


class TestCompare:
    """The five operators."""

    @pytest.mark.parametrize(
        ("op", "results"),
        [
            ("GT", [False, False, True]),
            ("LT", [True, False, False]),
            ("GTE", [False, True, True]),
            ("LTE", [True, True, False]),
            ("EQ", [False, True, False]),
        ],
    )
    def test_operators(self, tmp_path: Path, op: str, results: list[bool]) -> None:
        """9, 10 and 11 s after the first tick against reference_sec 10 (EQ: |Δ| < tolerance 0.1)."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(f'<IsElapsedTimeCompare reference_sec="10" operator="{op}"/>'))
        at(rig, 0.0)
        assert at(rig, 9.0, 10.0, 11.0) == [S if r else F for r in results]

    def test_eq_tolerance(self, tmp_path: Path) -> None:
        """EQ is strict inside the tolerance."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree('<IsElapsedTimeCompare reference_sec="10" operator="EQ"/>'))
        assert at(rig, 0.0, 9.95, 10.2) == [F, S, F]


class TestIsElapsedTimeCompare:
    """Reference modes and shared timers."""

    def test_first_tick_starts_the_own_timer(self, tmp_path: Path) -> None:
        """Default reference: the first tick; without a timer port the node's own timer holds it."""
        rig = Rig()
        loaded = rig.load_text(tmp_path, xml_tree('<IsElapsedTimeCompare reference_sec="5"/>'))
        assert at(rig, 0.0, 5.0, 5.01) == [F, F, S]
        assert loaded.root.timer_start() == 1000.0

    def test_nodes_share_a_named_timer(self, tmp_path: Path) -> None:
        """Two comparisons naming one timer, first ticked at different times, measure from the same start."""
        rig = Rig()
        body = (
            '<Sequence><IsElapsedTimeCompare name="a" reference_sec="2" operator="GTE" timer="{t}"/>'
            '<IsElapsedTimeCompare name="b" reference_sec="3" operator="LT" timer="{t}"/></Sequence>'
        )
        rig.load_text(tmp_path, xml_tree(body))
        assert at(rig, 0.0, 2.0, 2.9, 3.0) == [F, S, S, F]  # b first ticks at 2 s yet measures from 0 s

    def test_named_timers_are_independent(self, tmp_path: Path) -> None:
        """ResetTimer(timer={nav}) restarts only that timer."""
        rig = Rig()
        body = (
            '<Parallel success_count="2" failure_count="2">'
            '<IsElapsedTimeCompare name="default" reference_sec="10" operator="GTE"/>'
            '<IsElapsedTimeCompare name="nav" reference_sec="10" operator="GTE" timer="{nav}"/>'
            "</Parallel>"
        )
        loaded = rig.load_text(tmp_path, xml_tree(body))
        at(rig, 0.0)
        BB.set("/nav", 1008.0)  # as ResetTimer(timer="{nav}") would at 8 s
        at(rig, 10.0)
        assert find(loaded, "default").status == S
        assert find(loaded, "nav").status == F

    def test_reset_timer_with_named_timer(self, tmp_path: Path) -> None:
        """ResetTimer(timer="{nav}") writes now to /nav; the comparison's own timer stays."""
        rig = Rig()
        loaded = rig.load_text(
            tmp_path,
            xml_tree(
                '<Sequence><IsElapsedTimeCompare reference_sec="0" operator="GTE"/>'
                '<ResetTimer timer="{nav}"/></Sequence>'
            ),
        )
        at(rig, 0.0, 3.0)
        assert BB.get("/nav") == 1003.0 and find(loaded, "IsElapsedTimeCompare").timer_start() == 1000.0

    def test_tree_start_reference(self, tmp_path: Path) -> None:
        """reference="tree_start" measures from ctx.tree_start; ResetTimer does not move it."""
        rig = Rig()
        rig.ctx.tree_start = 900.0
        rig.load_text(
            tmp_path,
            xml_tree(
                '<Sequence><ResetTimer/><IsElapsedTimeCompare reference_sec="100" '
                'operator="GTE" reference="tree_start"/></Sequence>'
            ),
        )
        assert at(rig, -0.5, 0.0) == [F, S]

    def test_last_reset_reference(self, tmp_path: Path) -> None:
        """reference="last_reset" fails until some ResetTimer ran, then measures from it."""
        rig = Rig()
        rig.load_text(
            tmp_path,
            xml_tree('<IsElapsedTimeCompare reference_sec="1" operator="GTE" reference="last_reset" timer="{t}"/>'),
        )
        assert at(rig, 0.0, 5.0) == [F, F]
        BB.set("/t", 1004.5)  # as ResetTimer(timer="{t}") would at 4.5 s
        assert at(rig, 5.0, 5.5) == [F, S]

    def test_blackboard_reference(self, tmp_path: Path) -> None:
        """reference="blackboard" reads the event time from the timer key (e.g. written by RecordTime)."""
        rig = Rig()
        body = (
            '<ReactiveSequence><IsElapsedTimeCompare reference_sec="2" operator="LT" reference="blackboard" '
            'timer="{armed_at}"/><ExecuteTask/></ReactiveSequence>'
        )
        rig.load_text(tmp_path, xml_tree(body))
        assert at(rig, 0.0) == [F]
        BB.set("/armed_at", 1000.0)
        assert at(rig, 1.0, 2.0) == [py_trees.common.Status.RUNNING, F]

    def test_operator_from_the_blackboard(self, tmp_path: Path) -> None:
        """operator="{op}" is read at tick; an unknown one fails with a message, not an exception."""
        rig = Rig()
        loaded = rig.load_text(tmp_path, xml_tree('<IsElapsedTimeCompare reference_sec="1" operator="{op}"/>'))
        BB.set("/op", "LT")
        assert at(rig, 0.0) == [S]
        BB.set("/op", "NEAR")
        assert at(rig, 0.5) == [F]
        assert "unknown operator 'NEAR'" in loaded.root.feedback_message


class TestIsElapsedSinceEvent:
    """The time window after an event."""

    def test_window_and_missing_event(self, tmp_path: Path) -> None:
        """Inside [min, max] only; no event yet and an event in the future both fail."""
        rig = Rig()
        rig.load_text(
            tmp_path,
            xml_tree('<IsElapsedSinceEvent event_timestamp="{ev}" min_elapsed_sec="1" max_elapsed_sec="2"/>'),
        )
        assert at(rig, 0.0) == [F]
        BB.set("/ev", 1000.0)
        assert at(rig, 0.9, 1.0, 2.0, 2.1) == [F, S, S, F]
        BB.set("/ev", 1100.0)
        assert at(rig, 3.0) == [F]

    def test_default_window_is_open_ended(self, tmp_path: Path) -> None:
        """Without min/max: any time at or after the event."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree('<IsElapsedSinceEvent event_timestamp="{ev}"/>'))
        BB.set("/ev", 1000)  # an int timestamp is accepted
        assert at(rig, -1.0, 0.0, 1e6) == [F, S, S]


class TestIsCooldownElapsed:
    """Cooldown: never executed, or enough time since."""

    def test_never_executed_and_cooldown(self, tmp_path: Path) -> None:
        """Absent or <= 0 means never executed; afterwards cooldown_sec must pass (default 5 s)."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree('<IsCooldownElapsed last_execution_time="{last}"/>'))
        assert at(rig, 0.0) == [S]
        BB.set("/last", 0.0)
        assert at(rig, 0.0) == [S]
        BB.set("/last", 1000.0)
        assert at(rig, 4.9, 5.0) == [F, S]


class TestRecordTime:
    """RecordTime writes now."""

    def test_writes_now(self, tmp_path: Path) -> None:
        """output_time receives the clock's time at each tick."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree('<RecordTime output_time="{t}"/>'))
        at(rig, 2.5)
        assert BB.get("/t") == 1002.5
