"""BehaviorTree.CPP 4's sequences, fallbacks, Parallel and decorators, SKIPPED included, and Profile.

Timeout and Delay read the context's clock (py_trees' Timeout reads ``time.monotonic``). Profile (design note 003)
reads the one real clock in nodes/: it measures CPU work (in replay the context's clock stands still during a tick).
"""

from __future__ import annotations

from time import perf_counter
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
    halted,
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
            self.initialise()
        n = len(self.children)  # at least one: the loader refuses a control node without children
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
    """BT.CPP 4's ``retry_node.cpp`` / ``repeat_node.cpp``; a child that completed at once runs again at the next
    pass (RUNNING and a wake-up, as BT.CPP)."""

    ENDS: ClassVar[Status]  # the child's status that ends it; another completion is counted and run again
    DONE: ClassVar[Status]  # the status after LIMIT runs
    LIMIT: ClassVar[str]  # the port of the number of runs (-1: forever)
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
                self.wake_up.pending = True  # BT.CPP's emitWakeUpSignal
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
                self.wake_up.arm(self, self.deadline)  # BT.CPP: the timer wakes the tree up when it expires
            self.initialise()
        elif self.deadline is not None and now >= self.deadline:
            self.feedback_message = "timed out"
            yield end_as(self, FAILURE)  # py_trees' Decorator.stop halts the running child
            return
        yield from self.decorated.tick()
        if self.decorated.status != RUNNING:
            self.wake_up.cancel(self)
        yield end_as(self, self.decorated.status)

    def terminate(self, new_status: py_trees.common.Status) -> None:
        if new_status == INVALID:
            self.wake_up.cancel(self)


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
                self.wake_up.arm(self, now + delay / 1000.0)  # BT.CPP: the timer wakes the tree up when it expires
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
            self.wake_up.cancel(self)


class _Ordered(CanguardNode, py_trees.composites.Composite):
    """BT.CPP 4's sequences and fallbacks (``sequence_node.cpp``, ``fallback_node.cpp`` ...); SKIPPED children are
    passed over (all skipped: SKIPPED)."""

    GO_ON: ClassVar[py_trees.common.Status] = SUCCESS  # the child status that moves on (fallback: FAILURE)
    REACTIVE: ClassVar[bool] = False  # every tick starts at the first child
    ASYNC: ClassVar[bool] = False  # after a child that completed at once: RUNNING and a wake-up
    KEEP_ON_STOP: ClassVar[bool] = False  # the next run resumes at the child that ended this one
    index = 0  # the child the next tick starts at
    skipped_count = 0

    @property
    def memory(self) -> bool:
        """py_trees' word: a RUNNING child is resumed without re-ticking the earlier ones (not reactive)."""
        return not self.REACTIVE

    def terminate(self, new_status: py_trees.common.Status) -> None:
        if new_status == INVALID and not self.KEEP_ON_STOP:
            self.index = 0
            self.skipped_count = 0

    def tick(self) -> Any:
        children = self.children
        n = len(children)
        if self.status != RUNNING:
            self.skipped_count = 0
            # py_trees' way of BT.CPP's resetChildren: a new run starts from IDLE children
            reset(children[0 if self.REACTIVE else self.index:])
            self.initialise()
        if self.REACTIVE:
            yield from self._tick_reactive(children)
            return
        while self.index < n:
            child = children[self.index]
            self.current_child = child
            before = child.status
            yield from tick_child(child)
            result = outcome(child)
            if result == RUNNING:
                yield end_as(self, RUNNING)
                return
            if result == SKIPPED:
                self.index += 1
                self.skipped_count += 1
                continue
            if result != self.GO_ON:  # the run ends with this child's status
                reset(children[self.index + 1:])
                if not self.KEEP_ON_STOP:
                    self.index = 0
                yield end_as(self, child.status)
                return
            self.index += 1
            if self.ASYNC and before == INVALID and self.index < n:
                self.wake_up.pending = True  # BT.CPP's emitWakeUpSignal
                yield end_as(self, RUNNING)
                return
        all_skipped = self.skipped_count == n
        self.index = 0
        self.skipped_count = 0
        yield end_as(self, SKIPPED if all_skipped else self.GO_ON)

    def _tick_reactive(self, children: list[py_trees.behaviour.Behaviour]) -> Any:
        all_skipped = True
        for index, child in enumerate(children):
            self.current_child = child
            yield from tick_child(child)
            result = outcome(child)
            all_skipped = all_skipped and result == SKIPPED
            if result == RUNNING or (result != SKIPPED and result != self.GO_ON):
                # halt the others: a running child interrupted by an earlier one, the rest of the run
                for i, other in enumerate(children):
                    if i != index and (other.status == RUNNING or (i > index and other.status != INVALID)):
                        other.stop(INVALID)
                yield end_as(self, child.status)
                return
        yield end_as(self, SKIPPED if all_skipped else self.GO_ON)


