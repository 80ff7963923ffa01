"""Node IDs a config's ``actions:`` may not take: BehaviorTree.CPP 4's built-ins and canguard's nodes.

Names only: the config layer does not import the node library.
"""

from __future__ import annotations

BTCPP_BUILTIN_IDS = (
    # controls
    "Sequence", "AsyncSequence", "SequenceWithMemory", "SequenceStar", "ReactiveSequence", "Fallback",
    "AsyncFallback", "ReactiveFallback",
    "Parallel", "ParallelAll", "IfThenElse", "WhileDoElse", "Switch2", "Switch3", "Switch4", "Switch5",
    "Switch6", "TryCatch",
    # decorators
    "Inverter", "ForceSuccess", "ForceFailure", "RetryUntilSuccessful", "Repeat", "KeepRunningUntilFailure",
    "RunOnce", "Timeout", "Delay", "Precondition", "SkipUnlessUpdated", "WaitValueUpdate", "LoopInt",
    "LoopDouble", "LoopString", "LoopBool", "SubTree",
    # actions and conditions
    "AlwaysSuccess", "AlwaysFailure", "Script", "ScriptCondition", "SetBlackboard", "UnsetBlackboard",
    "Sleep", "WasEntryUpdated",
)
"""The IDs BehaviorTree.CPP 4's factory registers (``BehaviorTreeFactory`` constructor)."""

CANGUARD_NODE_IDS = (
    "EmitStop", "ExecuteTask", "IsCooldownElapsed", "IsCurrentNormal", "IsCurrentSafe", "IsElapsedSinceEvent",
    "IsElapsedTimeCompare", "IsI2tSafe", "IsJointEffortNormal", "IsValueAbove", "IsValueBelow", "Profile",
    "RecordTime", "ResetStop", "ResetTimer",
)
"""canguard's own node types (design notes and the stop rule)."""

RESERVED_NODE_IDS = frozenset(BTCPP_BUILTIN_IDS + CANGUARD_NODE_IDS)
