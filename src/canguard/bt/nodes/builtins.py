"""BehaviorTree.CPP 4's built-in nodes that canguard's own trees do not use (imported for a tree that does):
Always*, scripts, Set/UnsetBlackboard, Sleep, branches, Switch2..6, ParallelAll, TryCatch, Loop*, RunOnce and
the entry-update nodes. A script that fails while it runs fails its node (BT.CPP throws; a guard daemon must
not crash on a tree's script).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, ClassVar

import py_trees
from py_trees.blackboard import Blackboard

from canguard.bt.nodes.base import (
    BOOL_TEXT,
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
    count_of,
    end_as,
    follow,
    halted,
    node_types,
    outcome,
    port_info,
    reset,
    run_script,
    tick_child,
)
from canguard.bt.scopes import INT_TEXT, REAL_TEXT
from canguard.bt.scripting import ScriptError
from canguard.bt.scripting.script import Script as ParsedScript
from canguard.bt.scripting.script import convert_for_entry, entry_type

_NOTHING = object()


class _Scripted(CanguardNode):
    """A node with scripts in ports: parsed at bind, run against its subtree's blackboard."""

    SCRIPT_PORTS: tuple[str, ...] = ()
    scripts: dict[str, ParsedScript]  # by port

    def bind(self) -> None:
        self.scripts = {}
        for name in self.SCRIPT_PORTS:
            text = self.port(name)
            if text is None:
                continue
            try:
                self.scripts[name] = ParsedScript(str(text))
            except ScriptError as exc:
                raise PortError(name, f"script {text!r}: {exc}") from None


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
            value = run_script(self, "code", self.scripts["code"], self.board, condition=condition)
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
            try:
                target: type | None = entry_type(self.board.get(name))
            except KeyError:  # declared by a typed port, no value yet
                target = self.board.declared_type(name)
            if target is not None and target is not str:
                try:
                    value = convert_for_entry(value, target)
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
    until: float | None = None

    def initialise(self) -> None:
        msec = self.port("msec") or 0.0
        self.until = self.ctx.clock.now() + msec / 1000.0
        if msec > 0:  # BT.CPP: its timer wakes the tree up when it expires
            self.wake_up.arm(self, self.until)

    def update(self) -> py_trees.common.Status:
        return SUCCESS if self.until is None or self.ctx.clock.now() >= self.until else RUNNING

    def terminate(self, new_status: py_trees.common.Status) -> None:
        self.until = None if new_status == INVALID else self.until
        self.wake_up.cancel(self)


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
                ok = bool(run_script(self, "if", self.scripts["if"], self.board, condition=True))
            except ScriptError:
                ok = False
            if not ok:
                yield end_as(self, str(self.port("else")).upper())
                return
        yield from py_trees.decorators.Decorator.tick(self)  # the plain tick: this one is already skip-aware


class _Branching(CanguardNode, py_trees.composites.Composite):
    """IfThenElse / WhileDoElse: the first child decides, the second or third runs."""

    REACTIVE = False
    branch = 0

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


IfThenElse, WhileDoElse = node_types(_Branching, __name__, {
    "IfThenElse": {"DESCRIPTION": "first child decides: SUCCESS ticks the second, FAILURE the third (or fails); "
                                  "not re-checked"},
    "WhileDoElse": {"REACTIVE": True, "DESCRIPTION": "like IfThenElse, but the first child is ticked every time: "
                                                     "a change halts the running branch"}})


def _text(value: object) -> str:
    """A blackboard value as BT.CPP would read it into a string port."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:f}"  # std::to_string
    return str(value)


def same_case(variable: str, case: str) -> bool:
    """BT.CPP's switch comparison: equal text, or equal as integers, or equal as reals."""
    if variable == case:
        return True
    if INT_TEXT.match(variable) and INT_TEXT.match(case):
        return int(variable) == int(case)
    if REAL_TEXT.match(variable) and REAL_TEXT.match(case):
        return math.isclose(float(variable), float(case), rel_tol=0.0, abs_tol=0.0)
    return False


