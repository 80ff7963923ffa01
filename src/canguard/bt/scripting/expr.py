"""The syntax tree of a script and its evaluation, with BehaviorTree.CPP 4's semantics (:mod:`.values`).

Each node keeps its token's offset, so a runtime error names the column. As BT.CPP, ``&&`` and ``||``
evaluate both operands.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from canguard.bt.scripting.blackboard import ScriptBlackboard
from canguard.bt.scripting.errors import ScriptError
from canguard.bt.scripting.values import (
    FLT_EPSILON,
    INT64_MAX,
    INT64_MIN,
    UNSET,
    convert_for_entry,
    describe,
    entry_type,
    is_number,
    logic_bool,
    number_text,
    string_to_real,
    to_int64,
    to_real,
    type_name,
)


@dataclass(slots=True)
class Env:
    """What a script runs against: a blackboard and the registered enums (name -> int)."""

    bb: ScriptBlackboard
    enums: Mapping[str, int] | None = None


def _set(op: str, pos: int, **operands: object) -> None:
    """Raise the error of the first operand (``left=``, ``right=``) that holds no value."""
    for side, value in operands.items():
        if value is UNSET:
            raise ScriptError(f"the {side} operand of the operator [{op}] is not initialized", pos)


def _real(value: int | float, pos: int) -> float:
    try:
        return to_real(value)
    except ValueError as exc:
        raise ScriptError(str(exc), pos) from None


def _arithmetic(op: str, a: float, b: float) -> float:
    """``a op b`` for ``+ - * /`` as C++ doubles (IEEE division)."""
    if op != "/":
        return a + b if op == "+" else a - b if op == "-" else a * b
    if b != 0.0:
        return a / b
    if a == 0.0 or math.isnan(a):
        return math.nan
    return math.copysign(math.inf, a) * math.copysign(1.0, b)


@dataclass(frozen=True)
class Expr:
    pos: int

    def evaluate(self, env: Env) -> object:
        raise NotImplementedError


@dataclass(frozen=True)
class Literal(Expr):
    value: object

    def evaluate(self, env: Env) -> object:
        return self.value


@dataclass(frozen=True)
class Name(Expr):
    name: str

    def evaluate(self, env: Env) -> object:
        # a registered enum wins over a blackboard entry of the same name, as in BT.CPP
        if env.enums is not None and self.name in env.enums:
            return float(env.enums[self.name])
        if not env.bb.has(self.name):
            raise ScriptError(
                f"variable not found: [{self.name}] (no blackboard entry and no enum of that name)", self.pos
            )
        try:
            return env.bb.get(self.name)
        except KeyError:
            return UNSET


@dataclass(frozen=True)
class Unary(Expr):
    op: str  # "-", "~" or "!"
    operand: Expr

    def evaluate(self, env: Env) -> object:
        value = self.operand.evaluate(env)
        if isinstance(value, (int, float)):
            if self.op == "-":
                return -_real(value, self.pos)
            if self.op == "!":
                return float(not bool(value))  # BT.CPP: logic results are the reals 1.0 / 0.0
            rv = float(value)
            if math.isnan(rv) or rv > INT64_MAX or rv < INT64_MIN:
                raise ScriptError(f"{describe(value)} is out of range for the bitwise operator [~]", self.pos)
            return float(~int(value))
        _set(self.op, self.pos, right=value)
        raise ScriptError(f"the operator [{self.op}] expects a number, got {describe(value)}", self.pos)


@dataclass(frozen=True)
class Binary(Expr):
    op: str  # + - * / .. & | ^ && ||
    lhs: Expr
    rhs: Expr

    def evaluate(self, env: Env) -> object:
        op = self.op
        lv = self.lhs.evaluate(env)
        rv = self.rhs.evaluate(env)
        _set(op, self.pos, left=lv, right=rv)
        if isinstance(lv, (int, float)) and isinstance(rv, (int, float)):
            if op in "+-*/":
                return _arithmetic(op, _real(lv, self.pos), _real(rv, self.pos))
            if op in ("&", "|", "^"):
                li, ri = to_int64(lv), to_int64(rv)
                if li is None or ri is None:
                    bad = lv if li is None else rv
                    raise ScriptError(
                        f"the bitwise operator [{op}] expects integers, got {describe(bad)}", self.pos
                    )
                return float(li & ri if op == "&" else li | ri if op == "|" else li ^ ri)
            if op in ("&&", "||"):
                lb, rb = logic_bool(lv), logic_bool(rv)
                if lb is None or rb is None:
                    bad = lv if lb is None else rv
                    raise ScriptError(
                        f"the logic operator [{op}] expects booleans (or the numbers 0 and 1), got {describe(bad)}",
                        self.pos,
                    )
                return float((lb and rb) if op == "&&" else (lb or rb))
        elif isinstance(lv, str) and isinstance(rv, str) and op in ("+", ".."):
            return lv + rv
        elif op == ".." and (isinstance(lv, str) or isinstance(rv, str)) and (is_number(lv) or is_number(rv)):
            left = lv if isinstance(lv, str) else number_text(lv)  # type: ignore[arg-type]
            right = rv if isinstance(rv, str) else number_text(rv)  # type: ignore[arg-type]
            return left + right
        raise _not_permitted(op, lv, rv, self.pos)


_TAKES = {"..": "at least one string (and otherwise numbers)", "+": "two numbers or two strings",
          "&&": "booleans, or the numbers 0 and 1", "||": "booleans, or the numbers 0 and 1"}


def _not_permitted(op: str, lv: object, rv: object, pos: int) -> ScriptError:
    """The error of a binary operator ``op`` given operands it does not take."""
    expected = _TAKES.get(op, "numbers")
    return ScriptError(
        f"operation not permitted: [{op}] between {describe(lv)} and {describe(rv)} (expected {expected})", pos
    )


_ORDER: dict[str, Callable[[Any, Any], bool]] = {
    "<": operator.lt, ">": operator.gt, "<=": operator.le, ">=": operator.ge}


def _compare(op: str, a: Any, b: Any) -> bool:
    """``a op b``; reals are equal within float's epsilon (BT.CPP's ``IsSame``)."""
    if op in ("==", "!="):
        return (abs(a - b) <= FLT_EPSILON if isinstance(a, float) else a == b) == (op == "==")
    return _ORDER[op](a, b)


@dataclass(frozen=True)
class Compare(Expr):
    ops: tuple[tuple[str, int], ...]  # (operator, its position), one per pair of operands
    operands: tuple[Expr, ...]

    def evaluate(self, env: Env) -> object:
        lv = self.operands[0].evaluate(env)
        for (op, pos), operand in zip(self.ops, self.operands[1:], strict=True):
            rv = operand.evaluate(env)
            _set(op, pos, left=lv, right=rv)
            a: object
            b: object
            if is_number(lv) and is_number(rv):
                a, b = _real(lv, pos), _real(rv, pos)  # type: ignore[arg-type]
            elif isinstance(lv, str) and isinstance(rv, str):
                a, b = lv, rv
            elif (isinstance(lv, str) and is_number(rv)) or (is_number(lv) and isinstance(rv, str)):
                text = lv if isinstance(lv, str) else rv
                number = string_to_real(text, env.enums)  # type: ignore[arg-type]
                if number is None:
                    raise ScriptError(
                        f"can't compare {describe(text)} with a number: expected a number's text, "
                        "true, false or an enum name",
                        pos,
                    )
                a = number if isinstance(lv, str) else _real(lv, pos)  # type: ignore[arg-type]
                b = number if isinstance(rv, str) else _real(rv, pos)  # type: ignore[arg-type]
            else:
                raise ScriptError(
                    f"can't mix different types in a comparison: {describe(lv)} [{op}] {describe(rv)}", pos
                )
            if not _compare(op, a, b):
                return 0.0  # BT.CPP: a comparison is the real 1.0 or 0.0
            lv = rv
        return 1.0


@dataclass(frozen=True)
class Ternary(Expr):
    condition: Expr
    then: Expr
    otherwise: Expr

    def evaluate(self, env: Env) -> object:
        value = self.condition.evaluate(env)
        if isinstance(value, str):
            chosen = value != ""
        elif isinstance(value, (int, float)):
            chosen = value != 0
        else:
            _set("?", self.pos, left=value)
            raise ScriptError(f"the condition of [?] must be a number or a string, got {describe(value)}", self.pos)
        return self.then.evaluate(env) if chosen else self.otherwise.evaluate(env)


@dataclass(frozen=True)
class Assign(Expr):
    op: str  # := = += -= *= /=
    name: str
    rhs: Expr

    def evaluate(self, env: Env) -> object:
        op, key, bb = self.op, self.name, env.bb
        if not bb.has(key) and op != ":=":
            raise ScriptError(
                f"the blackboard entry [{key}] doesn't exist yet; "
                f"to create it, use the operator [:=] instead of [{op}]",
                self.pos,
            )
        value = self.rhs.evaluate(env)
        _set(op, self.pos, right=value)
        try:
            current = bb.get(key)
        except KeyError:
            current = UNSET
        declared = bb.declared_type(key) if bb.has(key) else None
        if op in (":=", "="):
            # BT.CPP (ExprAssignment, Any::copyInto): an entry without a value takes any value as it is, but
            # a string into one a port declared as a number is parsed to that type
            as_is = current is UNSET and (declared is None or not isinstance(value, str) or declared is str)
            result = value if as_is else self._convert(value, current, declared, env)
        else:
            result = self._compound(value, current, declared, env)
        bb.set(key, result)
        return result

    def _convert(self, value: object, current: object, declared: type | None, env: Env) -> object:
        target = entry_type(current) if current is not UNSET else declared
        assert target is not None
        try:
            return convert_for_entry(value, target, env.enums)
        except ValueError as exc:
            what = "holds" if current is not UNSET else "is declared as"
            raise ScriptError(
                f"can't assign {describe(value)} to the entry [{self.name}], which {what} {type_name(target)} ({exc})",
                self.pos,
            ) from None

    def _compound(self, value: object, current: object, declared: type | None, env: Env) -> object:
        op = self.op
        _set(op, self.pos, left=current)
        result: object
        if isinstance(value, (int, float)):
            if not isinstance(current, (int, float)):
                raise ScriptError(
                    f"the operator [{op}] needs a numeric entry, but [{self.name}] holds {describe(current)}", self.pos
                )
            a, b = _real(current, self.pos), _real(value, self.pos)
            result = _arithmetic(op[0], a, b)
        elif isinstance(value, str):
            if op != "+=":
                raise ScriptError(f"the operator [{op}] is not supported for strings (only [+=] is)", self.pos)
            if not isinstance(current, str):
                raise ScriptError(
                    f"can't append {describe(value)} to the entry [{self.name}], which holds {describe(current)}",
                    self.pos,
                )
            result = current + value
        else:
            raise ScriptError(f"the operator [{op}] expects a number or a string, got {describe(value)}", self.pos)
        return self._convert(result, current, declared, env)

