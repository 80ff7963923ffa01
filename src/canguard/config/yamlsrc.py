"""YAML with line numbers: duplicate keys refused, each key path's line, and the words of a problem."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

import yaml

from canguard.errors import clip, closest, quote

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

_FastUniqueKeyLoader: Any = None
if getattr(yaml, "__with_libyaml__", False):

    class _CUniqueKeyLoader(yaml.CSafeLoader):
        """The same loader on libyaml's parser (about 8x faster on a config; same constructors)."""

    _CUniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_unique_mapping)
    _FastUniqueKeyLoader = _CUniqueKeyLoader


def load_yaml(text: str) -> Any:
    """``text`` as :class:`_UniqueKeyLoader` reads it, through libyaml when PyYAML has it (its errors: the pure-Python
    loader's, which reads the text again)."""
    if _FastUniqueKeyLoader is not None:
        try:
            return yaml.load(text, Loader=_FastUniqueKeyLoader)
        except yaml.YAMLError:
            pass
    return yaml.load(text, Loader=_UniqueKeyLoader)


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


def _compose(text: str) -> yaml.Node | None:
    """The node tree of ``text`` (each node with its line), as :func:`load_yaml` reads; None on a problem."""
    for loader in (_FastUniqueKeyLoader, _UniqueKeyLoader):
        if loader is not None:
            try:
                return yaml.compose(text, Loader=loader)
            except yaml.YAMLError:
                continue
    return None


def key_lines(text: str) -> dict[str, int]:
    """The line (1-based) of every key path of a YAML document (``sources.axis0.signal``, ``task.frames[1]``)."""
    root = _compose(text)
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
    k = key
    while k:
        if k in lines:
            return lines[k]
        cut = max(k.rfind("."), k.rfind("["))
        if cut <= 0:
            return None
        k = k[:cut]
    return None
