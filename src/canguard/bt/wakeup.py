"""BehaviorTree.CPP's wake-up signal, and ``tickOnce()``: the root re-ticked while a wake-up is pending."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import py_trees

if TYPE_CHECKING:
    from canguard.bt.context import Context

RUNNING = py_trees.common.Status.RUNNING
MAX_RETICKS = 100  # re-ticks of the root in one tick, unlike BT.CPP (docs/trees.md): the rest wait for the next


class WakeUpSignal:
    """The latch a tree's nodes share, and their timers, which :func:`tick_once` fires before it ticks (as
    BT.CPP's timer thread would have between two ticks)."""

    def __init__(self) -> None:
        self.pending = False  # set by BT.CPP's emitWakeUpSignal, cleared by its waitFor(0)
        self._timers: dict[int, float] = {}
        self.capped = False  # consecutive ticks hit the bound: only the first is journalled

    def arm(self, owner: object, deadline: float) -> None:
        """A timer of ``owner`` that emits the signal at ``deadline`` (the engine's clock, s)."""
        self._timers[id(owner)] = deadline

    def cancel(self, owner: object) -> None:
        """Drop ``owner``'s timer, if any."""
        self._timers.pop(id(owner), None)

    def fire_due(self, now: float) -> None:
        """Emit for every timer whose deadline is at or before ``now``, and drop those timers."""
        due = [owner for owner, deadline in self._timers.items() if deadline <= now]
        for owner in due:
            del self._timers[owner]
        self.pending = self.pending or bool(due)


class _Tree(Protocol):
    """What :func:`tick_once` needs of a loaded tree."""

    root: py_trees.behaviour.Behaviour
    wake_up: WakeUpSignal
    context: Context


@dataclass(frozen=True)
class Ticked:
    """What one :func:`tick_once` did."""

    status: py_trees.common.Status  # the root's, after the last tick (INVALID when SKIPPED)
    skipped: bool
    reached: frozenset[py_trees.behaviour.Behaviour] | None  # collect=True: every node the ticks reached


def _tick_root(root: py_trees.behaviour.Behaviour, reached: set | None) -> None:
    root.skipped = False  # type: ignore[attr-defined]
    nodes: Iterator[py_trees.behaviour.Behaviour] = root.tick()
    if reached is None:
        for _ in nodes:  # py_trees' tick_once, without building the list
            pass
    else:
        reached.update(nodes)


def tick_once(tree: _Tree, max_reticks: int = MAX_RETICKS, *, exactly_once: bool = False,
              collect: bool = False) -> Ticked:
    """BT.CPP's ``tickOnce()``: tick the root, and again while it is RUNNING with a wake-up pending (at most
    ``max_reticks`` times, an ``error`` event at the first capped tick); ``exactly_once``: ``tickExactlyOnce()``."""
    signal = tree.wake_up
    signal.fire_due(tree.context.clock.now())
    reached: set | None = set() if collect else None
    root = tree.root
    _tick_root(root, reached)
    reticks = 0
    while not exactly_once and root.status == RUNNING and signal.pending and reticks < max_reticks:
        signal.pending = False
        reticks += 1
        _tick_root(root, reached)
    capped = not exactly_once and root.status == RUNNING and signal.pending  # stopped at the bound
    if capped and not signal.capped:
        tree.context.record("error", node=root.name, reason=f"the tree kept waking itself up: {max_reticks} re-ticks "
                            "in one tick, the next tick goes on (BT.CPP's tickOnce would not have returned yet)")
    signal.capped = capped
    return Ticked(root.status, bool(getattr(root, "skipped", False)),
                  frozenset(reached) if reached is not None else None)
