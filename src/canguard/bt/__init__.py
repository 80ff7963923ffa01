"""BehaviorTree.CPP v4 compatibility: tree loading, built-in nodes and the scripting language."""
