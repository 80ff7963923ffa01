"""Control nodes keep BehaviorTree.CPP semantics (memory, reactivity, counts, clocks)."""

from __future__ import annotations

from pathlib import Path

import pytest

from treekit import F, R, Rig, S, install_scripted, xml_tree


@pytest.fixture
def log(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, str]]:
    """The Scripted leaf's log (ticks as S/R/F, halts as 'halt')."""
    return install_scripted(monkeypatch)


def run(tmp_path: Path, body: str, ticks: int, dt: float = 0.0, rig: Rig | None = None) -> list[object]:
    rig = rig or Rig()
    rig.load_text(tmp_path, xml_tree(body))
    out = []
    for _ in range(ticks):
        out.append(rig.tick())
        rig.advance(dt)
    return out


class TestSequences:
    """Sequence, ReactiveSequence, SequenceWithMemory."""

    def test_sequence_resumes_at_the_running_child(self, tmp_path: Path, log: list) -> None:
        """BT.CPP Sequence does not re-tick earlier children while a later one runs."""
        body = '<Sequence><Scripted name="G" script="S,F"/><Scripted name="A" script="R,R,S"/></Sequence>'
        assert run(tmp_path, body, 3) == [R, R, S]
        assert log == [("G", "S"), ("A", "R"), ("A", "R"), ("A", "S")]

    def test_sequence_restarts_after_failure(self, tmp_path: Path, log: list) -> None:
        """After a FAILURE the next tick starts at the first child again."""
        body = '<Sequence><Scripted name="A" script="S"/><Scripted name="B" script="F,S"/></Sequence>'
        assert run(tmp_path, body, 2) == [F, S]
        assert log == [("A", "S"), ("B", "F"), ("A", "S"), ("B", "S")]

    def test_reactive_sequence_rechecks_and_halts(self, tmp_path: Path, log: list) -> None:
        """Every tick re-checks the guard; its FAILURE halts the running child."""
        body = '<ReactiveSequence><Scripted name="G" script="S,S,F"/><Scripted name="A" script="R"/></ReactiveSequence>'
        assert run(tmp_path, body, 3) == [R, R, F]
        assert log == [("G", "S"), ("A", "R"), ("G", "S"), ("A", "R"), ("G", "F"), ("A", "halt")]

    def test_sequence_with_memory_resumes_after_failure(self, tmp_path: Path, log: list) -> None:
        """A failed child is ticked again next time without re-ticking the ones that succeeded.

        As BT.CPP 4 (sequence_with_memory_node.cpp): after a child that succeeded at once
        from IDLE it yields RUNNING (the wake-up every factory-built tree has), so A's
        success and B's first try fall in different ticks.
        """
        body = (
            '<SequenceWithMemory><Scripted name="A" script="S"/><Scripted name="B" script="F,S,F"/>'
            "</SequenceWithMemory>"
        )
        assert run(tmp_path, body, 5) == [R, F, S, R, F]
        assert log == [("A", "S"), ("B", "F"), ("B", "S"), ("A", "S"), ("B", "F")]


class TestFallbacks:
    """Fallback and ReactiveFallback."""

    def test_fallback_resumes_at_the_running_child(self, tmp_path: Path, log: list) -> None:
        """A failed higher priority is not re-tried while a lower one runs."""
        body = '<Fallback><Scripted name="A" script="F,S"/><Scripted name="B" script="R,S"/></Fallback>'
        assert run(tmp_path, body, 2) == [R, S]
        assert log == [("A", "F"), ("B", "R"), ("B", "S")]

    def test_reactive_fallback_interrupts(self, tmp_path: Path, log: list) -> None:
        """A higher priority that succeeds halts the running lower one."""
        body = '<ReactiveFallback><Scripted name="A" script="F,S"/><Scripted name="B" script="R"/></ReactiveFallback>'
        assert run(tmp_path, body, 2) == [R, S]
        assert log == [("A", "F"), ("B", "R"), ("A", "S"), ("B", "halt")]


class TestParallel:
    """BT.CPP 4 Parallel with success_count / failure_count."""

    def test_default_waits_for_all_and_does_not_retick_finished(self, tmp_path: Path, log: list) -> None:
        """success_count=-1: all must succeed; a finished child is not ticked again."""
        body = '<Parallel><Scripted name="A" script="S"/><Scripted name="B" script="R,S"/></Parallel>'
        assert run(tmp_path, body, 2) == [R, S]
        assert log == [("A", "S"), ("B", "R"), ("B", "S")]

    def test_success_count_one_halts_the_others(self, tmp_path: Path, log: list) -> None:
        """One success is enough; the still running child is halted."""
        body = '<Parallel success_count="1"><Scripted name="A" script="R"/><Scripted name="B" script="S"/></Parallel>'
        assert run(tmp_path, body, 1) == [S]
        assert log == [("A", "R"), ("B", "S"), ("A", "halt")]

    def test_failure_count(self, tmp_path: Path, log: list) -> None:
        """failure_count=2: the second failure fails the parallel and halts the rest."""
        body = (
            '<Parallel success_count="1" failure_count="2"><Scripted name="A" script="F"/>'
            '<Scripted name="B" script="R,F"/><Scripted name="C" script="R"/></Parallel>'
        )
        assert run(tmp_path, body, 2) == [R, F]
        assert log[-2:] == [("B", "F"), ("C", "halt")]

    def test_fails_early_when_success_is_impossible(self, tmp_path: Path, log: list) -> None:
        """With all children needed, one failure fails at once, before later children are ticked."""
        body = '<Parallel failure_count="2"><Scripted name="A" script="F"/><Scripted name="B" script="R"/></Parallel>'
        assert run(tmp_path, body, 1) == [F]
        assert log == [("A", "F")]


