"""BehaviorTree.CPP v4's scripting language (no eval/exec), imported by the first :func:`parse`."""

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
