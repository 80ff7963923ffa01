"""BehaviorTree.CPP v4's scripting language (no eval/exec); :mod:`.script` loads with the built-ins or a condition."""

from __future__ import annotations


class ScriptError(ValueError):
    """A script that does not parse (at load) or that fails while it runs (at tick): ``column 7: expected ')'
    ...`` (``line 2, column 3: ...`` in a multi-line script; ``pos``: the 0-based offset, None: the whole)."""

    def __init__(self, message: str, pos: int | None = None, script: str | None = None) -> None:
        self.message = message
        self.pos = pos
        where = ""
        if pos is not None and script is not None:
            before = script[:pos]
            line, column = before.count("\n") + 1, pos - before.rfind("\n")
            where = f"line {line}, column {column}: " if "\n" in script else f"column {column}: "
        super().__init__(where + message)
