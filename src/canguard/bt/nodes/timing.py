"""Time conditions and timer actions (design note 000), on the context's clock (docs/trees.md, "Timers"), and
IsValueBelow / IsValueAbove: a blackboard value against a threshold (note 003, latency warning)."""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Sequence
from typing import ClassVar

import py_trees
from py_trees.blackboard import Blackboard

from canguard.bt.nodes.base import FAILURE, SUCCESS, CanguardNode, PortError, node_types, port_info

OPERATORS = ("GT", "LT", "GTE", "LTE", "EQ")
REFERENCES = ("first_tick", "tree_start", "last_reset", "blackboard")


class _TimerUser(CanguardNode):
    """A node with a timer: the key wired to ``timer`` (shared), or its own (``timer_key`` None)."""

    _own_start: float | None = None  # kept across halts (note 000)

    @property
    def timer_key(self) -> str | None:
        """The storage key of the shared timer wired to ``timer``; None: the node's own."""
        return self._keys.get("timer")

    def timer_start(self) -> float | None:
        """The timer's start time (the named key's, or its own); None when not started."""
        if self.timer_key is None:
            return self._own_start
        value = Blackboard.storage.get(self.timer_key)
        return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None

    def start_timer(self, now: float) -> None:
        """(Re)start the timer at ``now``."""
        if self.timer_key is None:
            self._own_start = float(now)
        else:
            Blackboard.storage[self.timer_key] = float(now)


_COMPARE: dict[str, Callable[[float, float], bool]] = {
    "GT": operator.gt, "LT": operator.lt, "GTE": operator.ge, "LTE": operator.le}


class IsElapsedTimeCompare(_TimerUser, py_trees.behaviour.Behaviour):
    """SUCCESS when (now − reference time) <operator> reference_sec"""

    KIND = "Condition"
    INPUT_PORTS = {  # noqa: RUF012 - py_trees reads ports as plain class dicts
        "reference_sec": port_info(float, "the time to compare the elapsed time with (s)"),
        "operator": port_info(str, "GT, LT, GTE, LTE or EQ (|elapsed − reference_sec| < tolerance)", "GT"),
        "tolerance": port_info(float, "tolerance of EQ (s)", 0.1),
        "reference": port_info(str, "first_tick, tree_start, last_reset or blackboard", "first_tick"),
        "timer": port_info(float, "blackboard key holding the timer's start time (s), shared by every node naming it; "
                                  "default: the node's own timer", required=False),
    }
    CHOICES = {"operator": OPERATORS, "reference": REFERENCES}  # noqa: RUF012
    KEY_PORTS = frozenset({"timer"})

    def bind(self) -> None:
        if self.port("reference") == "blackboard" and not self.is_wired("timer"):
            raise PortError("timer", 'required with reference="blackboard" (the key holding the event time)')
        tol = self.port("tolerance")
        if tol is not None and not (tol >= 0):
            raise PortError("tolerance", f"must be >= 0, got {tol!r}")

    def update(self) -> py_trees.common.Status:
        now = self.ctx.clock.now()
        ref_mode = self.port("reference")
        if ref_mode not in REFERENCES:
            self.feedback_message = f"unknown reference {ref_mode!r}; expected one of {', '.join(REFERENCES)}"
            return FAILURE
        if ref_mode == "tree_start":
            t0 = self.ctx.tree_start
            if t0 is None:  # ticked outside the engine: this tick is the tree's start
                self.ctx.tree_start = t0 = now
        else:
            t0 = self.timer_start()
            if t0 is None and ref_mode == "first_tick":
                self.start_timer(now)
                t0 = now
            elif t0 is None:
                where = f"in {self.timer_key}" if self.timer_key else "(no reset yet by a ResetTimer)"
                self.feedback_message = f"no reference time yet {where}"
                return FAILURE
        reference = self.port("reference_sec")
        tolerance = self.port("tolerance")
        if reference is None or tolerance is None:
            self.feedback_message = f"no value for reference_sec/tolerance {self._bad_port}".rstrip()
            return FAILURE
        elapsed = now - t0
        op = self.port("operator")
        if op not in OPERATORS:
            self.feedback_message = f"unknown operator {op!r}; expected one of {', '.join(OPERATORS)}"
            return FAILURE
        ok = abs(elapsed - reference) < tolerance if op == "EQ" else _COMPARE[op](elapsed, reference)
        self.feedback_message = f"elapsed {elapsed:.3f} s {op} {reference:g} s: {ok}"
        return SUCCESS if ok else FAILURE


