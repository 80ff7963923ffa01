"""BehaviorTree.CPP v4's scripting language (``Script``, ``ScriptCondition``, pre/post conditions).

No Python eval/exec: a tokenizer, a precedence-climbing parser and a tree-walking evaluator with
BT.CPP 4's typing rules (:mod:`.values`). Only :class:`ScriptError` is imported with the package;
the language (its expression classes cost ~5 ms to create) by the first :func:`parse`.
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
