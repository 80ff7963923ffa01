"""BehaviorTree.CPP 4's RunOnce and the entry-update nodes: WasEntryUpdated, SkipUnlessUpdated, WaitValueUpdate.

The entry-update nodes ask whether an entry was *written* since they last looked (BT.CPP's
``sequence_id``: the same value again counts). py_trees keeps no such counter, so
:func:`versioned_storage` puts a dict counting writes per key in place of ``Blackboard.storage``.
"""

from __future__ import annotations

from typing import Any

import py_trees
from py_trees.blackboard import Blackboard

from canguard.bt.nodes.base import (
    FAILURE,
    RUNNING,
    SKIPPED,
    SUCCESS,
    CanguardNode,
    DecoratorNode,
    end_as,
    node_types,
    port_info,
)


class _Versioned(dict[str, Any]):
    """A dict that counts the writes of each key (``versions``): BT.CPP's entry ``sequence_id``."""

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self.versions: dict[str, int] = dict.fromkeys(self, 1)

    def __setitem__(self, key: str, value: Any) -> None:
        super().__setitem__(key, value)
        self.versions[key] = self.versions.get(key, 0) + 1

    def setdefault(self, key: str, default: Any = None) -> Any:
        if key not in self:
            self[key] = default
        return self[key]

    def update(self, *args: Any, **kwargs: Any) -> None:
        for key, value in dict(*args, **kwargs).items():
            self[key] = value

    def clear(self) -> None:
        super().clear()
        self.versions.clear()


def versioned_storage() -> _Versioned:
    """``Blackboard.storage`` as a :class:`_Versioned` dict (installed at the first look; the entries kept)."""
    storage = Blackboard.storage
    if not isinstance(storage, _Versioned):
        storage = _Versioned(storage)
        Blackboard.storage = storage
    return storage


def _updated(node: WasEntryUpdated | _EntryUpdated) -> bool:
    """Whether the node's ``entry`` was written since it last looked (now: ``seen`` takes the write count)."""
    storage = versioned_storage()
    key = node.wired_keys().get("entry")
    if key is None:
        name = str(node.port("entry") or "").strip().strip("{}")
        namespace = getattr(node, "_subtree_namespace", None) or "/"
        key = name if name.startswith("/") else namespace.rstrip("/") + "/" + name
    if key not in storage:
        return False
    current = storage.versions.get(key, 1)
    updated, node.seen = current != node.seen, current
    return updated


_ENTRY = {"entry": port_info(str, "the blackboard entry to watch ({key} or key)")}


class WasEntryUpdated(CanguardNode, py_trees.behaviour.Behaviour):
    """SUCCESS when the entry was written since the last tick of this node (same value too)"""

    KIND = "Condition"
    INPUT_PORTS = dict(_ENTRY)  # noqa: RUF012
    UNTYPED_PORTS = frozenset({"entry"})  # BT.CPP: InputPort<BT::Any>

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name=name, **kwargs)
        self.seen = 0

    def update(self) -> py_trees.common.Status:
        return SUCCESS if _updated(self) else FAILURE


class _EntryUpdated(DecoratorNode):
    """BT.CPP's EntryUpdatedDecorator: the child ticks only after ``entry`` was written."""

    INPUT_PORTS = dict(_ENTRY)  # noqa: RUF012
    UNTYPED_PORTS = frozenset({"entry"})  # BT.CPP: InputPort<BT::Any>
    IF_NOT_UPDATED: str = "SKIPPED"

    def __init__(self, name: str, child: py_trees.behaviour.Behaviour, **kwargs: Any) -> None:
        super().__init__(name=name, child=child, **kwargs)
        self.seen = 0
        self.still_running = False

    def tick(self) -> Any:
        if not self.still_running and not _updated(self):
            yield end_as(self, self.IF_NOT_UPDATED)
            return
        yield from py_trees.decorators.Decorator.tick(self)  # the plain tick: this one is already skip-aware
        self.still_running = self.status == RUNNING

    def terminate(self, new_status: py_trees.common.Status) -> None:
        if new_status == py_trees.common.Status.INVALID:
            self.still_running = False


SkipUnlessUpdated, WaitValueUpdate = node_types(_EntryUpdated, __name__, {
    "SkipUnlessUpdated": {
        "DESCRIPTION": "ticks the child when the entry was written since the last look, else SKIPPED"},
    "WaitValueUpdate": {"IF_NOT_UPDATED": "RUNNING", "DESCRIPTION": (
        "RUNNING until the entry is written (since the last look), then ticks the child")}})


class RunOnce(DecoratorNode):
    """runs the child once; afterwards SKIPPED (then_skip=true) or the child's first result"""

    INPUT_PORTS = {  # noqa: RUF012
        "then_skip": port_info(bool, "after the first run: true = SKIPPED, false = the status it returned", True),
    }

    def __init__(self, name: str, child: py_trees.behaviour.Behaviour, **kwargs: Any) -> None:
        super().__init__(name=name, child=child, **kwargs)
        self.returned: py_trees.common.Status | None = None  # the first completed status; kept across halts

    def tick(self) -> Any:
        if self.returned is not None:
            yield end_as(self, self.returned if self.port("then_skip") is False else SKIPPED)
            return
        yield from py_trees.decorators.Decorator.tick(self)  # the plain tick: this one is already skip-aware

    def update(self) -> py_trees.common.Status:
        status = self.decorated.status
        if status in (SUCCESS, FAILURE):
            self.returned = status
        return status

