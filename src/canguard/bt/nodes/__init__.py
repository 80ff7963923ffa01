"""canguard's node library: py_trees behaviours with typed ports, by BehaviorTree.CPP node ID.

:data:`BUILTIN_NODES` is the closed table (extended per tree by config actions and plug-ins); a
family's module is imported when one of its classes is first looked up.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from importlib import import_module

from canguard.bt.nodes.actions import ConfiguredAction
from canguard.bt.nodes.base import CanguardNode, PortError, port_info
from canguard.bt.nodes.current import GuardNode

_MODULES: dict[str, str] = {
    # conditions
    "IsCurrentNormal": "current", "IsJointEffortNormal": "effort", "IsCurrentSafe": "current",
    "IsI2tSafe": "current", "IsElapsedTimeCompare": "timing", "IsElapsedSinceEvent": "timing",
    "IsCooldownElapsed": "timing", "IsValueBelow": "values", "IsValueAbove": "values",
    # actions
    "ExecuteTask": "actions", "EmitStop": "actions", "ResetStop": "actions", "ResetTimer": "timing",
    "RecordTime": "timing",
    # decorators
    "Profile": "profile", "Inverter": "control", "ForceSuccess": "control", "ForceFailure": "control",
    "RetryUntilSuccessful": "control", "Repeat": "control", "Timeout": "control", "Delay": "control",
    # controls
    "Sequence": "sequences", "AsyncSequence": "sequences", "ReactiveSequence": "sequences",
    "SequenceWithMemory": "sequences", "Fallback": "sequences", "AsyncFallback": "sequences",
    "ReactiveFallback": "sequences", "Parallel": "control",
    # more BehaviorTree.CPP 4 built-ins
    "AlwaysSuccess": "builtins", "AlwaysFailure": "builtins", "Script": "builtins", "ScriptCondition": "builtins",
    "SetBlackboard": "builtins", "UnsetBlackboard": "builtins", "Sleep": "builtins",
    "KeepRunningUntilFailure": "builtins", "Precondition": "builtins", "IfThenElse": "builtins",
    "WhileDoElse": "builtins",
    "Switch2": "branches", "Switch3": "branches", "Switch4": "branches", "Switch5": "branches",
    "Switch6": "branches", "ParallelAll": "branches", "TryCatch": "branches",
    "LoopInt": "loops", "LoopDouble": "loops", "LoopString": "loops", "LoopBool": "loops",
    "RunOnce": "once", "WasEntryUpdated": "once", "SkipUnlessUpdated": "once", "WaitValueUpdate": "once",
}
"""Every node ID canguard provides -> the module ``canguard.bt.nodes.<module>`` of its class."""


class _NodeTable(Mapping[str, "type[CanguardNode]"]):
    """Node ID -> class, in :data:`_MODULES`' order, imported when first looked up."""

    def __getitem__(self, node_id: str) -> type[CanguardNode]:
        cls: type[CanguardNode] = getattr(import_module(f"{__name__}.{_MODULES[node_id]}"), node_id)
        return cls

    def __contains__(self, node_id: object) -> bool:
        return node_id in _MODULES  # a known ID, without importing its class

    def __iter__(self) -> Iterator[str]:
        return iter(_MODULES)

    def __len__(self) -> int:
        return len(_MODULES)


BUILTIN_NODES: Mapping[str, type[CanguardNode]] = _NodeTable()
"""Every node type canguard provides, by node ID (the closed table)."""


def __getattr__(name: str) -> type[CanguardNode]:
    if name in _MODULES:
        return BUILTIN_NODES[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["BUILTIN_NODES", "CanguardNode", "ConfiguredAction", "GuardNode", "PortError", "port_info"]
