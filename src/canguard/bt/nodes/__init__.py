"""canguard's node library: py_trees behaviours with typed ports, by BehaviorTree.CPP node ID.

:data:`BUILTIN_NODES` is the closed table of node types canguard itself provides;
:func:`canguard.bt.loader.build_registry` binds each to a tree's context and extends
the table with one :class:`~canguard.bt.nodes.actions.ConfiguredAction` per
``actions:`` entry of the config and with the node types third-party packages
declare in the ``canguard.nodes`` entry-point group (loaded lazily, only when a
tree uses them). Node IDs read from XML are only ever looked up in that table:
nothing is imported or evaluated by a name found in a tree file.

A plug-in node type is a class deriving from :class:`CanguardNode` (or at least
:class:`py_trees.ports.PortsMixin`) and a py_trees behaviour; when its
constructor takes ``context=`` it receives the tree's :class:`~canguard.bt.context.Context`.
"""

from __future__ import annotations

from canguard.bt.nodes.actions import ConfiguredAction, EmitStop, ExecuteTask, ResetStop
from canguard.bt.nodes.base import CanguardNode, NodeKind, PortError, port_info
from canguard.bt.nodes.branches import NODES as BRANCH_NODES
from canguard.bt.nodes.builtins import NODES as BTCPP_NODES
from canguard.bt.nodes.control import (
    AsyncFallback,
    AsyncSequence,
    Delay,
    Fallback,
    ForceFailure,
    ForceSuccess,
    Inverter,
    Parallel,
    ReactiveFallback,
    ReactiveSequence,
    Repeat,
    RetryUntilSuccessful,
    Sequence,
    SequenceWithMemory,
    Timeout,
)
from canguard.bt.nodes.current import GuardNode, IsCurrentNormal, IsCurrentSafe, IsI2tSafe
from canguard.bt.nodes.effort import IsJointEffortNormal
from canguard.bt.nodes.loops import NODES as LOOP_NODES
from canguard.bt.nodes.once import NODES as ONCE_NODES
from canguard.bt.nodes.profile import Profile
from canguard.bt.nodes.timing import (
    IsCooldownElapsed,
    IsElapsedSinceEvent,
    IsElapsedTimeCompare,
    RecordTime,
    ResetTimer,
)
from canguard.bt.nodes.values import IsValueAbove, IsValueBelow

BUILTIN_NODES: dict[str, type[CanguardNode]] = {
    cls.__name__: cls
    for cls in (
        # conditions
        IsCurrentNormal,
        IsJointEffortNormal,
        IsCurrentSafe,
        IsI2tSafe,
        IsElapsedTimeCompare,
        IsElapsedSinceEvent,
        IsCooldownElapsed,
        IsValueBelow,
        IsValueAbove,
        # actions
        ExecuteTask,
        EmitStop,
        ResetStop,
        ResetTimer,
        RecordTime,
        # decorators
        Profile,
        Inverter,
        ForceSuccess,
        ForceFailure,
        RetryUntilSuccessful,
        Repeat,
        Timeout,
        Delay,
        # controls
        Sequence,
        AsyncSequence,
        ReactiveSequence,
        SequenceWithMemory,
        Fallback,
        AsyncFallback,
        ReactiveFallback,
        Parallel,
        # more BehaviorTree.CPP 4 built-ins
        *BTCPP_NODES,
        *BRANCH_NODES,
        *LOOP_NODES,
        *ONCE_NODES,
    )
}
"""Every node type canguard provides, by node ID (the closed table)."""

__all__ = [
    "BUILTIN_NODES",
    "CanguardNode",
    "ConfiguredAction",
    "Delay",
    "EmitStop",
    "ExecuteTask",
    "Fallback",
    "ForceFailure",
    "ForceSuccess",
    "GuardNode",
    "Inverter",
    "IsCooldownElapsed",
    "IsCurrentNormal",
    "IsCurrentSafe",
    "IsElapsedSinceEvent",
    "IsElapsedTimeCompare",
    "IsI2tSafe",
    "IsJointEffortNormal",
    "IsValueAbove",
    "IsValueBelow",
    "NodeKind",
    "Parallel",
    "PortError",
    "Profile",
    "ReactiveFallback",
    "ReactiveSequence",
    "RecordTime",
    "Repeat",
    "ResetStop",
    "ResetTimer",
    "RetryUntilSuccessful",
    "Sequence",
    "SequenceWithMemory",
    "Timeout",
    "port_info",
]
