"""More of BehaviorTree.CPP 4's built-in nodes: Always*, scripts, Set/UnsetBlackboard, Sleep, branches.

A script that fails while it runs fails its node (BT.CPP throws; a guard daemon must not crash
on a tree's script).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import py_trees
from py_trees.blackboard import Blackboard

from canguard.bt.nodes.base import (
    FAILURE,
    INVALID,
    RUNNING,
    SKIPPED,
    STATUS_NAMES,
    SUCCESS,
    CanguardNode,
    Children,
    DecoratorNode,
    PortError,
    Status,
    end_as,
    follow,
    halt_running,
    node_types,
    outcome,
    port_info,
    run_script,
    tick_child,
)
from canguard.bt.scopes import TreeBlackboard
from canguard.bt.scripting import ScriptError

if TYPE_CHECKING:
    from canguard.bt.scripting import Script as ParsedScript

_NOTHING = object()


class _Scripted(CanguardNode):
    """A node with scripts in ports: parsed at bind, run against its subtree's blackboard."""

    SCRIPT_PORTS: tuple[str, ...] = ()
    USES_BOARD = True

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.scripts: dict[str, ParsedScript] = {}
        self.board = TreeBlackboard("/")

    def bind(self) -> None:
        from canguard.bt.scripting import parse  # the language: only for trees with scripts

        for name in self.SCRIPT_PORTS:
            text = self.port(name)
            if text is None:
                continue
            try:
                self.scripts[name] = parse(str(text))
            except ScriptError as exc:
                raise PortError(name, f"script {text!r}: {exc}") from None

    def run_script(self, name: str, *, condition: bool = False) -> object:
        """Run script ``name`` (see :func:`.base.run_script`)."""
        return run_script(self, name, self.scripts[name], self.board, condition=condition)


class _Always(CanguardNode, py_trees.behaviour.Behaviour):
    """BT.CPP AlwaysSuccess / AlwaysFailure: ``RESULT``."""

    QUIET_RETICK = True
    RESULT: ClassVar[Status]

    def update(self) -> py_trees.common.Status:
        return self.RESULT


AlwaysSuccess, AlwaysFailure = node_types(_Always, __name__, {
    "AlwaysSuccess": {"RESULT": SUCCESS, "DESCRIPTION": "SUCCESS"},
    "AlwaysFailure": {"RESULT": FAILURE, "DESCRIPTION": "FAILURE"}})


class _Code(_Scripted, py_trees.behaviour.Behaviour):
    """BT.CPP Script / ScriptCondition: runs ``code``; FAILURE when it fails at run time (or a condition is false)."""

    SCRIPT_PORTS = ("code",)

    def update(self) -> py_trees.common.Status:
        condition = self.KIND == "Condition"
        try:
            value = self.run_script("code", condition=condition)
        except ScriptError:
            return FAILURE
        return SUCCESS if value or not condition else FAILURE


_CODE = {"Script": "the script, e.g. count := count + 1", "ScriptCondition": "a boolean expression, e.g. battery > 20"}
Script, ScriptCondition = node_types(_Code, __name__, {
    "Script": {"INPUT_PORTS": {"code": port_info(str, _CODE["Script"])}, "DESCRIPTION": (
        "runs code (BT.CPP scripting) on the blackboard: SUCCESS (FAILURE if it fails at run time)")},
    "ScriptCondition": {"KIND": "Condition", "INPUT_PORTS": {"code": port_info(str, _CODE["ScriptCondition"])},
                        "DESCRIPTION": "SUCCESS when code (BT.CPP scripting) is true, else FAILURE"}})


class SetBlackboard(_Scripted, py_trees.behaviour.Behaviour):
    """writes value into the blackboard entry named by output_key: SUCCESS"""

    UNTYPED_PORTS = frozenset({"value", "output_key"})  # BT.CPP: AnyTypeAllowed
    INPUT_PORTS = {  # noqa: RUF012
        "value": port_info(str, "the value (text, as in BT.CPP), or {key} to copy an entry"),
        "output_key": port_info(str, "the name of the entry to write"),
    }

    def update(self) -> py_trees.common.Status:
        key = self.port("output_key")
        # value="{src}": BT.CPP copies the source entry's value, with its type
        wired = self.is_wired("value")
        value = Blackboard.storage.get(self._keys["value"], _NOTHING) if wired else self.port("value")
        if not key or value is None or value is _NOTHING:
            self.feedback_message = "no output_key or no value (the entry value names does not exist)"
            return FAILURE
        name = str(key).strip("{}")
        if not wired and self.board.has(name):  # BT.CPP: text into a typed entry is parsed to its type
            from canguard.bt.scripting.script import convert_for_entry, entry_type

            try:
                target: type | None = entry_type(self.board.get(name))
            except KeyError:  # declared by a typed port, no value yet
                target = self.board.declared_type(name)
            if target is not None and target is not str:
                try:
                    value = convert_for_entry(value, target, None)
                except ValueError as exc:
                    self.feedback_message = f"can't convert {value!r} for the entry [{name}]: {exc}"
                    return FAILURE
        self.board.set(name, value)
        return SUCCESS


