"""IsValueBelow / IsValueAbove: compare a blackboard value with a threshold (note 003, latency warning).

Typical use, after a Profile decorator wrote ``{tick_time}``::

    <Condition ID="IsValueBelow" value="{tick_time}" threshold="50.0"/>

FAILURE while the value has not been written yet (or is not a number).
"""

from __future__ import annotations

import py_trees

from canguard.bt.nodes.base import FAILURE, SUCCESS, CanguardNode, port_info


class _Compare(CanguardNode, py_trees.behaviour.Behaviour):
    KIND = "Condition"
    INPUT_PORTS = {  # noqa: RUF012 - py_trees reads ports as plain class dicts
        "value": port_info(float, "the value to check, usually a {key}"),
        "threshold": port_info(float, "the limit"),
    }
    SYMBOL = "?"

    def holds(self, value: float, threshold: float) -> bool:
        raise NotImplementedError

    def update(self) -> py_trees.common.Status:
        """SUCCESS when the comparison holds; FAILURE otherwise or without a value."""
        value = self.port("value")
        threshold = self.port("threshold")
        if value is None or threshold is None:
            self.feedback_message = f"no value yet {self._bad_port}".rstrip()
            return FAILURE
        ok = self.holds(value, threshold)
        self.feedback_message = f"{value:g} {self.SYMBOL} {threshold:g}: {ok}"
        return SUCCESS if ok else FAILURE


class IsValueBelow(_Compare):
    """SUCCESS when value < threshold."""

    DESCRIPTION = "SUCCESS when value < threshold"
    SYMBOL = "<"

    def holds(self, value: float, threshold: float) -> bool:
        """value < threshold."""
        return value < threshold


class IsValueAbove(_Compare):
    """SUCCESS when value > threshold."""

    DESCRIPTION = "SUCCESS when value > threshold"
    SYMBOL = ">"

    def holds(self, value: float, threshold: float) -> bool:
        """value > threshold."""
        return value > threshold