class _Switch(CanguardNode, py_trees.composites.Composite):
    """Switch with ``CASES`` cases and a default child."""

    CASES = 0
    running = -1

    def __init_subclass__(cls, **kwargs: Any) -> None:
        ports = {"variable": port_info(str, "the value to compare with the cases (usually {key})")}
        for i in range(1, cls.CASES + 1):
            ports[f"case_{i}"] = port_info(str, f"the value that selects child {i}", required=False)
        cls.INPUT_PORTS = ports
        cls.DESCRIPTION = (f"ticks the child of the first case_1..case_{cls.CASES} equal to variable "
                           f"(as text or number), else the last (default) child; a change halts the running one")
        super().__init_subclass__(**kwargs)

    def bind(self) -> None:
        want = self.CASES + 1
        if len(self.children) != want:
            raise PortError("children", f"{type(self).__name__} needs {want} children ({self.CASES} cases + "
                                        f"default), has {len(self.children)}")

    def match(self) -> int:
        """The child to tick: the first case equal to the variable, else the default (last)."""
        variable = self.port("variable")
        if variable is None and self.is_wired("variable"):
            variable = Blackboard.storage.get(self._keys["variable"])  # any type: compared as text
        for i in range(self.CASES if variable is not None else 0):
            case = self.port(f"case_{i + 1}")
            if case is not None and same_case(_text(variable), _text(case)):
                return i
        return self.CASES

    def tick(self) -> Any:
        if self.status != RUNNING:
            self.running = -1
            self.initialise()
        index = self.match()
        if self.running not in (-1, index):
            self.children[self.running].stop(INVALID)
        yield from follow(self, self.children[index])  # BT.CPP: the matching child skipped, the switch too
        self.running = index if self.status == RUNNING else -1

    def stop(self, new_status: py_trees.common.Status = INVALID) -> None:
        self.running = -1
        super().stop(new_status)


Switch2, Switch3, Switch4, Switch5, Switch6 = node_types(
    _Switch, __name__, {f"Switch{n}": {"CASES": n} for n in range(2, 7)})


class ParallelAll(CanguardNode, py_trees.composites.Composite):
    """ticks every unfinished child each tick until all have finished; then FAILURE when at least max_failures failed
    (negative: children + 1 + n), else SUCCESS"""

    INPUT_PORTS = {  # noqa: RUF012
        "max_failures": port_info(int, "failures that make it fail (negative: children + 1 + n, -1 = all)", 1),
    }

    def __init__(self, name: str, children: Children = None, **kwargs: Any) -> None:
        super().__init__(name=name, children=children, **kwargs)
        self.finished: dict[int, py_trees.common.Status] = {}

    def bind(self) -> None:
        needed = count_of(self, "max_failures", 1)
        if not self.is_wired("max_failures") and needed > len(self.children):
            raise PortError("max_failures", f"{needed} failures needed but only {len(self.children)} children: can "
                                            "never fail")

    def tick(self) -> Any:
        if self.status != RUNNING:
            reset(self.children)
            self.finished.clear()
            self.initialise()
        skipped = 0
        for index, child in enumerate(self.children):
            if index in self.finished:
                continue
            self.current_child = child
            yield from tick_child(child)
            if outcome(child) == SKIPPED:
                skipped += 1
            elif child.status in (SUCCESS, FAILURE):
                self.finished[index] = child.status
        if skipped + len(self.finished) < len(self.children):  # BT.CPP: all skipped, the parallel too
            yield end_as(self, SKIPPED if skipped == len(self.children) else RUNNING)
            return
        failures = sum(1 for s in self.finished.values() if s == FAILURE)
        self.finished.clear()
        yield end_as(self, FAILURE if failures >= count_of(self, "max_failures", 1) else SUCCESS)

    def stop(self, new_status: py_trees.common.Status = INVALID) -> None:
        if new_status == INVALID:
            self.finished.clear()
        super().stop(new_status)


class TryCatch(CanguardNode, py_trees.composites.Composite):
    """ticks all but the last child as a Sequence (SUCCESS when all succeed); when one fails, the last (catch) child
    runs to its end and TryCatch fails; catch_on_halt: a halt runs it too"""

    INPUT_PORTS = {  # noqa: RUF012
        "catch_on_halt": port_info(bool, "when halted while trying, tick the catch child once", False),
    }
    index = 0
    in_catch = False
    skipped_count = 0

    def bind(self) -> None:
        if len(self.children) < 2:
            raise PortError("children", f"TryCatch needs at least 2 children, has {len(self.children)}")

    def tick(self) -> Any:
        if self.status != RUNNING:
            self.index, self.in_catch = 0, False
            self.initialise()
        tries = self.children[:-1]
        if self.index == 0:
            self.skipped_count = 0
        while not self.in_catch and self.index < len(tries):
            child = tries[self.index]
            self.current_child = child
            yield from tick_child(child)
            if outcome(child) == SKIPPED:
                self.index += 1
                self.skipped_count += 1
                continue
            if child.status == RUNNING:
                yield end_as(self, RUNNING)
                return
            if child.status == FAILURE:
                self.in_catch = True
                reset(tries)
            else:
                self.index += 1
        if not self.in_catch:
            all_skipped = self.skipped_count == len(tries)  # BT.CPP: every try skipped
            if all_skipped:
                self.index = 0
            yield end_as(self, SKIPPED if all_skipped else SUCCESS)
            return
        catch = self.children[-1]
        self.current_child = catch
        yield from catch.tick()
        yield end_as(self, RUNNING if catch.status == RUNNING else FAILURE)

    def stop(self, new_status: py_trees.common.Status = INVALID) -> None:
        if halted(self, new_status) and not self.in_catch and self.port("catch_on_halt"):
            for child in self.children[:-1]:  # the running try halted, then the catch child ticked once
                if child.status == RUNNING:
                    child.stop(INVALID)
            for _ in self.children[-1].tick():
                pass
        self.index, self.in_catch = 0, False
        super().stop(new_status)


