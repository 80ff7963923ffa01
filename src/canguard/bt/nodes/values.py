"""IsValueBelow / IsValueAbove: compare a blackboard value with a threshold (note 003, latency warning)."""

from __future__ import annotations

from typing import ClassVar

import py_trees

from canguard.bt.nodes.base import FAILURE, SUCCESS, CanguardNode, node_types, port_info


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
