"""Tokenizer of BehaviorTree.CPP's scripting language: one pattern; a malformed number (``65.``, ``3foo``,
``0x``, ``3e+``), an unterminated string or a stray character is an ``error`` token the parser reports."""

from __future__ import annotations

import re
from dataclasses import dataclass

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


@dataclass(frozen=True)
class Token:
    """One token: ``kind`` int, real, str, bool, name, op, end or error; ``text`` (a string's without quotes)."""

    kind: str
    text: str
    pos: int
    reason: str = ""


def _number(m: re.Match[str]) -> Token:
    text, pos = m["number"], m.start()
    bad = next((group for group in _NUMBER_ERRORS if m[group] is not None), None)
    if m["hex"] == "":
        reason = "expected hexadecimal digits after '0x'"
    elif bad is not None:
        reason = _NUMBER_ERRORS[bad]
    else:
        return Token("real" if m["fraction"] or m["exponent"] else "int", text, pos)
    return Token("error", text, pos, f"invalid number '{text}': {reason}")


def tokenize(src: str) -> list[Token]:
    """The tokens of ``src``, ending with one ``end`` token (never raises)."""
    tokens: list[Token] = []
    for m in _TOKEN.finditer(src):
        pos = m.start()
        if m["str"] is not None:
            tokens.append(Token("str", m["str"], pos))
        elif m["open"] is not None:
            tokens.append(Token("error", m["open"], pos, "unterminated string: expected a closing '"))
        elif m["number"] is not None:
            tokens.append(_number(m))
        elif m["name"] is not None:
            tokens.append(Token("bool" if m["name"] in ("true", "false") else "name", m["name"], pos))
        elif m["op"] is not None:
            tokens.append(Token("op", m["op"], pos))
        elif m["stray"] is not None:
            tokens.append(Token("error", m["stray"], pos, f"unexpected character {m['stray']!r}"))
    tokens.append(Token("end", "", len(src)))
    return tokens