class IsElapsedSinceEvent(CanguardNode, py_trees.behaviour.Behaviour):
    """SUCCESS inside the time window [min_elapsed_sec, max_elapsed_sec] after event_timestamp"""

    KIND = "Condition"
    INPUT_PORTS = {  # noqa: RUF012
        "event_timestamp": port_info(float, "time of the event (s), e.g. {mission_start_time}"),
        "min_elapsed_sec": port_info(float, "window start after the event (s)", 0.0),
        "max_elapsed_sec": port_info(float, "window end after the event (s)", math.inf),
    }

    def update(self) -> py_trees.common.Status:
        event = self.port("event_timestamp")
        lo, hi = self.port("min_elapsed_sec"), self.port("max_elapsed_sec")
        if event is None or lo is None or hi is None:
            self.feedback_message = f"no event time yet {self._bad_port}".rstrip()
            return FAILURE
        elapsed = self.ctx.clock.now() - event
        self.feedback_message = f"{elapsed:.3f} s since the event, window [{lo:g}, {hi:g}]"
        return SUCCESS if lo <= elapsed <= hi else FAILURE


class IsCooldownElapsed(CanguardNode, py_trees.behaviour.Behaviour):
    """SUCCESS when the action never ran (time absent or <= 0) or cooldown_sec have passed"""

    KIND = "Condition"
    INPUT_PORTS = {  # noqa: RUF012
        "cooldown_sec": port_info(float, "minimum time between two executions (s)", 5.0),
        "last_execution_time": port_info(float, "time of the last execution (s), e.g. {last_recovery_time}", 0.0),
    }

    def update(self) -> py_trees.common.Status:
        last = self.port("last_execution_time")
        cooldown = self.port("cooldown_sec")
        if last is None or last <= 0.0:
            self.feedback_message = "never executed"
            return SUCCESS
        if cooldown is None:
            self.feedback_message = f"no cooldown value {self._bad_port}".rstrip()
            return FAILURE
        elapsed = self.ctx.clock.now() - last
        self.feedback_message = f"{elapsed:.3f} s since the last execution (cooldown {cooldown:g} s)"
        return SUCCESS if elapsed >= cooldown else FAILURE


class ResetTimer(_TimerUser, py_trees.behaviour.Behaviour):
    """restart a timer: write now to its key (default: the nearest comparisons' own timers)"""

    OUTPUT_PORTS = {  # noqa: RUF012
        "timer": port_info(float, "blackboard key of the timer to restart; default: the own timers of the "
                                  "IsElapsedTimeCompare nodes without timer under this node's closest ancestor that "
                                  "has any", required=False),
    }
    targets: Sequence[IsElapsedTimeCompare] = ()  # whose own timers it restarts (no timer port)

    def bind(self) -> None:
        if self.timer_key is not None:
            return
        ancestor = self.parent
        while ancestor is not None:
            found = [n for n in ancestor.iterate() if isinstance(n, IsElapsedTimeCompare) and n.timer_key is None]
            if found:
                self.targets = found
                return
            ancestor = ancestor.parent
        raise PortError("timer", "no IsElapsedTimeCompare without a timer port in this tree to restart; "
                                 'name the timer to restart (timer="{key}", the same key as the comparison\'s)')

    def update(self) -> py_trees.common.Status:
        now = self.ctx.clock.now()
        if self.timer_key is not None:
            self.start_timer(now)
            self.feedback_message = f"timer {self.timer_key} = {now:.3f}"
        else:
            for node in self.targets:
                node.start_timer(now)
            self.feedback_message = f"timers of {', '.join(n.name for n in self.targets)} = {now:.3f}"
        return SUCCESS


class RecordTime(CanguardNode, py_trees.behaviour.Behaviour):
    """write the current time (s) to output_time"""

    OUTPUT_PORTS = {  # noqa: RUF012
        "output_time": port_info(float, "blackboard key that receives the current time (s)"),
    }

    def update(self) -> py_trees.common.Status:
        self.write("output_time", float(self.ctx.clock.now()))
        return SUCCESS


class _Compare(CanguardNode, py_trees.behaviour.Behaviour):
    """``value <SYMBOL> threshold``."""

    KIND = "Condition"
    INPUT_PORTS = {  # noqa: RUF012 - py_trees reads ports as plain class dicts
        "value": port_info(float, "the value to check, usually a {key}"),
        "threshold": port_info(float, "the limit"),
    }
    SYMBOL: ClassVar[str]

    def update(self) -> py_trees.common.Status:
        value = self.port("value")
        threshold = self.port("threshold")
        if value is None or threshold is None:
            self.feedback_message = f"no value yet {self._bad_port}".rstrip()
            return FAILURE
        ok = value < threshold if self.SYMBOL == "<" else value > threshold
        self.feedback_message = f"{value:g} {self.SYMBOL} {threshold:g}: {ok}"
        return SUCCESS if ok else FAILURE


IsValueBelow, IsValueAbove = node_types(_Compare, __name__, {
    "IsValueBelow": {"SYMBOL": "<", "DESCRIPTION": "SUCCESS when value < threshold"},
    "IsValueAbove": {"SYMBOL": ">", "DESCRIPTION": "SUCCESS when value > threshold"}})
