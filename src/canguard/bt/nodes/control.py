"""Parallel and the decorators of BehaviorTree.CPP 4, on py_trees' classes where the semantics match.

Timeout and Delay read the context's clock (py_trees' Timeout reads ``time.monotonic``).
"""

from __future__ import annotations

from typing import Any, ClassVar

import py_trees

from canguard.bt.nodes.base import (
    FAILURE,
    INVALID,
    RUNNING,
    SKIPPED,
    SUCCESS,
    CanguardNode,
    Children,
    DecoratorNode,
    PortError,
    Status,
    count_of,
    end_as,
    node_types,
    outcome,
    port_info,
    reset,
    tick_child,
)


class Parallel(CanguardNode, py_trees.composites.Parallel):
    """ticks every unfinished child each tick; SUCCESS after success_count successes, FAILURE after failure_count
    failures (negative: children + 1 + n, so -1 = all)"""

    INPUT_PORTS = {  # noqa: RUF012
        "success_count": port_info(int, "successes needed (-1: all children)", -1),
        "failure_count": port_info(int, "failures that fail the parallel (-1: all children)", 1),
    }

    def __init__(self, name: str, children: Children = None, **kwargs: Any) -> None:
        policy = py_trees.common.ParallelPolicy.SuccessOnAll(synchronise=False)
        super().__init__(name=name, policy=policy, children=children, **kwargs)
        self.finished: dict[int, py_trees.common.Status] = {}  # completed this run: not ticked again

    def thresholds(self) -> tuple[int, int]:
        """(successes needed, failures that fail it)."""
        return count_of(self, "success_count", -1), count_of(self, "failure_count", 1)

    def bind(self) -> None:
        """Counts larger than the number of children can never be met: a load-time error."""
        n = len(self.children)
        s, f = self.thresholds()
        if not self.is_wired("success_count") and s > n:
            raise PortError("success_count", f"{s} successes needed but only {n} children: can never succeed")
        if not self.is_wired("failure_count") and f > n:
            raise PortError("failure_count", f"{f} failures needed but only {n} children: can never fail")

    def tick(self) -> Any:
        if self.status != RUNNING:
            reset(self.children)
            self.finished.clear()
            self.current_child = None
            self.initialise()
        n = len(self.children)
        if not n:
            yield end_as(self, SUCCESS)
            return
        need_s, need_f = self.thresholds()
        all_needed = (self.port("success_count") or -1) < 0
        skipped = 0
        for index, child in enumerate(self.children):
            if index not in self.finished:
                yield from tick_child(child)
                if outcome(child) == SKIPPED:
                    skipped += 1
                elif child.status in (SUCCESS, FAILURE):
                    self.finished[index] = child.status
            successes = sum(1 for s in self.finished.values() if s == SUCCESS)
            failures = len(self.finished) - successes
            # BT.CPP: with a negative success_count, skipped children count towards it
            done = successes >= need_s or (all_needed and successes + skipped >= need_s)
            if done or n - failures < need_s or failures >= need_f:
                self.current_child = child
                self.finished.clear()
                yield end_as(self, SUCCESS if done else FAILURE)  # py_trees' Parallel.stop halts the running
                return
        self.current_child = self.children[-1]
        yield end_as(self, SKIPPED if skipped == n else RUNNING)  # every child skipped: the parallel too


Inverter, ForceSuccess, ForceFailure = (  # py_trees' own decorators, under BT.CPP's names
    type(node_id, (CanguardNode, base), {"__module__": __name__, "__doc__": doc, "QUIET_RETICK": True})
    for node_id, base, doc in (
        ("Inverter", py_trees.decorators.Inverter, "SUCCESS <-> FAILURE; RUNNING unchanged"),
        ("ForceSuccess", py_trees.decorators.FailureIsSuccess, "FAILURE becomes SUCCESS; RUNNING unchanged"),
        ("ForceFailure", py_trees.decorators.SuccessIsFailure, "SUCCESS becomes FAILURE; RUNNING unchanged")))