class TestDecorators:
    """Inverter, ForceSuccess, ForceFailure, RetryUntilSuccessful, Repeat."""

    @pytest.mark.parametrize(
        ("tag", "expected"),
        [("Inverter", [F, R, S]), ("ForceSuccess", [S, R, S]), ("ForceFailure", [F, R, F])],
    )
    def test_status_mapping(self, tmp_path: Path, log: list, tag: str, expected: list) -> None:
        """SUCCESS, RUNNING, FAILURE of the child map as in BT.CPP."""
        assert run(tmp_path, f'<{tag}><Scripted name="A" script="S,R,F"/></{tag}>', 3) == expected

    @pytest.mark.parametrize(
        ("attempts", "script", "expected"),
        [("3", "F,F,S", [R, R, S]), ("3", "F", [R, R, F, R]), ("-1", "F", [R] * 5), ("1", "F", [F, F]),
         ("3", "R,F,S", [R, S]), ("2", "R,F,F", [R, F])],
    )
    def test_retry(self, tmp_path: Path, log: list, attempts: str, script: str, expected: list) -> None:
        """As BT.CPP 4's retry_node.cpp in a factory-built tree: a child that failed at once is retried at the next
        tick; one that was RUNNING and then failed is retried within the tick; FAILURE once the attempts are used up
        (-1: never)."""
        body = (
            f'<RetryUntilSuccessful num_attempts="{attempts}">'
            f'<Scripted name="A" script="{script}"/></RetryUntilSuccessful>'
        )
        assert run(tmp_path, body, len(expected)) == expected

    @pytest.mark.parametrize(
        ("cycles", "script", "expected"),
        [("3", "S", [R, R, S, R]), ("3", "S,F", [R, F]), ("-1", "S", [R] * 4), ("2", "R,S,S", [R, S])],
    )
    def test_repeat(self, tmp_path: Path, log: list, cycles: str, script: str, expected: list) -> None:
        """As BT.CPP 4's repeat_node.cpp: a child that succeeded at once is repeated at the next tick, one that was
        RUNNING and then succeeded is repeated within the tick; a FAILURE ends the repetition."""
        body = f'<Repeat num_cycles="{cycles}"><Scripted name="A" script="{script}"/></Repeat>'
        assert run(tmp_path, body, len(expected)) == expected

    def test_repeat_zero_cycles(self, tmp_path: Path, log: list) -> None:
        """num_cycles=0 succeeds without ticking the child."""
        assert run(tmp_path, '<Repeat num_cycles="0"><Scripted name="A" script="S"/></Repeat>', 1) == [S]
        assert log == []

    def test_counts_from_the_blackboard(self, tmp_path: Path, log: list) -> None:
        """num_attempts may come from a {key}; it is read at tick."""
        import py_trees

        rig = Rig()
        rig.load_text(
            tmp_path,
            xml_tree('<RetryUntilSuccessful num_attempts="{n}"><Scripted name="A" script="F"/></RetryUntilSuccessful>'),
        )
        py_trees.blackboard.Blackboard.set("/n", 2)
        assert [rig.tick(), rig.tick()] == [R, F]


class TestTimeout:
    """Timeout on the context's (manual) clock."""

    def test_times_out_and_halts_the_child(self, tmp_path: Path, log: list) -> None:
        """msec=1500: RUNNING at 0 s and 1 s; at 1.5 s FAILURE, the child halted and not ticked."""
        body = '<Timeout msec="1500"><Scripted name="A" script="R"/></Timeout>'
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(body))
        out = []
        for t in (0.0, 1.0, 1.5, 1.6):
            rig.clock.set(1000.0 + t)
            out.append(rig.tick())
        assert out == [R, R, F, R]
        assert log == [("A", "R"), ("A", "R"), ("A", "halt"), ("A", "R")]

    def test_child_finishing_in_time(self, tmp_path: Path, log: list) -> None:
        """A child that completes before the deadline gives its status; the next run has a fresh timer."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree('<Timeout msec="1000"><Scripted name="A" script="R,F,R,R,R"/></Timeout>'))
        out = []
        for t in (0.0, 0.9, 5.0, 5.5, 6.0):
            rig.clock.set(1000.0 + t)
            out.append(rig.tick())
        assert out == [R, F, R, R, F]

    def test_zero_means_no_limit(self, tmp_path: Path, log: list) -> None:
        """msec=0 never times out."""
        assert run(tmp_path, '<Timeout msec="0"><Scripted name="A" script="R"/></Timeout>', 4, dt=100.0) == [R] * 4


class TestDelay:
    """Delay on the context's (manual) clock."""

    def test_waits_then_ticks_the_child(self, tmp_path: Path, log: list) -> None:
        """delay_msec=500: RUNNING until 0.5 s, then the child's status; then a new wait."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree('<Delay delay_msec="500"><Scripted name="A" script="S"/></Delay>'))
        out = []
        for t in (0.0, 0.4, 0.5, 0.6, 1.1):
            rig.clock.set(1000.0 + t)
            out.append(rig.tick())
        assert out == [R, R, S, R, S]
        assert log == [("A", "S"), ("A", "S")]

    def test_halt_restarts_the_wait(self, tmp_path: Path, log: list) -> None:
        """A Delay halted by a reactive parent waits the full delay again."""
        rig = Rig()
        body = (
            '<ReactiveSequence><Scripted name="G" script="S,F,S,S,S"/>'
            '<Delay delay_msec="500"><Scripted name="A" script="S"/></Delay></ReactiveSequence>'
        )
        rig.load_text(tmp_path, xml_tree(body))
        out = []
        for t in (0.0, 0.3, 0.6, 1.0, 1.1):
            rig.clock.set(1000.0 + t)
            out.append(rig.tick())
        assert out == [R, F, R, R, S]
