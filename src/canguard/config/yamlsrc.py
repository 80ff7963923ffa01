"""YAML with line numbers, and a config file's problems: their words and the generic checks of a value."""

from __future__ import annotations

import math
import os
from collections.abc import Iterator, Mapping
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

import yaml

from canguard.errors import ConfigError, clip, closest, quote

_SECONDS_KEYS = ("period", "repeat", "max_age", "deadline", "save_period")
_CONFIRM_OPS: dict[str, Literal["<", ">", "=="]] = {"below": "<", "above": ">", "equals": "=="}
_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


class _UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate mapping keys (a typo must not pass silently)."""


def _construct_unique_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode) -> dict[Any, Any]:
    loader.flatten_mapping(node)
    mapping: dict[Any, Any] = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in mapping:
            raise yaml.constructor.ConstructorError("while constructing a mapping", node.start_mark,
                                                    f"found duplicate key {key!r}", key_node.start_mark)
        mapping[key] = loader.construct_object(value_node, deep=True)
    return mapping


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_unique_mapping)

_LOADERS: tuple[Any, ...] = (_UniqueKeyLoader,)
"""libyaml's loader first where PyYAML has it (8x faster); a problem is reported in the pure-Python one's words."""
if getattr(yaml, "__with_libyaml__", False):

    class _CUniqueKeyLoader(yaml.CSafeLoader):
        """The same loader on libyaml's parser."""

    _CUniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_unique_mapping)
    _LOADERS = (_CUniqueKeyLoader, _UniqueKeyLoader)


def _read(text: str, read: Any) -> Any:
    """``read(text, Loader=...)`` with each of :data:`_LOADERS` until one succeeds (the last one's error raised)."""
    for loader in _LOADERS[:-1]:
        try:
            return read(text, Loader=loader)
        except yaml.YAMLError:
            pass
    return read(text, Loader=_LOADERS[-1])


def load_yaml(text: str) -> Any:
    """``text`` as :class:`_UniqueKeyLoader` reads it, through libyaml when PyYAML has it."""
    return _read(text, yaml.load)


def _shown(value: Any) -> str:
    """A value as an error quotes it: a string capped (:func:`canguard.errors.quote`), else its repr, capped."""
    return quote(value) if isinstance(value, str) else clip(repr(value))


def _found(value: Any) -> str:
    """How a found value reads in an error message."""
    if value is None:
        return "nothing"
    if isinstance(value, bool):
        return f"{value!r} (a boolean)"
    if isinstance(value, (str, int, float)):
        return _shown(value)
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return f"a {type(value).__name__}"


def _closest(word: Any, choices: Any) -> str:
    """``"; closest: a, b"`` for the nearest names, or the known names when none is near."""
    names = sorted({str(c) for c in choices})
    if not names:
        return ""
    near = closest(str(word), names, n=3, spread=0.15)
    if near:
        return "; closest: " + ", ".join(near)
    shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
    return f"; known: {shown}"


def _path(parent: str, key: Any) -> str:
    return f"{parent}.{key}" if parent else str(key)


def key_lines(text: str) -> dict[str, int]:
    """The line (1-based) of every key path of a YAML document (``sources.axis0.signal``, ``task.frames[1]``)."""
    try:
        root = _read(text, yaml.compose)
    except yaml.YAMLError:
        root = None
    lines: dict[str, int] = {}
    constructor = yaml.SafeLoader("")

    def walk(node: yaml.Node, key: str) -> None:
        if isinstance(node, yaml.MappingNode):
            for key_node, value_node in node.value:
                if not isinstance(key_node, yaml.ScalarNode):
                    continue
                try:  # the key as the loader sees it (``1:`` is the int 1, as in the problem's path)
                    name = constructor.construct_object(key_node)
                except yaml.YAMLError:
                    name = key_node.value
                sub = _path(key, name)
                lines.setdefault(sub, key_node.start_mark.line + 1)
                walk(value_node, sub)
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                sub = f"{key}[{i}]"
                lines.setdefault(sub, item.start_mark.line + 1)
                walk(item, sub)

    if root is not None:
        walk(root, "")
    return lines


def _line_of(lines: Mapping[str, int], key: str) -> int | None:
    """The line of ``key``, else of its nearest enclosing key that is in the file (a missing key)."""
    while key and key not in lines:
        key = key[:max(key.rfind("."), key.rfind("["), 0)]
    return lines.get(key) if key else None


