"""A parsed script: parse once at load, run at every tick."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields

from canguard.bt.scripting.blackboard import ScriptBlackboard
from canguard.bt.scripting.errors import ScriptError
from canguard.bt.scripting.expr import Env, Expr
from canguard.bt.scripting.parser import parse_statements
from canguard.bt.scripting.values import UNSET, as_condition

MAX_DEPTH = 200  # deepest expression tree a script may have: far from Python's recursion limit


def _depth(expr: Expr) -> int:
    """How deep ``expr``'s tree is (walked without recursion)."""
    deepest, stack = 0, [(expr, 1)]
    while stack:
        node, depth = stack.pop()
        deepest = max(deepest, depth)
        for f in fields(node):
            value = getattr(node, f.name)
            values = value if isinstance(value, tuple) else (value,)
            stack.extend((c, depth + 1) for c in values if isinstance(c, Expr))
    return deepest


class Script:
    """The statements of one script; a failure is a :class:`ScriptError` naming the column."""

    __slots__ = ("_statements", "text")

    def __init__(self, text: str) -> None:
        try:
            statements = parse_statements(text)
        except RecursionError:
            raise ScriptError(f"script nested too deeply (more than {MAX_DEPTH} levels)") from None
        for stmt in statements:
            if _depth(stmt) > MAX_DEPTH:
                raise ScriptError(f"expression nested too deeply (more than {MAX_DEPTH} levels)", stmt.pos, text)
        self.text = text
        self._statements: tuple[Expr, ...] = tuple(statements)

    def __repr__(self) -> str:
        return f"Script({self.text!r})"

    def run(self, blackboard: ScriptBlackboard, enums: Mapping[str, int] | None = None) -> object:
        """Run every statement; the value of the last one (None when that is an entry without a value)."""
        env = Env(blackboard, enums)
        try:
            value: object = None
            for stmt in self._statements:
                value = stmt.evaluate(env)
        except ScriptError as exc:
            raise exc.located(self.text) from None
        return None if value is UNSET else value

    def condition(self, blackboard: ScriptBlackboard, enums: Mapping[str, int] | None = None) -> bool:
        """Run the script and take its value as a boolean (:func:`.values.as_condition`)."""
        value = self.run(blackboard, enums)
        try:
            return as_condition(value)
        except ValueError as exc:
            raise ScriptError(f"{exc} from the script {self.text!r}") from None
