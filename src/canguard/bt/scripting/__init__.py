"""BehaviorTree.CPP v4's scripting language (``Script``, ``ScriptCondition``, pre/post conditions).

``parse(text)`` turns a script into a :class:`Script` once, at load (a syntax
error is a :class:`ScriptError` with its column); ``Script.run(blackboard, enums)``
evaluates it at each tick against any :class:`ScriptBlackboard` and returns the
value of its last statement; ``Script.condition(...)`` takes that value as a
boolean. No Python eval/exec: a tokenizer, a precedence-climbing parser and a
tree-walking evaluator with BT.CPP 4's typing rules (see :mod:`.values`).
"""

from canguard.bt.scripting.blackboard import DictBlackboard, ScriptBlackboard
from canguard.bt.scripting.errors import ScriptError
from canguard.bt.scripting.script import Script, parse
from canguard.bt.scripting.values import UNSET, as_condition

__all__ = ["UNSET", "DictBlackboard", "Script", "ScriptBlackboard", "ScriptError", "as_condition", "parse"]
