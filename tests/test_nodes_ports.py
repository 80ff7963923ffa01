"""Every node type declares the ports (names, directions, types, defaults) BehaviorTree.CPP users type."""

from __future__ import annotations

import importlib
import inspect
import math
import pkgutil
from typing import Any

import pytest

import canguard.bt.nodes as nodes_package
from canguard.bt.nodes import BUILTIN_NODES, CanguardNode, ConfiguredAction
from canguard.bt.nodes.base import port_table

NO = object()
"""No default: required (or optional without a default where marked)."""

# node ID -> {port: (direction, type, default)}; the list the node contracts name, plus the extras noted.
EXPECTED: dict[str, dict[str, tuple[str, type, Any]]] = {
    "IsCurrentNormal": {"topic_name": ("in", str, NO), "max_current": ("in", float, 30.0)},
    "IsJointEffortNormal": {"topic_name": ("in", str, NO), "max_effort": ("in", float, 100.0)},
    "IsCurrentSafe": {
        "topic_name": ("in", str, NO),
        "overcurrent_threshold": ("in", float, 35.0),
        "recovery_threshold": ("in", float, 25.0),
        "trip_after": ("in", float, 0.0),
        "recover_after": ("in", float, 0.0),  # extra: the recovery counterpart of trip_after
        "inrush_time": ("in", float, 0.0),
        "inrush_threshold": ("in", float, NO),
        "start_current": ("in", float, NO),
    },
    "IsI2tSafe": {
        "topic_name": ("in", str, NO),
        "model": ("in", str, "leaky"),
        "continuous_current": ("in", float, NO),
        "peak_current": ("in", float, NO),
        "peak_time": ("in", float, NO),
        "tau": ("in", float, NO),
        "tau_cool": ("in", float, NO),  # extra: cooling time constant of the thermal image
        "k": ("in", float, 1.0),
        "recover_fraction": ("in", float, 0.5),
        "level": ("out", float, NO),
    },
    "IsElapsedTimeCompare": {
        "reference_sec": ("in", float, NO),
        "operator": ("in", str, "GT"),
        "tolerance": ("in", float, 0.1),
        "reference": ("in", str, "first_tick"),
        "timer": ("in", float, NO),
    },
    "IsElapsedSinceEvent": {
        "event_timestamp": ("in", float, NO),
        "min_elapsed_sec": ("in", float, 0.0),
        "max_elapsed_sec": ("in", float, math.inf),
    },
    "IsCooldownElapsed": {"cooldown_sec": ("in", float, 5.0), "last_execution_time": ("in", float, 0.0)},
    "ResetTimer": {"timer": ("out", float, NO)},
    "RecordTime": {"output_time": ("out", float, NO)},
    "IsValueBelow": {"value": ("in", float, NO), "threshold": ("in", float, NO)},
    "IsValueAbove": {"value": ("in", float, NO), "threshold": ("in", float, NO)},
    "Profile": {
        "last_ms": ("out", float, NO),
        "avg_ms": ("out", float, NO),
        "max_ms": ("out", float, NO),
        "count": ("out", int, NO),
    },
    "ExecuteTask": {},
    "EmitStop": {},
    "ResetStop": {},
    "Sequence": {},
    "ReactiveSequence": {},
    "SequenceWithMemory": {},
    "Fallback": {},
    "ReactiveFallback": {},
    "Parallel": {"success_count": ("in", int, -1), "failure_count": ("in", int, 1)},
    "Inverter": {},
    "ForceSuccess": {},
    "ForceFailure": {},
    "RetryUntilSuccessful": {"num_attempts": ("in", int, NO)},
    "Repeat": {"num_cycles": ("in", int, NO)},
    "Timeout": {"msec": ("in", float, NO)},
    "Delay": {"delay_msec": ("in", float, NO)},
    # more BehaviorTree.CPP 4 built-ins (canguard.bt.nodes.builtins)
    "AlwaysSuccess": {},
    "AlwaysFailure": {},
    "Script": {"code": ("in", str, NO)},
    "ScriptCondition": {"code": ("in", str, NO)},
    "SetBlackboard": {"value": ("in", str, NO), "output_key": ("in", str, NO)},
    "UnsetBlackboard": {"key": ("in", str, NO)},
    "Sleep": {"msec": ("in", float, NO)},
    "KeepRunningUntilFailure": {},
    "Precondition": {"if": ("in", str, NO), "else": ("in", str, "FAILURE")},
    "IfThenElse": {},
    "WhileDoElse": {},
    "Switch2": {"variable": ("in", str, NO), **{f"case_{i}": ("in", str, NO) for i in range(1, 3)}},
    "Switch3": {"variable": ("in", str, NO), **{f"case_{i}": ("in", str, NO) for i in range(1, 4)}},
    "Switch4": {"variable": ("in", str, NO), **{f"case_{i}": ("in", str, NO) for i in range(1, 5)}},
    "Switch5": {"variable": ("in", str, NO), **{f"case_{i}": ("in", str, NO) for i in range(1, 6)}},
    "Switch6": {"variable": ("in", str, NO), **{f"case_{i}": ("in", str, NO) for i in range(1, 7)}},
    "ParallelAll": {"max_failures": ("in", int, 1)},
    "TryCatch": {"catch_on_halt": ("in", bool, False)},
    "LoopInt": {"queue": ("in", str, NO), "if_empty": ("in", str, "SUCCESS"), "value": ("out", int, NO)},
    "LoopDouble": {"queue": ("in", str, NO), "if_empty": ("in", str, "SUCCESS"), "value": ("out", float, NO)},
    "LoopString": {"queue": ("in", str, NO), "if_empty": ("in", str, "SUCCESS"), "value": ("out", str, NO)},
    "LoopBool": {"queue": ("in", str, NO), "if_empty": ("in", str, "SUCCESS"), "value": ("out", bool, NO)},
    "AsyncSequence": {},
    "AsyncFallback": {},
    "RunOnce": {"then_skip": ("in", bool, True)},
    "WasEntryUpdated": {"entry": ("in", str, NO)},
    "SkipUnlessUpdated": {"entry": ("in", str, NO)},
    "WaitValueUpdate": {"entry": ("in", str, NO)},
}

