"""Node IDs a config's ``actions:`` may not take: BehaviorTree.CPP 4's built-ins and canguard's nodes.

Names only: the config layer does not import the node library."""

from __future__ import annotations

RESERVED_NODE_IDS = frozenset((
    # BehaviorTree.CPP 4's factory (``BehaviorTreeFactory`` constructor): controls
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
    # canguard's own node types (design notes and the stop rule)
    "EmitStop", "ExecuteTask", "IsCooldownElapsed", "IsCurrentNormal", "IsCurrentSafe", "IsElapsedSinceEvent",
    "IsElapsedTimeCompare", "IsI2tSafe", "IsJointEffortNormal", "IsValueAbove", "IsValueBelow", "Profile",
    "RecordTime", "ResetStop", "ResetTimer",
))
