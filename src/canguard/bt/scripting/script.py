"""The scripting language itself: a tokenizer (one pattern), a Pratt parser that compiles each expression
into a closure at load, and BehaviorTree.CPP 4's rules for values (``operators.hpp``, ``safe_any.hpp``).

As BT.CPP: comparisons chain and bind looser than the bitwise operators (``x & 1 == 1`` is ``(x & 1) == 1``),
and ``&&`` and ``||`` evaluate both operands (the value rules: docs/trees.md, "Scripts").
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple

from canguard.bt.scripting import ScriptError

if TYPE_CHECKING:
    from canguard.bt.scopes import TreeBlackboard

FLT_EPSILON = 1.1920928955078125e-07  # reals this close are equal (BT.CPP's IsSame)
INT64_MIN = -(2**63)
INT64_MAX = 2**63 - 1
EXACT_INT = 2**53 - 1  # the largest integer a double holds exactly
MAX_DEPTH = 200  # deepest expression tree a script may have: far from Python's recursion limit
UNSET: Any = object()
"""The value of an entry that exists but holds nothing yet (BT.CPP's empty ``Any``)."""


Run = Callable[["TreeBlackboard"], Any]

_NUMBER_TEXT = re.compile(r"-?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|-?(?:inf|infinity|nan)", re.IGNORECASE)


def type_name(t: type) -> str:
    """``an integer``, ``a real``, ``a boolean``, ``a string`` or ``a <class name>``."""
    return {bool: "a boolean", int: "an integer", float: "a real", str: "a string"}.get(t, f"a {t.__name__}")


def describe(value: object) -> str:
    """``the integer 3``, ``the real 2.5``, ``the string 'a'``, ``the boolean true``."""
    if isinstance(value, bool):
        return f"the boolean {'true' if value else 'false'}"
    if isinstance(value, int):
        return f"the integer {value}"
    if isinstance(value, (float, str)):
        return f"the {'real' if isinstance(value, float) else 'string'} {value!r}"
    return "an unset value" if value is UNSET else f"a value of type {type(value).__name__}"


def to_real(value: int | float, pos: int | None = None) -> float:
    """A number as a double; ScriptError (at ``pos``) when an integer is too large to be exact."""
    if isinstance(value, int) and abs(value) > EXACT_INT:
        raise ScriptError(f"the integer {value} is too large to be a real without loss (limit 2**53)", pos)
    return float(value)


def to_int64(value: int | float) -> int | None:
    """A number as an int64, or None when it is not integral or out of range."""
    if isinstance(value, int):
        return int(value) if INT64_MIN <= value <= INT64_MAX else None
    if not math.isfinite(value) or value != math.floor(value) or not (INT64_MIN <= value < 2.0**63):
        return None
    return int(value)


def logic_bool(value: object) -> bool | None:
    """A value as ``&&``/``||``/conditions see it, or None when it does not convert."""
    if isinstance(value, float):
        return value != 0.0  # nan is true, as a C++ cast
    return bool(value) if isinstance(value, int) and value in (0, 1) else None


def _text(value: str | int | float) -> str:
    """A string as it is, a number as BT.CPP turns it into a string for ``..``: integers as is, reals as ``%f``."""
    if isinstance(value, str):
        return value
    return str(int(value)) if isinstance(value, int) else f"{value:f}"


def string_to_real(text: str) -> float | None:
    """A string compared with (or assigned to) a number: 'true', 'false' or a number's text; else None."""
    if text in ("true", "false"):
        return float(text == "true")
    return float(text) if _NUMBER_TEXT.fullmatch(text) else None


def convert_for_entry(value: object, target: type) -> object:
    """``value`` converted to ``target``, its entry's type; ValueError saying what it takes if BT.CPP refuses."""
    if target not in (bool, int, float):
        if isinstance(value, target):
            return value
        raise ValueError(f"expected {type_name(target)}")
    number: object = value
    if isinstance(value, str):
        number = string_to_real(value)
        if number is None:
            raise ValueError("expected a number, or a string holding one, true, false or an enum name")
    if not isinstance(number, (int, float)):
        raise ValueError("expected a number")
    if target is float:
        return to_real(number)
    if target is bool:
        if isinstance(number, bool) or number in (0, 1):
            return bool(number)
        raise ValueError("expected true, false, 0 or 1")
    converted = to_int64(number)
    if converted is None:
        raise ValueError("expected an integral number within 64 bits")
    return converted


def entry_type(value: object) -> type:
    """The type an entry holding ``value`` keeps."""
    return next((kind for kind in (bool, int, float, str) if isinstance(value, kind)), type(value))


_NUMERIC = (int, float)


def _numbers(a: object, b: object) -> bool:
    return isinstance(a, _NUMERIC) and isinstance(b, _NUMERIC)


def _set(op: str, pos: int, **operands: object) -> None:
    """Raise the error of the first operand (``left=``, ``right=``) that holds no value."""
    for side, value in operands.items():
        if value is UNSET:
            raise ScriptError(f"the {side} operand of the operator [{op}] is not initialized", pos)


_TAKES = {"..": "at least one string (and otherwise numbers)", "+": "two numbers or two strings",
          "&&": "booleans, or the numbers 0 and 1", "||": "booleans, or the numbers 0 and 1"}


def _not_permitted(op: str, lv: object, rv: object, pos: int) -> ScriptError:
    """The error of a binary operator ``op`` given operands it does not take."""
    return ScriptError(f"operation not permitted: [{op}] between {describe(lv)} and {describe(rv)} "
                       f"(expected {_TAKES.get(op, 'numbers')})", pos)


def _ieee(op: str, a: float, b: float) -> float:
    """``a op b`` for ``+ - * /`` as C++ doubles (IEEE division)."""
    if op != "/":
        return a + b if op == "+" else a - b if op == "-" else a * b
    if b != 0.0:
        return a / b
    if a == 0.0 or math.isnan(a):
        return math.nan
    return math.copysign(math.inf, a) * math.copysign(1.0, b)


def _arithmetic(op: str, lv: Any, rv: Any, pos: int) -> object:
    if _numbers(lv, rv):
        return _ieee(op, to_real(lv, pos), to_real(rv, pos))
    if op == "+" and isinstance(lv, str) and isinstance(rv, str):
        return lv + rv
    raise _not_permitted(op, lv, rv, pos)


def _concat(op: str, lv: Any, rv: Any, pos: int) -> object:
    if (isinstance(lv, str) or isinstance(rv, str)) and all(isinstance(v, (str, int, float)) for v in (lv, rv)):
        return _text(lv) + _text(rv)
    raise _not_permitted(op, lv, rv, pos)


_BITS = {"&": operator.and_, "|": operator.or_, "^": operator.xor, "&&": operator.and_, "||": operator.or_}


def _bits(op: str, lv: Any, rv: Any, pos: int) -> object:
    """The bitwise operators on int64s, the logic ones (``&&``, ``||``) on :func:`logic_bool` values."""
    if not _numbers(lv, rv):
        raise _not_permitted(op, lv, rv, pos)
    logic = len(op) == 2
    a, b = (logic_bool(lv), logic_bool(rv)) if logic else (to_int64(lv), to_int64(rv))
    if a is None or b is None:
        what = (f"logic operator [{op}] expects booleans (or the numbers 0 and 1)" if logic
                else f"bitwise operator [{op}] expects integers")
        raise ScriptError(f"the {what}, got {describe(lv if a is None else rv)}", pos)
    return float(_BITS[op](a, b))


_BINARY: dict[str, Callable[[str, Any, Any, int], object]] = {
    **dict.fromkeys("+-*/", _arithmetic), "..": _concat, **dict.fromkeys(_BITS, _bits)}
_ORDER: dict[str, Callable[[Any, Any], bool]] = {
    "<": operator.lt, ">": operator.gt, "<=": operator.le, ">=": operator.ge}


def _comparable(op: str, lv: Any, rv: Any, pos: int) -> tuple[Any, Any]:
    """The operands of ``lv op rv`` as compared: two reals or two strings (a string beside a number read as one)."""
    if _numbers(lv, rv):
        return to_real(lv, pos), to_real(rv, pos)
    if isinstance(lv, str) and isinstance(rv, str):
        return lv, rv
    text, other = (lv, rv) if isinstance(lv, str) else (rv, lv)
    if not isinstance(text, str) or not isinstance(other, _NUMERIC):
        raise ScriptError(f"can't mix different types in a comparison: {describe(lv)} [{op}] {describe(rv)}", pos)
    number = string_to_real(text)
    if number is None:
        raise ScriptError(f"can't compare {describe(text)} with a number: expected a number's text, "
                          "true, false or an enum name", pos)
    return (number, to_real(other, pos)) if isinstance(lv, str) else (to_real(other, pos), number)


def _compare(op: str, a: Any, b: Any) -> bool:
    """``a op b``; reals are equal within float's epsilon (BT.CPP's ``IsSame``)."""
    if op in ("==", "!="):
        return (abs(a - b) <= FLT_EPSILON if isinstance(a, float) else a == b) == (op == "==")
    return _ORDER[op](a, b)


def _assigned(op: str, key: str, pos: int, value: object, bb: TreeBlackboard) -> object:
    """What ``key op value`` writes to the entry: BT.CPP's ``ExprAssignment``."""
    try:
        current = bb.get(key)
    except KeyError:
        current = UNSET
    declared = bb.declared_type(key) if bb.has(key) else None
    if op in (":=", "="):
        # BT.CPP (ExprAssignment, Any::copyInto): an entry without a value takes any value as it is, but
        # a string into one a port declared as a number is parsed to that type
        if current is UNSET and (declared is None or not isinstance(value, str) or declared is str):
            return value
    else:
        _set(op, pos, left=current)
        if isinstance(value, (int, float)):
            if not isinstance(current, (int, float)):
                raise ScriptError(f"the operator [{op}] needs a numeric entry, but [{key}] holds {describe(current)}",
                                  pos)
            value = _ieee(op[0], to_real(current, pos), to_real(value, pos))
        elif not isinstance(value, str):
            raise ScriptError(f"the operator [{op}] expects a number or a string, got {describe(value)}", pos)
        elif op != "+=":
            raise ScriptError(f"the operator [{op}] is not supported for strings (only [+=] is)", pos)
        elif not isinstance(current, str):
            raise ScriptError(f"can't append {describe(value)} to the entry [{key}], which holds {describe(current)}",
                              pos)
        else:
            value = current + value
    target = entry_type(current) if current is not UNSET else declared
    assert target is not None
    try:
        return convert_for_entry(value, target)
    except ValueError as exc:
        what = "holds" if current is not UNSET else "is declared as"
        raise ScriptError(f"can't assign {describe(value)} to the entry [{key}], which {what} "
                          f"{type_name(target)} ({exc})", pos) from None


class _Expr(NamedTuple):
    """A compiled expression: its closure and what the parser checks of it."""

    run: Run
    pos: int  # the offset its runtime errors name
    depth: int = 1  # its tree's depth
    name: str | None = None  # a bare name's (the left side of an assignment)


def _literal(value: object, pos: int) -> _Expr:
    return _Expr(lambda bb: value, pos)


def _name(name: str, pos: int) -> _Expr:
    def run(bb: TreeBlackboard) -> object:
        if not bb.has(name):
            raise ScriptError(f"variable not found: [{name}] (no blackboard entry and no enum of that name)", pos)
        try:
            return bb.get(name)
        except KeyError:
            return UNSET

    return _Expr(run, pos, 1, name)


def _unary(op: str, pos: int, operand: _Expr) -> _Expr:
    inner = operand.run

    def run(bb: TreeBlackboard) -> object:
        value = inner(bb)
        if not isinstance(value, (int, float)):
            _set(op, pos, right=value)
            raise ScriptError(f"the operator [{op}] expects a number, got {describe(value)}", pos)
        if op == "-":
            return -to_real(value, pos)
        if op == "!":
            return float(not value)  # BT.CPP: logic results are the reals 1.0 / 0.0
        if math.isnan(value) or not INT64_MIN <= float(value) <= INT64_MAX:
            raise ScriptError(f"{describe(value)} is out of range for the bitwise operator [~]", pos)
        return float(~int(value))

    return _Expr(run, pos, operand.depth + 1)


def _binary(op: str, pos: int, lhs: _Expr, rhs: _Expr) -> _Expr:
    left, right, apply = lhs.run, rhs.run, _BINARY[op]

    def run(bb: TreeBlackboard) -> object:
        lv = left(bb)
        rv = right(bb)
        _set(op, pos, left=lv, right=rv)
        return apply(op, lv, rv, pos)

    return _Expr(run, pos, max(lhs.depth, rhs.depth) + 1)


def _chain(first: _Expr, rest: list[tuple[str, int, _Expr]]) -> _Expr:
    def run(bb: TreeBlackboard) -> object:
        lv = first.run(bb)
        for op, pos, operand in rest:
            rv = operand.run(bb)
            _set(op, pos, left=lv, right=rv)
            if not _compare(op, *_comparable(op, lv, rv, pos)):
                return 0.0  # BT.CPP: a comparison is the real 1.0 or 0.0
            lv = rv
        return 1.0

    return _Expr(run, rest[0][1], max(e.depth for e in (first, *(e for _, _, e in rest))) + 1)


def _ternary(pos: int, condition: _Expr, then: _Expr, otherwise: _Expr) -> _Expr:
    def run(bb: TreeBlackboard) -> object:
        value = condition.run(bb)
        if not isinstance(value, (str, int, float)):
            _set("?", pos, left=value)
            raise ScriptError(f"the condition of [?] must be a number or a string, got {describe(value)}", pos)
        return (then if value != "" and value != 0 else otherwise).run(bb)

    return _Expr(run, pos, max(condition.depth, then.depth, otherwise.depth) + 1)


def _assign(op: str, pos: int, key: str, rhs: _Expr) -> _Expr:
    def run(bb: TreeBlackboard) -> object:
        if op != ":=" and not bb.has(key):
            raise ScriptError(f"the blackboard entry [{key}] doesn't exist yet; "
                              f"to create it, use the operator [:=] instead of [{op}]", pos)
        value = rhs.run(bb)
        _set(op, pos, right=value)
        result = _assigned(op, key, pos, value, bb)
        bb.set(key, result)
        return result

    return _Expr(run, pos, rhs.depth + 1)


_NUMBER = r"""0[xX](?P<hex>[0-9a-fA-F]*)(?P<hex_tail>[A-Za-z0-9_.]+)?
    | [0-9]+(?: (?P<point>\.(?![.0-9])[A-Za-z0-9_.]*)
              | (?P<fraction>\.[0-9]+)?
                (?: (?P<no_exponent>[eE](?![-+]?[0-9])[-+]?)
                  | (?P<exponent>[eE][-+]?[0-9]+)? (?P<letters>[A-Za-z_][A-Za-z0-9_]*|(?=@))? ))"""
_TOKEN = re.compile(rf"""[ \t\n\r]+ | '(?P<str>[^']*)' | (?P<open>'.*) | (?P<number>{_NUMBER})
    | (?P<name>[A-Za-z_@][A-Za-z0-9_]*) | (?P<op>\.\.|&&|\|\||[=!<>:+\-*/]=|[-+*/&|^~!<>=?:();]) | (?P<stray>.)""",
                    re.X | re.S)
_NUMBER_ERRORS = {
    "hex_tail": "a hexadecimal integer has no fraction, exponent or letters after its digits",
    "point": "expected digits after the decimal point",
    "no_exponent": "expected digits in the exponent",
    "letters": "a number must not be followed by letters (names start with a letter or '_')",
}


class _Token(NamedTuple):
    kind: str  # int, real, str, bool, name, op, end or error (a malformed token the parser reports)
    text: str  # a string's without its quotes
    pos: int
    reason: str = ""


def _token(m: re.Match[str]) -> _Token:
    kind, pos = m.lastgroup, m.start()
    text = m[kind] if kind is not None else ""
    if kind == "number":
        bad = next((group for group in _NUMBER_ERRORS if m[group] is not None), None)
        reason = "expected hexadecimal digits after '0x'" if m["hex"] == "" else _NUMBER_ERRORS.get(bad or "")
        if reason is None:
            return _Token("real" if m["fraction"] or m["exponent"] else "int", text, pos)
        return _Token("error", text, pos, f"invalid number '{text}': {reason}")
    if kind == "open":
        return _Token("error", text, pos, "unterminated string: expected a closing '")
    if kind == "stray":
        return _Token("error", text, pos, f"unexpected character {text!r}")
    return _Token("bool" if kind == "name" and text in ("true", "false") else str(kind), text, pos)


ASSIGNMENT_OPS = frozenset({":=", "=", "+=", "-=", "*=", "/="})
COMPARISON_OPS = frozenset({"==", "!=", "<", "<=", ">", ">="})
_TERNARY_BP = 4
_COMPARISON_BP = 10
_PREFIX_BP = 20
_LEFT_BP = {**dict.fromkeys(ASSIGNMENT_OPS, 2), "?": _TERNARY_BP, **dict.fromkeys(COMPARISON_OPS, _COMPARISON_BP),
            "||": 6, "&&": 8, "|": 12, "^": 12, "&": 14, "+": 16, "-": 16, "..": 16, "*": 18, "/": 18}
_MAY_FOLLOW = frozenset({"int", "real", "str", "bool", "name", "error", "end"})  # a statement


def _shown(tok: _Token) -> str:
    return "the end of the script" if tok.kind == "end" else repr(tok.text) if tok.kind != "str" else f"'{tok.text}'"


class _Parser:
    """Precedence climbing with BT.CPP 4's binding powers; the left side of an assignment must be a name (a
    parse error here, BT.CPP notices only at run)."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.tokens = [_token(m) for m in _TOKEN.finditer(text) if m.lastgroup is not None]
        self.tokens.append(_Token("end", "", len(text)))
        self.i = 0

    def error(self, message: str, pos: int | None) -> ScriptError:
        return ScriptError(message, pos, self.text)

    def where(self, pos: int) -> str:
        """``column C`` (``line L, column C`` in a multi-line script) of offset ``pos``."""
        return str(self.error("", pos))[:-2]

    def take(self) -> _Token:
        tok = self.tokens[self.i]
        self.i += tok.kind != "end"
        return tok

    def at(self, op: str) -> bool:
        tok = self.tokens[self.i]
        return tok.kind == "op" and tok.text == op

    def statements(self) -> list[_Expr]:
        stmts: list[_Expr] = []
        while self.at(";"):
            self.take()
        while self.tokens[self.i].kind != "end":
            stmts.append(self.expression(0))
            tok = self.tokens[self.i]  # a malformed token is reported as the next statement's
            if tok.kind not in _MAY_FOLLOW and tok.text not in ";(-!~":
                raise self.error(f"expected an operator, ';' or the end of the script, got {_shown(tok)}", tok.pos)
            while self.at(";"):
                self.take()
        if not stmts:
            raise self.error("empty script: expected at least one statement", None)
        return stmts

    def expression(self, min_bp: int) -> _Expr:
        left = self.prefix()
        while True:
            tok = self.tokens[self.i]
            bp = _LEFT_BP.get(tok.text, -1) if tok.kind == "op" else -1
            if bp < min_bp:
                return left
            self.take()
            if tok.text in ASSIGNMENT_OPS:
                if left.name is None:
                    raise self.error(f"the left side of [{tok.text}] must be the name of a blackboard entry",
                                     left.pos)
                return _assign(tok.text, tok.pos, left.name, self.expression(0))
            if tok.text == "?":
                return self.ternary(tok, left)
            if tok.text in COMPARISON_OPS:
                left = self.chain(tok, left)
            else:
                left = _binary(tok.text, tok.pos, left, self.expression(bp + 1))

    def ternary(self, question: _Token, condition: _Expr) -> _Expr:
        then = self.expression(0)
        if not self.at(":"):
            tok = self.tokens[self.i]
            raise self.error(f"expected ':' of the [?] at {self.where(question.pos)}, got {_shown(tok)}", tok.pos)
        self.take()
        return _ternary(question.pos, condition, then, self.expression(_TERNARY_BP))

    def chain(self, tok: _Token, first: _Expr) -> _Expr:
        rest = [(tok.text, tok.pos, self.expression(_COMPARISON_BP + 1))]
        while self.tokens[self.i].kind == "op" and self.tokens[self.i].text in COMPARISON_OPS:
            tok = self.take()
            rest.append((tok.text, tok.pos, self.expression(_COMPARISON_BP + 1)))
        return _chain(first, rest)

    def prefix(self) -> _Expr:
        tok = self.take()
        kind, text, pos = tok.kind, tok.text, tok.pos
        if kind == "int":
            value = int(text, 16) if text[:2] in ("0x", "0X") else int(text)
            if value > INT64_MAX:
                raise self.error(f"the integer {text} does not fit in 64 bits (signed)", pos)
            return _literal(value, pos)
        if kind in ("real", "str", "bool"):  # BT.CPP 4: the literals true / false are the reals 1.0 / 0.0
            return _literal(float(text == "true") if kind == "bool" else float(text) if kind == "real" else text, pos)
        if kind == "name":
            return _name(text, pos)
        if kind == "error":
            raise self.error(tok.reason, pos)
        if kind == "op" and text in ("-", "!", "~"):
            return _unary(text, pos, self.expression(_PREFIX_BP))
        if kind == "op" and text == "(":
            inner = self.expression(0)
            if not self.at(")"):
                got = self.tokens[self.i]
                raise self.error(f"expected ')' to close the '(' at {self.where(pos)}, got {_shown(got)}", got.pos)
            self.take()
            return inner
        raise self.error(
            f"expected a value (a number, a 'string', true, false, a name, '(' or - ! ~), got {_shown(tok)}", pos)


class Script:
    """The statements of one script, parsed once (at load) and run at every tick; a failure is a
    :class:`ScriptError` naming the column."""

    __slots__ = ("_runs", "text")

    def __init__(self, text: str) -> None:
        try:
            statements = _Parser(text).statements()
        except RecursionError:
            raise ScriptError(f"script nested too deeply (more than {MAX_DEPTH} levels)") from None
        for stmt in statements:
            if stmt.depth > MAX_DEPTH:
                raise ScriptError(f"expression nested too deeply (more than {MAX_DEPTH} levels)", stmt.pos, text)
        self.text = text
        self._runs = tuple(stmt.run for stmt in statements)

    def run(self, blackboard: TreeBlackboard) -> object:
        """Run every statement; the value of the last one (None when that is an entry without a value)."""
        value: object = None
        try:
            for run in self._runs:
                value = run(blackboard)
        except ScriptError as exc:
            raise ScriptError(exc.message, exc.pos, self.text) from None
        return None if value is UNSET else value

    def condition(self, blackboard: TreeBlackboard) -> bool:
        """Run the script and take its value as a boolean (:func:`logic_bool`)."""
        value = self.run(blackboard)
        result = logic_bool(value)
        if result is None:
            raise ScriptError(f"expected a boolean result (true/false, or a number 0 or 1), got {describe(value)} "
                              f"from the script {self.text!r}")
        return result