Sequence, AsyncSequence, ReactiveSequence, SequenceWithMemory, Fallback, AsyncFallback, ReactiveFallback = node_types(
    _Ordered, __name__, {
        "Sequence": {"QUIET_RETICK": True,
                     "DESCRIPTION": "children in order; a RUNNING child is resumed (earlier ones not re-ticked)"},
        "AsyncSequence": {"ASYNC": True,
                          "DESCRIPTION": "a Sequence that yields (RUNNING) after each child that succeeded at once"},
        "ReactiveSequence": {"QUIET_RETICK": True, "REACTIVE": True, "DESCRIPTION": (
            "children in order, from the first at every tick (guards re-checked while a child runs)")},
        # BT.CPP 4's SequenceWithMemory always yields after a child that completed at once
        "SequenceWithMemory": {"ASYNC": True, "KEEP_ON_STOP": True, "DESCRIPTION": (
            "children in order; after a FAILURE or RUNNING the next tick resumes at that child")},
        "Fallback": {"QUIET_RETICK": True, "GO_ON": FAILURE,
                     "DESCRIPTION": "children in order until one does not fail; a RUNNING child is resumed"},
        "AsyncFallback": {"GO_ON": FAILURE, "ASYNC": True,
                          "DESCRIPTION": "a Fallback that yields (RUNNING) after each child that failed at once"},
        "ReactiveFallback": {"QUIET_RETICK": True, "GO_ON": FAILURE, "REACTIVE": True, "DESCRIPTION": (
            "children in order, from the first at every tick (higher priorities interrupt)")},
    })


class Profile(DecoratorNode):
    """transparent: times its child's tick, outputs last/avg/max ms and count; resets on halt"""

    OUTPUT_PORTS = {  # noqa: RUF012
        "last_ms": port_info(float, "duration of the child's last tick (ms)", required=False),
        "avg_ms": port_info(float, "mean duration since the last reset (ms)", required=False),
        "max_ms": port_info(float, "longest duration since the last reset (ms)", required=False),
        "count": port_info(int, "ticks measured since the last reset", required=False),
    }

    last_ms = 0.0  # the measurements since the last reset (a halt)
    avg_ms = 0.0
    max_ms = 0.0
    count = 0

    def tick(self) -> Any:
        if self.status != RUNNING:
            self.initialise()
        t0 = perf_counter()
        nodes = list(self.decorated.tick())
        ms = (perf_counter() - t0) * 1000.0
        yield from nodes
        self.last_ms = ms
        self.count += 1
        self.avg_ms += (ms - self.avg_ms) / self.count  # the running mean
        self.max_ms = max(self.max_ms, ms)
        for name in self.OUTPUT_PORTS:
            self.write(name, getattr(self, name))  # written when wired
        yield end_as(self, self.decorated.status)

    def terminate(self, new_status: py_trees.common.Status) -> None:
        if halted(self, new_status):  # forget every measurement
            self.last_ms, self.avg_ms, self.max_ms, self.count = 0.0, 0.0, 0.0, 0