def _to_bool(text: str) -> bool:
    try:
        return BOOL_TEXT[text.strip().lower()]
    except KeyError:
        raise ValueError(f"{text!r} is not a bool (true/false/1/0)") from None


class _Loop(DecoratorNode):
    """A loop over a queue of ``ITEM`` values: a constant "1;2;3" (parsed at load), an entry holding a list
    (consumed in place, as BT.CPP's shared queue) or such a string (parsed when the run starts)."""

    ITEM: type = str
    CHOICES = {"if_empty": ("SUCCESS", "FAILURE", "SKIPPED")}  # noqa: RUF012
    SKIP_THROUGH = False  # BT.CPP's loop_node.h: a skipped child leaves the loop RUNNING
    UNTYPED_PORTS = frozenset({"queue"})  # BT.CPP: an untyped BidirectionalPort (a list, a vector or a string)
    static: list[Any] | None = None
    queue: list[Any] | deque[Any] | None = None
    child_running = False

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

    def _take(self) -> Any:
        """The next element, or ``_NOTHING`` when there is none."""
        if self.static is None:
            raw = Blackboard.storage.get(self._keys["queue"])
            if isinstance(raw, list | deque):
                self.queue = raw  # shared: the loop consumes the entry itself
            elif isinstance(raw, str) and self.queue is None:
                self.queue = self.parse(raw)
            elif raw is None or not isinstance(raw, str):
                raise ValueError(f"queue holds {raw!r}: expected a list or a ';'-separated string")
        if not self.queue:
            return _NOTHING
        return self.queue.popleft() if isinstance(self.queue, deque) else self.queue.pop(0)

    def tick(self) -> Any:
        if self.status != RUNNING:
            self.child_running = False
            self.queue = None if self.static is None else list(self.static)
            self.initialise()
        if not self.child_running:
            try:
                item = self._take()
            except ValueError as exc:  # BT.CPP throws; the guard fails this node and says why
                self.feedback_message = str(exc)
                yield end_as(self, FAILURE)
                return
            if item is _NOTHING:
                yield end_as(self, str(self.port("if_empty")).upper())
                return
            self.write("value", item)
        child = self.decorated
        yield from child.tick()
        self.child_running = child.status == RUNNING
        yield end_as(self, FAILURE if child.status == FAILURE else RUNNING)


LoopInt, LoopDouble, LoopString, LoopBool = node_types(_Loop, __name__, {
    "LoopInt": {"ITEM": int}, "LoopDouble": {"ITEM": float}, "LoopString": {"ITEM": str}, "LoopBool": {"ITEM": bool}})


class _Versioned(dict[str, Any]):
    """A dict that counts the writes of each key (``versions``): BT.CPP's entry ``sequence_id``, which py_trees
    lacks (the same value written again counts)."""

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self.versions: dict[str, int] = dict.fromkeys(self, 1)

    def __setitem__(self, key: str, value: Any) -> None:
        super().__setitem__(key, value)
        self.versions[key] = self.versions.get(key, 0) + 1

    def update(self, *args: Any, **kwargs: Any) -> None:
        for key, value in dict(*args, **kwargs).items():
            self[key] = value

    def clear(self) -> None:
        super().clear()
        self.versions.clear()


def _updated(node: WasEntryUpdated | _EntryUpdated) -> bool:
    """Whether the node's ``entry`` was written since it last looked (now: ``seen`` takes the write count)."""
    storage = Blackboard.storage
    if not isinstance(storage, _Versioned):  # installed at the first look, the entries kept
        storage = Blackboard.storage = _Versioned(storage)
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
    seen = 0

    def update(self) -> py_trees.common.Status:
        return SUCCESS if _updated(self) else FAILURE


class _EntryUpdated(DecoratorNode):
    """BT.CPP's EntryUpdatedDecorator: the child ticks only after ``entry`` was written."""

    INPUT_PORTS = dict(_ENTRY)  # noqa: RUF012
    UNTYPED_PORTS = frozenset({"entry"})  # BT.CPP: InputPort<BT::Any>
    IF_NOT_UPDATED: str = "SKIPPED"
    seen = 0
    still_running = False

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
    returned: py_trees.common.Status | None = None  # the first completed status; kept across halts

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
