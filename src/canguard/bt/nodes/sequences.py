"""BehaviorTree.CPP 4's sequences and fallbacks (Sequence, AsyncSequence, ReactiveSequence, SequenceWithMemory,
Fallback, AsyncFallback, ReactiveFallback), SKIPPED included."""

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
    end_as,
    node_types,
    outcome,
    reset,
    tick_child,
)


class _Ordered(CanguardNode, py_trees.composites.Composite):
    """BT.CPP 4's sequences and fallbacks (``sequence_node.cpp``, ``fallback_node.cpp`` ...).

    ``GO_ON``: the child status that moves on (SUCCESS in a sequence, FAILURE in a fallback); the
    other ends the run; SKIPPED children are passed over (all skipped: SKIPPED). ``REACTIVE``: every
    tick starts at the first child. ``ASYNC``: after a child that completed at once, RUNNING and a
    wake-up. ``KEEP_ON_STOP``: the next run resumes at the child that ended this one.
    """

    GO_ON: ClassVar[py_trees.common.Status] = SUCCESS
    REACTIVE: ClassVar[bool] = False
    ASYNC: ClassVar[bool] = False
    KEEP_ON_STOP: ClassVar[bool] = False
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
                self.emit_wake_up()
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