class UnsetBlackboard(_Scripted, py_trees.behaviour.Behaviour):
    """removes the blackboard entry key: SUCCESS"""

    UNTYPED_PORTS = frozenset({"key"})
    INPUT_PORTS = {"key": port_info(str, "the entry to remove")}  # noqa: RUF012

    def update(self) -> py_trees.common.Status:
        key = self.port("key")
        if key:
            self.board.unset(str(key))
        return SUCCESS


class Sleep(CanguardNode, py_trees.behaviour.Behaviour):
    """RUNNING until msec have elapsed (the engine's clock), then SUCCESS"""

    INPUT_PORTS = {"msec": port_info(float, "how long (ms)")}  # noqa: RUF012

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.until: float | None = None

    def initialise(self) -> None:
        msec = self.port("msec") or 0.0
        self.until = self.ctx.clock.now() + msec / 1000.0
        if msec > 0:  # BT.CPP: its timer wakes the tree up when it expires
            self.arm_timer(self.until)

    def update(self) -> py_trees.common.Status:
        if self.until is None or self.ctx.clock.now() >= self.until:
            return SUCCESS
        return RUNNING

    def terminate(self, new_status: py_trees.common.Status) -> None:
        self.until = None if new_status == INVALID else self.until
        self.cancel_timer()


class KeepRunningUntilFailure(DecoratorNode):
    """the child's SUCCESS becomes RUNNING (it is ticked again next time); FAILURE ends it"""

    SKIP_THROUGH = False  # BT.CPP: a skipped child leaves it RUNNING

    def update(self) -> py_trees.common.Status:
        status = self.decorated.status
        return RUNNING if status in (SUCCESS, INVALID) else status


class Precondition(_Scripted, DecoratorNode):
    """ticks the child when the script if is true (and while it runs); else returns else"""

    INPUT_PORTS = {  # noqa: RUF012
        "if": port_info(str, "the condition (BT.CPP scripting)"),
        "else": port_info(str, "status when the condition is false: FAILURE, SUCCESS, RUNNING or SKIPPED",
                          "FAILURE"),
    }
    SCRIPT_PORTS = ("if",)

    def bind(self) -> None:
        super().bind()
        if str(self.port("else")).upper() not in STATUS_NAMES:
            raise PortError("else", f"{self.port('else')!r}: expected SUCCESS, FAILURE, RUNNING or SKIPPED")

    def tick(self) -> Any:
        if self.status != RUNNING or self.decorated.status != RUNNING:
            try:
                ok = bool(self.run_script("if", condition=True))
            except ScriptError:
                ok = False
            if not ok:
                yield end_as(self, str(self.port("else")).upper())
                return
        yield from py_trees.decorators.Decorator.tick(self)  # the plain tick: this one is already skip-aware


class _Branching(CanguardNode, py_trees.composites.Composite):
    """IfThenElse / WhileDoElse: the first child decides, the second or third runs."""

    REACTIVE = False

    def __init__(self, name: str, children: Children = None, **kwargs: Any) -> None:
        super().__init__(name=name, children=children, **kwargs)
        self.branch = 0

    def bind(self) -> None:
        if len(self.children) not in (2, 3):  # BT.CPP: both take 2 or 3 (without a third, a FAILURE fails)
            raise PortError("children", f"{type(self).__name__} needs 2 or 3 children, has {len(self.children)}")

    def tick(self) -> Any:
        if self.status != RUNNING:
            self.branch = 0
            self.initialise()
        if self.branch == 0 or self.REACTIVE:
            cond = self.children[0]
            yield from tick_child(cond)
            if outcome(cond) == SKIPPED:  # BT.CPP throws here too: a skipped condition decides nothing
                raise RuntimeError(f"{type(self).__name__} {self.name}: its condition (first child) was skipped")
            if cond.status == RUNNING:
                yield end_as(self, RUNNING)
                return
            branch = 1 if cond.status == SUCCESS else 2
            if self.branch and branch != self.branch and self.children[self.branch].status == RUNNING:
                self.children[self.branch].stop(INVALID)  # WhileDoElse: the condition changed
            self.branch = branch
        if self.branch >= len(self.children):
            yield end_as(self, FAILURE)
            return
        yield from follow(self, self.children[self.branch])  # BT.CPP returns the branch's status, SKIPPED too

    def stop(self, new_status: py_trees.common.Status = INVALID) -> None:
        halt_running(self.children)
        super().stop(new_status)


IfThenElse, WhileDoElse = node_types(_Branching, __name__, {
    "IfThenElse": {"DESCRIPTION": "first child decides: SUCCESS ticks the second, FAILURE the third (or fails); "
                                  "not re-checked"},
    "WhileDoElse": {"REACTIVE": True, "DESCRIPTION": "like IfThenElse, but the first child is ticked every time: "
                                                     "a change halts the running branch"}})

