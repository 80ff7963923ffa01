"""canguard's node library: py_trees behaviours with typed ports, by BehaviorTree.CPP node ID."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from importlib import import_module

from canguard.bt.nodes.actions import ConfiguredAction
from canguard.bt.nodes.base import CanguardNode, PortError, port_info
from canguard.bt.nodes.current import GuardNode

_FAMILIES = (  # conditions, actions, decorators, controls, then more of BehaviorTree.CPP 4's built-ins
    ("current", "IsCurrentNormal IsJointEffortNormal IsCurrentSafe IsI2tSafe"),
    ("timing", "IsElapsedTimeCompare IsElapsedSinceEvent IsCooldownElapsed IsValueBelow IsValueAbove"),
    ("actions", "ExecuteTask EmitStop ResetStop"), ("timing", "ResetTimer RecordTime"), ("control", "Profile"),
    ("control", "Inverter ForceSuccess ForceFailure RetryUntilSuccessful Repeat Timeout Delay Sequence AsyncSequence "
                "ReactiveSequence SequenceWithMemory Fallback AsyncFallback ReactiveFallback Parallel"),
    ("builtins", "AlwaysSuccess AlwaysFailure Script ScriptCondition SetBlackboard UnsetBlackboard Sleep "
                 "KeepRunningUntilFailure Precondition IfThenElse WhileDoElse Switch2 Switch3 Switch4 Switch5 Switch6 "
                 "ParallelAll TryCatch LoopInt LoopDouble LoopString LoopBool RunOnce WasEntryUpdated "
                 "SkipUnlessUpdated WaitValueUpdate"),
)
_MODULES = {node_id: module for module, ids in _FAMILIES for node_id in ids.split()}
"""Every node ID canguard provides -> the module ``canguard.bt.nodes.<module>`` of its class."""


class _NodeTable(Mapping[str, "type[CanguardNode]"]):
    """Node ID -> class, in :data:`_MODULES`' order, imported when first looked up."""

    def __getitem__(self, node_id: str) -> type[CanguardNode]:
        return getattr(import_module(f"{__name__}.{_MODULES[node_id]}"), node_id)

    def __contains__(self, node_id: object) -> bool:
        return node_id in _MODULES  # a known ID, without importing its class

    def __iter__(self) -> Iterator[str]:
        return iter(_MODULES)

    def __len__(self) -> int:
        return len(_MODULES)


BUILTIN_NODES: Mapping[str, type[CanguardNode]] = _NodeTable()
"""Every node type canguard provides, by node ID: the closed table that config actions and plug-ins extend per tree."""


__all__ = ["BUILTIN_NODES", "CanguardNode", "ConfiguredAction", "GuardNode", "PortError", "port_info"]
