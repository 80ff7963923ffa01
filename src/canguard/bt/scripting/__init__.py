"""BehaviorTree.CPP v4's scripting language (``Script``, ``ScriptCondition``, pre/post conditions).

``parse(text)`` turns a script into a :class:`Script` once, at load (a syntax
error is a :class:`ScriptError` with its column); ``Script.run(blackboard, enums)``
evaluates it at each tick against any :class:`ScriptBlackboard` and returns the
value of its last statement; ``Script.condition(...)`` takes that value as a
boolean. No Python eval/exec: a tokenizer, a precedence-climbing parser and a
tree-walking evaluator with BT.CPP 4's typing rules (see :mod:`.values`).

Only :class:`ScriptError` is imported with the package; the language itself (its
expression classes cost ~5 ms to create) is imported by the first :func:`parse`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from canguard.bt.scripting.errors import ScriptError

if TYPE_CHECKING:
    from canguard.bt.scripting.script import Script

__all__ = ["ScriptError", "parse"]


def parse(text: str) -> Script:
    """Parse ``text`` once (at load); ScriptError with the column when it does not parse."""
    from canguard.bt.scripting.script import Script

    return Script(text)
