"""BehaviorTree.CPP 4 Switch2..Switch6, ParallelAll and TryCatch."""

from __future__ import annotations

import math
from typing import Any

import py_trees
from py_trees.blackboard import Blackboard

from canguard.bt.nodes.base import (
    FAILURE,
    INVALID,
    RUNNING,
    SKIPPED,
    SUCCESS,
    CanguardNode,
    Children,
    PortError,
    count_of,
    end_as,
    follow,
    halt_running,
    halted,
    node_types,
    outcome,
    port_info,
    reset,
    tick_child,
)
from canguard.bt.scopes import INT_TEXT, REAL_TEXT


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

    def __init_subclass__(cls, **kwargs: Any) -> None:
        ports = {"variable": port_info(str, "the value to compare with the cases (usually {key})")}
        for i in range(1, cls.CASES + 1):
            ports[f"case_{i}"] = port_info(str, f"the value that selects child {i}", required=False)
        cls.INPUT_PORTS = ports
        cls.DESCRIPTION = (f"ticks the child of the first case_1..case_{cls.CASES} equal to variable "
                           f"(as text or number), else the last (default) child; a change halts the running one")
        super().__init_subclass__(**kwargs)

    def __init__(self, name: str, children: Children = None, **kwargs: Any) -> None:
        super().__init__(name=name, children=children, **kwargs)
        self.running = -1

    def bind(self) -> None:
        want = self.CASES + 1
        if len(self.children) != want:
            raise PortError("children", f"{type(self).__name__} needs {want} children ({self.CASES} cases + "
                                        f"default), has {len(self.children)}")

    def variable(self) -> str | None:
        """The variable as text; None when it is wired to an entry that holds nothing."""
        value = self.port("variable")
        if value is None and self.is_wired("variable"):
            value = Blackboard.storage.get(self._keys["variable"])  # any type: compared as text
        return None if value is None else _text(value)

    def match(self) -> int:
        """The child to tick: the first matching case, else the default (last)."""
        variable = self.variable()
        if variable is not None:
            for i in range(self.CASES):
                case = self.port(f"case_{i + 1}")
                if case is not None and same_case(variable, _text(case)):
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
        halt_running(self.children)
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

    def threshold(self) -> int:
        return count_of(self, "max_failures", 1)

    def bind(self) -> None:
        if not self.is_wired("max_failures") and self.threshold() > len(self.children):
            raise PortError("max_failures", f"{self.threshold()} failures needed but only "
                                            f"{len(self.children)} children: can never fail")

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
        yield end_as(self, FAILURE if failures >= self.threshold() else SUCCESS)

    def stop(self, new_status: py_trees.common.Status = INVALID) -> None:
        halt_running(self.children)
        if new_status == INVALID:
            self.finished.clear()
        super().stop(new_status)


class TryCatch(CanguardNode, py_trees.composites.Composite):
    """ticks all but the last child as a Sequence (SUCCESS when all succeed); when one fails, the last (catch) child
    runs to its end and TryCatch fails; catch_on_halt: a halt runs it too"""

    INPUT_PORTS = {  # noqa: RUF012
        "catch_on_halt": port_info(bool, "when halted while trying, tick the catch child once", False),
    }

    def __init__(self, name: str, children: Children = None, **kwargs: Any) -> None:
        super().__init__(name=name, children=children, **kwargs)
        self.index = 0
        self.in_catch = False
        self.skipped_count = 0

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
            halt_running(self.children[:-1])
            for _ in self.children[-1].tick():
                pass
        halt_running(self.children)
        self.index, self.in_catch = 0, False
        super().stop(new_status)

