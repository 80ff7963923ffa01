"""canguard's node library: py_trees behaviours with typed ports, by BehaviorTree.CPP node ID.

:data:`BUILTIN_NODES` is the closed table of node types canguard itself provides;
:func:`canguard.bt.loader.build_registry` binds each to a tree's context and extends
the table with one :class:`~canguard.bt.nodes.actions.ConfiguredAction` per
``actions:`` entry of the config and with the node types third-party packages
declare in the ``canguard.nodes`` entry-point group (loaded lazily, only when a
tree uses them). Node IDs read from XML are only ever looked up in that table:
nothing is imported or evaluated by a name found in a tree file.

The table names each node type's module, and a module is imported when one of its
classes is first looked up (``BUILTIN_NODES[node_id]``, or ``from canguard.bt.nodes
import Sequence``): a tree pays at start-up only for the node families it uses. The
actions and the current guards, which the engine and the loader always need, are
imported with the package.

A plug-in node type is a class deriving from :class:`CanguardNode` (or at least
:class:`py_trees.ports.PortsMixin`) and a py_trees behaviour; when its
constructor takes ``context=`` it receives the tree's :class:`~canguard.bt.context.Context`.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from importlib import import_module

from canguard.bt.nodes.actions import ConfiguredAction, EmitStop, ExecuteTask, ResetStop
from canguard.bt.nodes.base import CanguardNode, NodeKind, PortError, port_info
from canguard.bt.nodes.current import GuardNode, IsCurrentNormal, IsCurrentSafe, IsI2tSafe

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
"""Every node ID canguard provides and the module ``canguard.bt.nodes.<module>`` of its class (named as the ID)."""


class _NodeTable(Mapping[str, "type[CanguardNode]"]):
    """Node ID -> class, in :data:`_MODULES`' order; a class's module is imported when it is first looked up."""

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


__all__ = ["BUILTIN_NODES", "CanguardNode", "ConfiguredAction", "EmitStop", "ExecuteTask", "GuardNode",
           "IsCurrentNormal", "IsCurrentSafe", "IsI2tSafe", "NodeKind", "PortError", "ResetStop", "port_info"]
