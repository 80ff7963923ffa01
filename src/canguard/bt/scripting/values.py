"""Values of the scripting language and BehaviorTree.CPP 4's rules for converting them (``operators.hpp``,
``safe_any.hpp``): int64 integers, doubles and strings as ``int``, ``float``, ``str`` (a ``bool`` is a number);
every arithmetic result is a real; an entry keeps its type.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping

FLT_EPSILON = 1.1920928955078125e-07  # reals this close are equal (BT.CPP's IsSame)

INT64_MIN = -(2**63)
INT64_MAX = 2**63 - 1
EXACT_INT = 2**53 - 1  # the largest integer a double holds exactly


class _Unset:
    """The value of an entry that exists but holds nothing yet (BT.CPP's empty ``Any``)."""

    def __repr__(self) -> str:
        return "UNSET"


UNSET = _Unset()

_NUMBER_TEXT = re.compile(r"-?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|-?(?:inf|infinity|nan)", re.IGNORECASE)


def is_number(value: object) -> bool:
    return isinstance(value, (int, float))


def describe(value: object) -> str:
    """``the integer 3``, ``the real 2.5``, ``the string 'a'``, ``the boolean true``."""
    if isinstance(value, bool):
        return f"the boolean {'true' if value else 'false'}"
    if isinstance(value, int):
        return f"the integer {value}"
    if isinstance(value, float):
        return f"the real {value!r}"
    if isinstance(value, str):
        return f"the string {value!r}"
    if value is UNSET:
        return "an unset value"
    return f"a value of type {type(value).__name__}"


def type_name(t: type) -> str:
    """``an integer``, ``a real``, ``a boolean``, ``a string`` or ``a <class name>``."""
    names = {bool: "a boolean", int: "an integer", float: "a real", str: "a string"}
    return names.get(t, f"a {t.__name__}")


def to_real(value: int | float) -> float:
    """A number as a double; ValueError when an integer is too large to be exact."""
    if isinstance(value, float):
        return value
    if abs(value) > EXACT_INT:
        raise ValueError(f"the integer {value} is too large to be a real without loss (limit 2**53)")
    return float(value)


def to_int64(value: int | float) -> int | None:
    """A number as an int64, or None when it is not integral or out of range."""
    if isinstance(value, int):
        number = int(value)
        return number if INT64_MIN <= number <= INT64_MAX else None
    if not math.isfinite(value) or value != math.floor(value) or not (INT64_MIN <= value < 2.0**63):
        return None
    return int(value)


def logic_bool(value: object) -> bool | None:
    """A value as ``&&``/``||``/conditions see it, or None when it does not convert."""
    if isinstance(value, bool):
        return value
    if isinstance(value, int):
        return bool(value) if value in (0, 1) else None
    if isinstance(value, float):
        return value != 0.0  # nan is true, as a C++ cast
    return None


def as_condition(value: object) -> bool:
    """The boolean a condition takes from a script's value (:func:`logic_bool`); ValueError if none."""
    result = logic_bool(value)
    if result is None:
        raise ValueError(f"expected a boolean result (true/false, or a number 0 or 1), got {describe(value)}")
    return result


def number_text(value: int | float) -> str:
    """A number as BT.CPP turns it into a string for ``..``: integers as is, reals as ``%f``."""
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, int):
        return str(value)
    return f"{value:f}"


def string_to_real(text: str, enums: Mapping[str, int] | None) -> float | None:
    """A string compared with (or assigned to) a number: 'true', 'false', an enum name or a number's text;
    None otherwise (BT.CPP's ``StringToDouble``)."""
    if text == "true":
        return 1.0
    if text == "false":
        return 0.0
    if enums is not None and text in enums:
        return float(enums[text])
    if _NUMBER_TEXT.fullmatch(text):
        return float(text)
    return None


def convert_for_entry(value: object, target: type, enums: Mapping[str, int] | None) -> object:
    """``value`` converted to ``target``, its entry's type; ValueError saying what it takes if BT.CPP refuses."""
    if target is str:
        if isinstance(value, str):
            return value
        raise ValueError("expected a string")
    if target in (bool, int, float):
        number: object = value
        if isinstance(value, str):
            number = string_to_real(value, enums)
            if number is None:
                raise ValueError("expected a number, or a string holding one, true, false or an enum name")
        if not isinstance(number, (int, float)):
            raise ValueError("expected a number")
        if target is float:
            return to_real(number)
        if target is bool:
            if isinstance(number, bool):
                return number
            if number in (0, 1):
                return bool(number)
            raise ValueError("expected true, false, 0 or 1")
        converted = to_int64(number)
        if converted is None:
            raise ValueError("expected an integral number within 64 bits")
        return converted
    if isinstance(value, target):
        return value
    raise ValueError(f"expected {type_name(target)}")


def entry_type(value: object) -> type:
    """The type an entry holding ``value`` keeps."""
    for kind in (bool, int, float, str):
        if isinstance(value, kind):
            return kind
    return type(value)
