"""Precedence-climbing parser of BehaviorTree.CPP's scripting language, with BT.CPP 4's binding powers.

Comparisons chain and bind looser than the bitwise operators (``x & 1 == 1`` is ``(x & 1) == 1``).
The left side of an assignment must be a name: a parse error here (BT.CPP notices only at run).
"""

from __future__ import annotations

from canguard.bt.scripting.errors import ScriptError
from canguard.bt.scripting.expr import Assign, Binary, Compare, Expr, Literal, Name, Ternary, Unary
from canguard.bt.scripting.lexer import Token, tokenize
from canguard.bt.scripting.values import INT64_MAX

ASSIGNMENT_OPS = frozenset({":=", "=", "+=", "-=", "*=", "/="})
COMPARISON_OPS = frozenset({"==", "!=", "<", "<=", ">", ">="})
_TERNARY_BP = 4
_COMPARISON_BP = 10
_PREFIX_BP = 20
_LEFT_BP = {**dict.fromkeys(ASSIGNMENT_OPS, 2), "?": _TERNARY_BP, **dict.fromkeys(COMPARISON_OPS, _COMPARISON_BP),
            "||": 6, "&&": 8, "|": 12, "^": 12, "&": 14, "+": 16, "-": 16, "..": 16, "*": 18, "/": 18}
_STARTS_OPERAND = frozenset({"int", "real", "str", "bool", "name"})


def _shown(tok: Token) -> str:
    return "the end of the script" if tok.kind == "end" else repr(tok.text) if tok.kind != "str" else f"'{tok.text}'"


class _Parser:
    def __init__(self, text: str) -> None:
        self.text = text
        self.tokens = tokenize(text)
        self.i = 0

    def where(self, pos: int) -> str:
        """``column C`` (``line L, column C`` in a multi-line script) of offset ``pos``."""
        err = ScriptError("", pos, self.text)
        return str(err)[:-2]

    def peek(self) -> Token:
        return self.tokens[self.i]

    def advance(self) -> Token:
        tok = self.tokens[self.i]
        if tok.kind != "end":
            self.i += 1
        return tok

    def at_op(self, text: str) -> bool:
        tok = self.peek()
        return tok.kind == "op" and tok.text == text

    def statements(self) -> list[Expr]:
        stmts: list[Expr] = []
        while self.at_op(";"):
            self.advance()
        while self.peek().kind != "end":
            stmts.append(self.expression(0))
            tok = self.peek()
            if tok.kind == "end":
                break
            if tok.kind == "op" and tok.text == ";":
                while self.at_op(";"):
                    self.advance()
            elif tok.kind == "error":
                raise ScriptError(tok.reason, tok.pos)
            elif tok.kind not in _STARTS_OPERAND and not (tok.kind == "op" and tok.text in "(-!~"):
                raise ScriptError(f"expected an operator, ';' or the end of the script, got {_shown(tok)}", tok.pos)
        if not stmts:
            raise ScriptError("empty script: expected at least one statement")
        return stmts

    def expression(self, min_bp: int) -> Expr:
        left = self.prefix()
        while True:
            tok = self.peek()
            bp = _LEFT_BP.get(tok.text, -1) if tok.kind == "op" else -1
            if bp < 0 or bp < min_bp:
                return left
            if tok.text in ASSIGNMENT_OPS:
                return self.assignment(left)
            if tok.text == "?":
                return self.ternary(left)
            if tok.text in COMPARISON_OPS:
                left = self.comparison(left)
                continue
            self.advance()
            right = self.expression(bp + 1)
            left = Binary(tok.pos, tok.text, left, right)

    def assignment(self, target: Expr) -> Expr:
        tok = self.advance()
        if not isinstance(target, Name):
            raise ScriptError(
                f"the left side of [{tok.text}] must be the name of a blackboard entry", target.pos
            )
        return Assign(tok.pos, tok.text, target.name, self.expression(0))

    def ternary(self, condition: Expr) -> Expr:
        question = self.advance()
        then = self.expression(0)
        if not self.at_op(":"):
            tok = self.peek()
            raise ScriptError(
                f"expected ':' of the [?] at {self.where(question.pos)}, got {_shown(tok)}", tok.pos
            )
        self.advance()
        otherwise = self.expression(_TERNARY_BP)
        return Ternary(question.pos, condition, then, otherwise)

    def comparison(self, first: Expr) -> Expr:
        ops: list[tuple[str, int]] = []
        operands = [first]
        while self.peek().kind == "op" and self.peek().text in COMPARISON_OPS:
            tok = self.advance()
            ops.append((tok.text, tok.pos))
            operands.append(self.expression(_COMPARISON_BP + 1))
        return Compare(ops[0][1], tuple(ops), tuple(operands))

    def prefix(self) -> Expr:
        tok = self.advance()
        kind = tok.kind
        if kind == "int":
            value = int(tok.text, 16) if tok.text[:2] in ("0x", "0X") else int(tok.text)
            if value > INT64_MAX:
                raise ScriptError(f"the integer {tok.text} does not fit in 64 bits (signed)", tok.pos)
            return Literal(tok.pos, value)
        if kind == "real":
            return Literal(tok.pos, float(tok.text))
        if kind == "str":
            return Literal(tok.pos, tok.text)
        if kind == "bool":  # BT.CPP 4: the literals true / false are the reals 1.0 / 0.0
            return Literal(tok.pos, 1.0 if tok.text == "true" else 0.0)
        if kind == "name":
            return Name(tok.pos, tok.text)
        if kind == "error":
            raise ScriptError(tok.reason, tok.pos)
        if kind == "op" and tok.text in ("-", "!", "~"):
            return Unary(tok.pos, tok.text, self.expression(_PREFIX_BP))
        if kind == "op" and tok.text == "(":
            inner = self.expression(0)
            if not self.at_op(")"):
                got = self.peek()
                raise ScriptError(f"expected ')' to close the '(' at {self.where(tok.pos)}, got {_shown(got)}", got.pos)
            self.advance()
            return inner
        raise ScriptError(
            f"expected a value (a number, a 'string', true, false, a name, '(' or - ! ~), got {_shown(tok)}", tok.pos
        )


def parse_statements(text: str) -> list[Expr]:
    """The statements of ``text``; ScriptError (with its column) when it does not parse."""
    try:
        return _Parser(text).statements()
    except ScriptError as exc:
        raise exc.located(text) from None
