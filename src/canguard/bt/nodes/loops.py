"""BehaviorTree.CPP 4 LoopInt / LoopDouble / LoopString / LoopBool (``loop_node.h``).

``queue`` is a constant "1;2;3" (parsed at load), or an entry holding a list (consumed in place,
as BT.CPP's shared queue is) or such a string (parsed when the run starts).
"""

from __future__ import annotations

from collections import deque
from typing import Any

from py_trees.blackboard import Blackboard

from canguard.bt.nodes.base import (
    BOOL_TEXT,
    FAILURE,
    RUNNING,
    DecoratorNode,
    PortError,
    end_as,
    node_types,
    port_info,
)


def _to_bool(text: str) -> bool:
    try:
        return BOOL_TEXT[text.strip().lower()]
    except KeyError:
        raise ValueError(f"{text!r} is not a bool (true/false/1/0)") from None


class _Loop(DecoratorNode):
    """A loop over a queue of ``ITEM`` values."""

    ITEM: type = str
    CHOICES = {"if_empty": ("SUCCESS", "FAILURE", "SKIPPED")}  # noqa: RUF012
    SKIP_THROUGH = False  # BT.CPP's loop_node.h: a skipped child leaves the loop RUNNING
    UNTYPED_PORTS = frozenset({"queue"})  # BT.CPP: an untyped BidirectionalPort (a list, a vector or a string)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        name = cls.ITEM.__name__
        cls.INPUT_PORTS = {
            "queue": port_info(str, f"values separated by ';' (e.g. 1;2;3), or {{key}} of a list of {name}"),
            "if_empty": port_info(str, "status when nothing is left to take: SUCCESS, FAILURE or SKIPPED",
                                  "SUCCESS"),
        }
        cls.OUTPUT_PORTS = {"value": port_info(cls.ITEM, "the element the child is ticked with", required=False)}
        cls.DESCRIPTION = (f"ticks the child once per element of queue ({name}), written to value; RUNNING while "
                           "elements remain, FAILURE when the child fails, if_empty when none are left")
        super().__init_subclass__(**kwargs)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.static: list[Any] | None = None
        self.queue: list[Any] | deque[Any] | None = None
        self.child_running = False

    def parse(self, text: str) -> list[Any]:
        """'1;2;3' as a list of ITEM ('' is an empty queue)."""
        if text == "":
            return []
        convert = _to_bool if self.ITEM is bool else self.ITEM
        return [convert(part) for part in text.split(";")]

    def bind(self) -> None:
        if not self.is_wired("queue"):
            try:
                self.static = self.parse(str(self.port("queue") or ""))
            except ValueError as exc:
                raise PortError("queue", f"{self.port('queue')!r}: not a list of {self.ITEM.__name__}: {exc}") from None

    def _take(self) -> tuple[bool, Any]:
        """(True, the next element), or (False, None) when there is none."""
        if self.static is None:
            raw = Blackboard.storage.get(self._keys["queue"])
            if isinstance(raw, list | deque):
                self.queue = raw  # shared: the loop consumes the entry itself
            elif isinstance(raw, str) and self.queue is None:
                self.queue = self.parse(raw)
            elif raw is None or not isinstance(raw, str):
                raise ValueError(f"queue holds {raw!r}: expected a list or a ';'-separated string")
        if not self.queue:
            return False, None
        item = self.queue.popleft() if isinstance(self.queue, deque) else self.queue.pop(0)
        return True, item

    def tick(self) -> Any:
        if self.status != RUNNING:
            self.child_running = False
            self.queue = None if self.static is None else list(self.static)
            self.initialise()
        if not self.child_running:
            try:
                taken, item = self._take()
            except ValueError as exc:  # BT.CPP throws; the guard fails this node and says why
                self.feedback_message = str(exc)
                yield end_as(self, FAILURE)
                return
            if not taken:
                yield end_as(self, str(self.port("if_empty")).upper())
                return
            self.write("value", item)
        child = self.decorated
        yield from child.tick()
        self.child_running = child.status == RUNNING
        yield end_as(self, FAILURE if child.status == FAILURE else RUNNING)


LoopInt, LoopDouble, LoopString, LoopBool = node_types(_Loop, __name__, {
    "LoopInt": {"ITEM": int}, "LoopDouble": {"ITEM": float}, "LoopString": {"ITEM": str}, "LoopBool": {"ITEM": bool}})
