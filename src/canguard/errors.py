"""The one exception tree of canguard.

Every error also inherits the matching built-in (ValueError, OSError). ConfigError and TreeError carry every
problem one load found (``problems``): ``canguard check`` prints them all, one per line.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from typing import Any


class CanguardError(Exception):
    """Base class of every error canguard raises on purpose."""


MAX_SHOWN = 100
"""At most this many problems are printed; the rest are counted ("... and N more")."""


def render_problems(problems: Iterable[str], limit: int = MAX_SHOWN) -> str:
    """``problems`` one per line, the first ``limit`` of them, then ``... and N more``."""
    lines = list(problems)
    if len(lines) <= limit:
        return "\n".join(lines)
    return "\n".join([*lines[:limit], f"... and {len(lines) - limit} more"])


QUOTE_CHARS = 100
"""An error quotes at most this many characters of a line or a value it found (then its length)."""


def _printable(text: str, limit: int) -> tuple[str, bool]:
    """``text`` with control characters escaped (``\\x00``), cut to ``limit`` characters; True when cut."""
    out: list[str] = []
    n = 0
    for c in text:
        shown = c if c.isprintable() else repr(c)[1:-1]
        n += len(shown)
        if n > limit:
            return "".join(out), True
        out.append(shown)
    return "".join(out), False


def clip(text: str, limit: int = QUOTE_CHARS) -> str:
    """``text`` on one printable line of at most about ``limit`` characters; a longer one is cut, with its length."""
    shown, cut = _printable(text, limit)
    return f"{shown}... ({len(text)} characters in all)" if cut else shown


def quote(text: str, limit: int = QUOTE_CHARS) -> str:
    """``text`` in quotes, as :func:`clip` shows it: a bad line or value, however long or binary, on one line."""
    shown, cut = _printable(text, limit)
    return f"'{shown}'... ({len(text)} characters in all)" if cut else f"'{shown}'"


def closest(word: str, choices: Iterable[str], n: int = 5, cutoff: float = 0.5, spread: float = 1.0) -> list[str]:
    """The ``n`` choices nearest to ``word``, closest first: case ignored, difflib's similarity >= ``cutoff``
    and within ``spread`` of the best one (a small spread gives a clear typo one answer, not a list)."""
    word = word.lower()
    scored = []
    for c in set(choices):
        m = difflib.SequenceMatcher(None, word, c.lower())
        if m.real_quick_ratio() >= cutoff and m.quick_ratio() >= cutoff:
            scored.append((-m.ratio(), c))
    scored.sort()
    if not scored:
        return []
    best = -scored[0][0]
    return [c for r, c in scored[:n] if -r >= cutoff and -r >= best - spread]


class ConfigError(CanguardError, ValueError):
    """One or more problems in a YAML config file: ``problems``, each ``file: key: found X, expected Y``;
    ``located``, the same with the key's line (``file:line: key: ...``) where known, is what ``str()`` lists."""

    partial: Any = None
    """The sound parts of the config (a ``canguard.config.schema.PartialConfig``), set by the loader."""

    def __init__(self, problems: str | Iterable[str], located: Iterable[str] | None = None) -> None:
        self.problems: list[str] = [problems] if isinstance(problems, str) else list(problems)
        self.located: list[str] = list(located) if located is not None else list(self.problems)
        super().__init__(render_problems(self.located))


class TreeError(CanguardError, ValueError):
    """A behaviour tree that does not load: ``problems``, each ``file:line: node ...: what``, one per line."""

    def __init__(self, problems: str | Iterable[str]) -> None:
        self.problems: list[str] = [problems] if isinstance(problems, str) else list(problems)
        super().__init__(render_problems(self.problems))


class LogFormatError(CanguardError, ValueError):
    """A line of a recorded CAN log that does not parse (names file:line and the text)."""


class BusError(CanguardError, OSError):
    """A CAN bus that cannot be opened or that went away."""


class StateFileError(CanguardError, OSError):
    """An I²t state file that cannot be read or written."""