REQUIRED = {
    "IsCurrentNormal": {"topic_name"},
    "IsJointEffortNormal": {"topic_name"},
    "IsCurrentSafe": {"topic_name"},
    "IsI2tSafe": {"topic_name", "continuous_current"},
    "IsElapsedTimeCompare": {"reference_sec"},
    "IsElapsedSinceEvent": {"event_timestamp"},
    "RecordTime": {"output_time"},
    "IsValueBelow": {"value", "threshold"},
    "IsValueAbove": {"value", "threshold"},
    "RetryUntilSuccessful": {"num_attempts"},
    "Repeat": {"num_cycles"},
    "Timeout": {"msec"},
    "Delay": {"delay_msec"},
    "Script": {"code"},
    "ScriptCondition": {"code"},
    "SetBlackboard": {"value", "output_key"},
    "UnsetBlackboard": {"key"},
    "Sleep": {"msec"},
    "Precondition": {"if"},
    "Switch2": {"variable"},
    "Switch3": {"variable"},
    "Switch4": {"variable"},
    "Switch5": {"variable"},
    "Switch6": {"variable"},
    "LoopInt": {"queue"},
    "LoopDouble": {"queue"},
    "LoopString": {"queue"},
    "LoopBool": {"queue"},
    "WasEntryUpdated": {"entry"},
    "SkipUnlessUpdated": {"entry"},
    "WaitValueUpdate": {"entry"},
}

