"""BehaviorTree.CPP v4's scripting language (``Script``, ``ScriptCondition``, pre/post conditions).

``parse(text)`` turns a script into a :class:`Script` once, at load (a syntax
error is a :class:`ScriptError` with its column); ``Script.run(blackboard, enums)``
evaluates it at each tick against any :class:`ScriptBlackboard` and returns the
value of its last statement; ``Script.condition(...)`` takes that value as a
boolean. No Python eval/exec: a tokenizer, a precedence-climbing parser and a
tree-walking evaluator with BT.CPP 4's typing rules (see :mod:`.values`).

Only :class:`ScriptError` is imported with the package; the language itself (its
expression classes cost ~5 ms to create) is imported when a name below is first
asked for, so a tree without scripts or pre/post conditions never pays for it.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING

from canguard.bt.scripting.errors import ScriptError

if TYPE_CHECKING:
    from canguard.bt.scripting.blackboard import ScriptBlackboard
    from canguard.bt.scripting.script import Script, parse
    from canguard.bt.scripting.values import UNSET, as_condition

__all__ = ["UNSET", "Script", "ScriptBlackboard", "ScriptError", "as_condition", "parse"]

_LAZY = {
    "ScriptBlackboard": "blackboard",
    "Script": "script",
    "parse": "script",
    "UNSET": "values",
    "as_condition": "values",
}
"""The names imported on first use, and their module."""


def __getattr__(name: str) -> object:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f"{__name__}.{_LAZY[name]}"), name)
    globals()[name] = value
    return value
