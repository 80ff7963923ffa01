"""BehaviorTree.CPP's wake-up signal, and ``tickOnce()``: the root re-ticked while a wake-up is pending.

One latch per tree, shared by its nodes (BT.CPP's ``Tree::initialize``): a node emits it, the
re-tick loop of ``tickOnce()`` consumes it while the root is RUNNING. Unlike BT.CPP the re-ticks
of one tick are bounded (:data:`MAX_RETICKS`), the first capped tick of a run journalled
(docs/trees.md, "Ticks").
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    import py_trees

    from canguard.bt.context import Context

MAX_RETICKS = 100
"""Re-ticks of the root allowed in one tick (after the first); the rest wait for the next tick."""


class WakeUpSignal:
    """The latch a tree's nodes share: ``emit()`` sets it, ``consume()`` reads and clears it.

    Timers (``arm(owner, deadline)``) emit it once the clock reaches their deadline:
    :func:`tick_once` fires the due ones before it ticks, as BT.CPP's timer thread
    would have between two ticks. ``cancel(owner)`` drops a timer (halt, completion).
    """

    def __init__(self) -> None:
        self.pending = False
        self._timers: dict[int, float] = {}
        self.capped = False
        """True while consecutive ticks hit the re-tick bound (the first of a run is journalled)."""

    def emit(self) -> None:
        """Set the latch (BT.CPP's ``emitWakeUpSignal``)."""
        self.pending = True

    def consume(self) -> bool:
        """Whether the latch was set; clears it (BT.CPP's ``waitFor(0)``)."""
        was = self.pending
        self.pending = False
        return was

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
        if due:
            self.emit()


class _Tree(Protocol):
    """What :func:`tick_once` needs of a loaded tree."""

    root: py_trees.behaviour.Behaviour
    wake_up: WakeUpSignal
    context: Context


@dataclass(frozen=True)
class Ticked:
    """What one :func:`tick_once` did."""

    status: py_trees.common.Status
    """The root's status after the last tick (INVALID when it was SKIPPED: see ``skipped``)."""
    skipped: bool
    """The root returned BT.CPP's SKIPPED."""
    reticks: int
    """How many times the root was ticked again for a pending wake-up."""
    capped: bool
    """The re-ticks stopped at the bound with a wake-up still pending."""
    reached: frozenset[py_trees.behaviour.Behaviour] | None
    """With ``collect=True``: every node any of the ticks reached; else None."""


def _tick_root(root: py_trees.behaviour.Behaviour, reached: set | None) -> None:
    root.skipped = False  # type: ignore[attr-defined]
    nodes: Iterator[py_trees.behaviour.Behaviour] = root.tick()
    if reached is None:
        for _ in nodes:  # py_trees' tick_once, without building the list
            pass
    else:
        reached.update(nodes)


def tick_once(
    tree: _Tree, max_reticks: int = MAX_RETICKS, *, exactly_once: bool = False, collect: bool = False
) -> Ticked:
    """BT.CPP's ``tickOnce()``: tick the root, and again while it is RUNNING with a wake-up pending.

    ``exactly_once``: BT.CPP's ``tickExactlyOnce()`` (one tick; a pending wake-up stays
    pending). ``max_reticks`` bounds the re-ticks; hitting it is journalled (an ``error``
    event naming the root) at the first tick of a run of capped ticks.
    """
    from py_trees.common import Status

    signal = tree.wake_up
    signal.fire_due(tree.context.now())
    reached: set | None = set() if collect else None
    root = tree.root
    _tick_root(root, reached)
    reticks = 0
    capped = False
    while not exactly_once and root.status == Status.RUNNING and signal.pending:
        if reticks >= max_reticks:
            capped = True
            break
        signal.consume()
        reticks += 1
        _tick_root(root, reached)
    if capped and not signal.capped:
        tree.context.record(
            "error",
            node=root.name,
            reason=f"the tree kept waking itself up: {max_reticks} re-ticks in one tick, "
            "the next tick goes on (BT.CPP's tickOnce would not have returned yet)",
        )
    signal.capped = capped
    return Ticked(
        status=root.status,
        skipped=bool(getattr(root, "skipped", False)),
        reticks=reticks,
        capped=capped,
        reached=frozenset(reached) if reached is not None else None,
    )