KINDS = {
    "Condition": {
        "IsCurrentNormal",
        "IsJointEffortNormal",
        "IsCurrentSafe",
        "IsI2tSafe",
        "IsElapsedTimeCompare",
        "IsElapsedSinceEvent",
        "IsCooldownElapsed",
        "IsValueBelow",
        "IsValueAbove",
        "ScriptCondition",
        "WasEntryUpdated",
    },
    "Action": {"ExecuteTask", "EmitStop", "ResetStop", "ResetTimer", "RecordTime", "AlwaysSuccess", "AlwaysFailure",
               "Script", "SetBlackboard", "UnsetBlackboard", "Sleep"},
    "Decorator": {
        "Profile",
        "Inverter",
        "ForceSuccess",
        "ForceFailure",
        "RetryUntilSuccessful",
        "Repeat",
        "Timeout",
        "Delay",
        "KeepRunningUntilFailure",
        "Precondition",
        "LoopInt",
        "LoopDouble",
        "LoopString",
        "LoopBool",
        "RunOnce",
        "SkipUnlessUpdated",
        "WaitValueUpdate",
    },
    "Control": {
        "Sequence",
        "AsyncSequence",
        "ReactiveSequence",
        "SequenceWithMemory",
        "Fallback",
        "AsyncFallback",
        "ReactiveFallback",
        "Parallel",
        "IfThenElse",
        "WhileDoElse",
        "Switch2",
        "Switch3",
        "Switch4",
        "Switch5",
        "Switch6",
        "ParallelAll",
        "TryCatch",
    },
}


class TestPorts:
    """Port declarations of every built-in node type."""

    def test_the_table_covers_every_node(self) -> None:
        """No node type is missing from this test, none is extra."""
        assert set(EXPECTED) == set(BUILTIN_NODES)

    def test_the_lazy_table_names_every_node_class(self) -> None:
        """BUILTIN_NODES imports a node's module when it is looked up: its table names every public node
        class of the package's modules (bar the bases and the config action), each under its class name."""
        defined = {}
        for info in pkgutil.iter_modules(nodes_package.__path__):
            module = importlib.import_module(f"{nodes_package.__name__}.{info.name}")
            defined.update({name: obj for name, obj in vars(module).items()
                            if inspect.isclass(obj) and obj.__module__ == module.__name__
                            and issubclass(obj, CanguardNode) and not name.startswith("_")})
        assert set(defined) - {"CanguardNode", "DecoratorNode", "GuardNode", "ConfiguredAction"} == set(BUILTIN_NODES)
        assert all(BUILTIN_NODES[node_id] is defined[node_id] for node_id in BUILTIN_NODES)

    @pytest.mark.parametrize("node_id", sorted(EXPECTED))
    def test_ports_and_defaults(self, node_id: str) -> None:
        """Names, directions, types and defaults are as documented."""
        cls = BUILTIN_NODES[node_id]
        got = {
            name: (
                "in" if direction == "input" else "out",
                info.data_type,
                info.default_value if info.has_default else NO,
            )
            for name, (direction, info) in port_table(cls).items()
        }
        assert got == EXPECTED[node_id]

    @pytest.mark.parametrize("node_id", sorted(EXPECTED))
    def test_required_ports(self, node_id: str) -> None:
        """Exactly the ports without which the node cannot work are required."""
        cls = BUILTIN_NODES[node_id]
        required = {n for n, (_, i) in port_table(cls).items() if i.required and not i.has_default}
        assert required == REQUIRED.get(node_id, set())

    @pytest.mark.parametrize("node_id", sorted(EXPECTED))
    def test_kind_and_description(self, node_id: str) -> None:
        """Each node has its BT.CPP category, a description, and described ports."""
        cls = BUILTIN_NODES[node_id]
        assert issubclass(cls, CanguardNode)
        assert node_id in KINDS[cls.KIND]
        assert cls.DESCRIPTION
        assert all(info.description for _, info in port_table(cls).values())

    def test_configured_action_ports(self) -> None:
        """Every actions: entry has one optional output port, output_time (float)."""
        ((name, (direction, info)),) = port_table(ConfiguredAction).items()
        assert (name, direction, info.data_type, info.required) == ("output_time", "output", float, False)