class Checks:
    """One pass over one config file: the problems found so far and the generic checks of a value."""

    def __init__(self, path: Path, display: str, text: str = "") -> None:
        self.base = path.parent
        self.display = display
        self.text = text
        self.problems: list[str] = []
        self.located: list[str] = []  # ``problems`` with the line of their key: ``file:line: key: ...``
        self.bus_names: tuple[str, ...] = ()  # the configured buses, which every ``bus:`` key names

    @cached_property
    def lines(self) -> dict[str, int]:
        """Each key path's line in :attr:`text`, worked out when a problem first asks (a valid config never does)."""
        return key_lines(self.text)

    def problem(self, key: str, found: str, expected: str) -> None:
        """Record ``file: key: found X, expected Y`` (and its located form ``file:line: key: ...``)."""
        self.problems.append(f"{self.display}: {key}: found {found}, expected {expected}")
        line = _line_of(self.lines, key)
        where = self.display if line is None else f"{self.display}:{line}"
        self.located.append(f"{where}: {key}: found {found}, expected {expected}")

    def fail(self) -> ConfigError:
        """The ConfigError listing every problem recorded so far."""
        return ConfigError(self.problems, self.located)

    def mapping(self, value: Any, key: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> bool:
        """Check ``value`` is a mapping with only ``allowed`` keys and every ``required`` one."""
        if not isinstance(value, Mapping):
            self.problem(key or "(top level)", _found(value), f"a mapping with keys {', '.join(allowed)}")
            return False
        for k in value:
            if k not in allowed:
                self.problem(_path(key, k), f"unknown key {_shown(k)}",
                             f"one of {', '.join(allowed)}" + _closest(k, allowed))
        for k in required:
            if k not in value:
                self.problem(_path(key, k), "nothing", "a value (required key)")
        return True

    def named(self, value: Mapping[Any, Any], key: str, what: str) -> Iterator[tuple[str, Any, str]]:
        """Each ``name: body`` of ``value`` and its key path; a problem for each name that is not a string."""
        for name, body in value.items():
            if isinstance(name, str) and name:
                yield name, body, _path(key, name)
            else:
                self.problem(_path(key, name), _found(name), f"{what} (a string)")

    def section(self, value: Any, key: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> Any:
        """An optional section: ``value`` when it is a mapping (its keys checked by :meth:`mapping`), else None."""
        return value if value is not None and self.mapping(value, key, allowed, required) else None

    def choice(self, mapping: Mapping[str, Any], name: str, key: str, options: tuple[Any, ...], default: Any) -> Any:
        """``mapping[name]`` (``default`` when left out) if it is one of ``options``, else a problem and ``default``."""
        value = mapping.get(name, default)
        if type(value) is type(options[0]) and value in options:
            return value
        shown = [str(o).lower() if isinstance(o, bool) else str(o) for o in options]
        self.problem(_path(key, name), _found(value), ", ".join(shown[:-1]) + " or " + shown[-1])
        return default

    def string(self, value: Any, key: str, expected: str = "a string") -> str | None:
        if isinstance(value, str) and value:
            return value
        self.problem(key, _found(value), expected)
        return None

    def number(self, value: Any, key: str, *, positive: bool = False) -> float | None:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        if ok and (not positive or value > 0):
            return float(value)
        unit = " in seconds" if key.rsplit(".", 1)[-1] in _SECONDS_KEYS else ""
        self.problem(key, _found(value), f"a number > 0{unit}" if positive else "a finite number")
        return None

    def seconds(self, mapping: Mapping[str, Any], name: str, key: str, default: float) -> float:
        if name not in mapping:
            return default
        value = self.number(mapping[name], _path(key, name), positive=True)
        return default if value is None else value

    def file_path(self, value: Any, key: str) -> Path | None:
        text = self.string(value, key, "a file path (relative to the config file or absolute)")
        if text is None:
            return None
        try:
            p = Path(text).expanduser()
        except RuntimeError:  # ~user of a user that does not exist, or no home directory
            self.problem(key, _found(text), "a file path whose ~ names an existing user's home directory")
            return None
        return Path(os.path.normpath(p if p.is_absolute() else self.base / p))

    def bus(self, mapping: Mapping[str, Any], key: str) -> str:
        """Resolve ``mapping``'s ``bus:`` key (left out: the only bus)."""
        value = mapping.get("bus")
        key = _path(key, "bus")
        if value is None:
            if len(self.bus_names) == 1:
                return self.bus_names[0]
            if self.bus_names:
                buses = ", ".join(self.bus_names)
                self.problem(key, "nothing", f"one of the buses {buses} (several buses are configured)")
            return ""
        if not isinstance(value, str) or value not in self.bus_names:
            if self.bus_names:
                self.problem(key, _found(value), "a configured bus" + _closest(value, self.bus_names))
            return ""
        return value
