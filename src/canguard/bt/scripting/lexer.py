"""Tokenizer of BehaviorTree.CPP's scripting language.

Tokens: integers (``42``, ``0x2A``), reals (``3.14``, ``3e2``, ``3.14e-2``),
'single-quoted' strings (no escapes, as BT.CPP), ``true``/``false``, names
(``[A-Za-z_@][A-Za-z0-9_]*``; ``@`` marks a root-blackboard key), and the
operators ``:= = += -= *= /= + - * / .. & | ^ ~ ! && || == != < <= > >= ? : ( ) ;``.
Whitespace is space, tab, newline and carriage return. A malformed number
(``65.``, ``3foo``, ``0x``, ``3e+``), an unterminated string or a stray
character becomes an ``error`` token, which the parser reports with its column.
"""

from __future__ import annotations

from dataclasses import dataclass

TWO_CHAR_OPS = frozenset({"..", "&&", "||", "==", "!=", "<=", ">=", ":=", "+=", "-=", "*=", "/="})
ONE_CHAR_OPS = frozenset("+-*/&|^~!<>=?:();")
_WHITESPACE = " \t\n\r"
_DIGITS = "0123456789"
_HEX = "0123456789abcdefABCDEF"
_ALPHA = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"


@dataclass(frozen=True)
class Token:
    """One token. ``kind``: int, real, str, bool, name, op, end or error; ``text``: the
    source text (a string's content without quotes; an error's reason is in ``reason``)."""

    kind: str
    text: str
    pos: int
    reason: str = ""


def _ident_start(c: str) -> bool:
    return c in _ALPHA or c == "_" or c == "@"


def _ident_char(c: str) -> bool:
    return c in _ALPHA or c in _DIGITS or c == "_"


def _skip_garbage(src: str, i: int) -> int:
    while i < len(src) and (_ident_char(src[i]) or src[i] == "."):
        i += 1
    return i


def _scan_hex(src: str, start: int) -> tuple[int, str]:
    """End of a hex literal at ``start`` (``0x``...), and an error reason or ''."""
    i = start + 2
    reason = ""
    if i >= len(src) or src[i] not in _HEX:
        reason = "expected hexadecimal digits after '0x'"
    while i < len(src) and src[i] in _HEX:
        i += 1
    if i < len(src) and (src[i] == "." or _ident_char(src[i])):
        reason = reason or "a hexadecimal integer has no fraction, exponent or letters after its digits"
        i = _skip_garbage(src, i)
    return i, reason


def _scan_decimal(src: str, start: int) -> tuple[int, bool, str]:
    """End of a decimal number at ``start``, whether it is real, and an error reason or ''."""
    n = len(src)
    i = start
    real = False
    while i < n and src[i] in _DIGITS:
        i += 1
    if i < n and src[i] == ".":
        if i + 1 < n and src[i + 1] == ".":
            pass  # "65..x": the integer 65, then the concatenation operator
        elif i + 1 < n and src[i + 1] in _DIGITS:
            real = True
            i += 1
            while i < n and src[i] in _DIGITS:
                i += 1
        else:
            return _skip_garbage(src, i + 1), False, "expected digits after the decimal point"
    if i < n and src[i] in "eE":
        real = True
        i += 1
        if i < n and src[i] in "+-":
            i += 1
        if i >= n or src[i] not in _DIGITS:
            return i, False, "expected digits in the exponent"
        while i < n and src[i] in _DIGITS:
            i += 1
    if i < n and _ident_start(src[i]):
        while i < n and _ident_char(src[i]):
            i += 1
        return i, False, "a number must not be followed by letters (names start with a letter or '_')"
    return i, real, ""


def tokenize(src: str) -> list[Token]:
    """The tokens of ``src``, ending with one ``end`` token (never raises)."""
    tokens: list[Token] = []
    n = len(src)
    i = 0
    while i < n:
        c = src[i]
        if c in _WHITESPACE:
            i += 1
            continue
        start = i
        if c == "'":
            close = src.find("'", i + 1)
            if close < 0:
                tokens.append(Token("error", src[start:], start, "unterminated string: expected a closing '"))
                i = n
            else:
                tokens.append(Token("str", src[start + 1 : close], start))
                i = close + 1
        elif c in _DIGITS:
            if c == "0" and i + 1 < n and src[i + 1] in "xX":
                i, reason = _scan_hex(src, start)
                kind = "int"
            else:
                i, real, reason = _scan_decimal(src, start)
                kind = "real" if real else "int"
            text = src[start:i]
            if reason:
                tokens.append(Token("error", text, start, f"invalid number '{text}': {reason}"))
            else:
                tokens.append(Token(kind, text, start))
        elif _ident_start(c):
            i += 1
            while i < n and _ident_char(src[i]):
                i += 1
            text = src[start:i]
            tokens.append(Token("bool" if text in ("true", "false") else "name", text, start))
        elif src[i : i + 2] in TWO_CHAR_OPS:
            tokens.append(Token("op", src[i : i + 2], start))
            i += 2
        elif c in ONE_CHAR_OPS:
            tokens.append(Token("op", c, start))
            i += 1
        else:
            tokens.append(Token("error", c, start, f"unexpected character {c!r}"))
            i += 1
    tokens.append(Token("end", "", n))
    return tokens