class _Cycles(DecoratorNode):
    """BT.CPP 4's ``retry_node.cpp`` / ``repeat_node.cpp``: the child's ``ENDS`` status ends it, another
    completion is counted and run again, up to ``LIMIT`` runs (-1: forever), then ``DONE``. A child that
    completed at once runs again at the next pass (RUNNING and a wake-up, as BT.CPP)."""

    ENDS: ClassVar[Status]
    DONE: ClassVar[Status]
    LIMIT: ClassVar[str]
    AGAIN_TEXT: ClassVar[str]  # feedback when the child runs again at the next pass; {}: the count
    DONE_TEXT: ClassVar[str] = ""
    count = 0

    def terminate(self, new_status: py_trees.common.Status) -> None:
        if new_status == INVALID:
            self.count = 0

    def tick(self) -> Any:
        limit = self.port(self.LIMIT)
        if limit is None:
            yield end_as(self, FAILURE)
            return
        child = self.decorated
        while self.count < limit or limit == -1:
            fresh = child.status != RUNNING
            yield from tick_child(child)
            status = child.status
            if status == self.ENDS:
                self.count = 0
            if status in (RUNNING, self.ENDS):
                yield end_as(self, status)
                return
            self.count += 1
            limit = self.port(self.LIMIT)
            if limit is None:
                break
            if fresh and (self.count < limit or limit == -1):
                self.feedback_message = self.AGAIN_TEXT.format(self.count)
                self.emit_wake_up()
                yield end_as(self, RUNNING)
                return
        if self.DONE_TEXT:
            self.feedback_message = self.DONE_TEXT.format(self.count)
        self.count = 0
        yield end_as(self, self.DONE)


RetryUntilSuccessful, Repeat = node_types(_Cycles, __name__, {
    "RetryUntilSuccessful": {
        "INPUT_PORTS": {"num_attempts": port_info(
            int, "attempts before giving up (-1: forever; 0: FAILURE, the child not ticked)")},
        "ENDS": SUCCESS, "DONE": FAILURE, "LIMIT": "num_attempts", "AGAIN_TEXT": "attempt {} failed, retrying",
        "DONE_TEXT": "failed {} time(s)",
        "DESCRIPTION": "a FAILURE is retried, up to num_attempts attempts (-1: forever)"},
    "Repeat": {
        "INPUT_PORTS": {"num_cycles": port_info(
            int, "successes to collect (-1: forever; 0: SUCCESS, the child not ticked)")},
        "ENDS": FAILURE, "DONE": SUCCESS, "LIMIT": "num_cycles", "AGAIN_TEXT": "cycle {} done",
        "DESCRIPTION": "a SUCCESS is repeated, num_cycles times (-1: forever); FAILURE ends it"}})


class Timeout(DecoratorNode):
    """FAILURE (child halted) when the child is still RUNNING msec after it started"""

    INPUT_PORTS = {  # noqa: RUF012
        "msec": port_info(float, "time limit (ms, the engine's clock); 0: none"),
    }
    deadline: float | None = None

    def tick(self) -> Any:
        now = self.ctx.clock.now()
        if self.status != RUNNING:
            msec = self.port("msec")
            self.deadline = now + msec / 1000.0 if msec else None
            if self.deadline is not None:
                self.arm_timer(self.deadline)  # BT.CPP: the timer wakes the tree up when it expires
            self.initialise()
        elif self.deadline is not None and now >= self.deadline:
            if self.decorated.status == RUNNING:
                self.decorated.stop(INVALID)
            self.feedback_message = "timed out"
            yield end_as(self, FAILURE)
            return
        yield from self.decorated.tick()
        if self.decorated.status != RUNNING:
            self.cancel_timer()
        yield end_as(self, self.decorated.status)

    def terminate(self, new_status: py_trees.common.Status) -> None:
        if new_status == INVALID:
            self.cancel_timer()


class Delay(DecoratorNode):
    """waits delay_msec (RUNNING), then ticks the child; the next run waits again"""

    INPUT_PORTS = {  # noqa: RUF012
        "delay_msec": port_info(float, "delay before the child is ticked (ms, the engine's clock)"),
    }
    started: float | None = None

    def tick(self) -> Any:
        now = self.ctx.clock.now()
        delay = self.port("delay_msec")
        if self.status != RUNNING or self.started is None:
            self.started = now
            if delay is not None:
                self.arm_timer(now + delay / 1000.0)  # BT.CPP: the timer wakes the tree up when it expires
            self.initialise()
        if delay is None or now - self.started < delay / 1000.0:
            self.feedback_message = "waiting"
            yield end_as(self, RUNNING)
            return
        self.feedback_message = ""
        yield from self.decorated.tick()
        if self.decorated.status != RUNNING:
            self.started = None
        yield end_as(self, self.decorated.status)

    def terminate(self, new_status: py_trees.common.Status) -> None:
        if new_status == INVALID:
            self.started = None
            self.cancel_timer()
