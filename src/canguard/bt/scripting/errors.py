"""The one error of the scripting language: where in the script, and what was expected."""

from __future__ import annotations


class ScriptError(ValueError):
    """A script that does not parse (at load) or that fails while it runs (at tick): ``column 7: expected ')'
    ...`` (``line 2, column 3: ...`` in a multi-line script; ``pos``: the 0-based offset, None: the whole)."""

    def __init__(self, message: str, pos: int | None = None, script: str | None = None) -> None:
        self.message = message
        self.pos = pos
        self.script = script
        self.line: int | None = None
        self.column: int | None = None
        if pos is not None and script is not None:
            before = script[:pos]
            self.line = before.count("\n") + 1
            self.column = pos - (before.rfind("\n") + 1) + 1
        super().__init__(str(self))

    def __str__(self) -> str:
        if self.column is None:
            return self.message
        where = f"line {self.line}, column {self.column}" if "\n" in (self.script or "") else f"column {self.column}"
        return f"{where}: {self.message}"
