"""The tuned config and tree, as text edits of the originals: layout and comments kept.

The config's other relative paths are made absolute: written elsewhere, it still finds them.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from pathlib import Path

import yaml

from canguard.errors import ConfigError

_TAG = re.compile(r"<([A-Za-z_][\w.:-]*)((?:\s+[\w.:-]+\s*=\s*(?:\"[^\"]*\"|'[^']*'))*)\s*(/?)>")
_ATTR = re.compile(r"([\w.:-]+)(\s*=\s*)(\"[^\"]*\"|'[^']*')")


def figure(value: float) -> str:
    """A figure as a tree or config writes it: the shortest text that reads back as the same float."""
    return repr(float(value)).removesuffix(".0")  # a float's repr never ends in ".0" after an exponent


def _named(text: str, node: str) -> list[re.Match[str]]:
    """The start tags of the elements named ``node``: by ``name``, else the ID (the tag, or a v3 ``ID=``)."""
    found = []
    for m in _TAG.finditer(text):
        attrs = {a.group(1): a.group(3)[1:-1] for a in _ATTR.finditer(m.group(2))}
        if attrs.get("name", attrs.get("ID", m.group(1))) == node:
            found.append(m)
    return found


def set_attributes(text: str, node: str, values: Mapping[str, float], where: str) -> str:
    """``text`` with the attributes of the element named ``node`` set to ``values`` (ConfigError: not one such)."""
    found = _named(text, node)
    if len(found) != 1:
        raise ConfigError(f"{where}: expected one element named {node!r} to write its tuned figures, "
                          f"found {len(found)}")
    m = found[0]
    head = m.group(2)
    for port, value in values.items():
        new = figure(value)
        hit = next((a for a in _ATTR.finditer(head) if a.group(1) == port), None)
        if hit is None:
            head += f' {port}="{new}"'
        else:
            head = f"{head[:hit.start(3)]}{hit.group(3)[0]}{new}{hit.group(3)[0]}{head[hit.end(3):]}"
    return f"{text[:m.start(2)]}{head}{text[m.end(2):]}"


def port_text(text: str, node: str, port: str) -> str | None:
    """The attribute text of ``port`` on the element named ``node`` (None: not written there)."""
    for m in _named(text, node)[:1]:
        return next((a.group(3)[1:-1] for a in _ATTR.finditer(m.group(2)) if a.group(1) == port), None)
    return None


def _mapping_get(node: yaml.Node, key: str) -> tuple[yaml.Node, yaml.Node] | None:
    if isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            if isinstance(k, yaml.ScalarNode) and k.value == key:
                return k, v
    return None


def tuned_config(text: str, config_dir: Path, tree_name: str, ages: Mapping[str, float]) -> str:
    """The config's text with the tuned ``max_age`` values, the tree beside it, and absolute paths."""
    root = yaml.compose(text)
    if root is None:
        return text
    edits = [_absolute(node, config_dir) for node in _path_nodes(root)]
    tree = _mapping_get(root, "tree")
    tree_file = _mapping_get(tree[1], "file") if tree is not None else None
    if tree_file is not None:
        node = tree_file[1]
        edits.append((node.start_mark.index, node.end_mark.index, json.dumps(tree_name)))  # YAML-quoted
    sources = _mapping_get(root, "sources")
    for name, seconds in ages.items():
        source = _mapping_get(sources[1], name) if sources is not None else None
        if source is None:
            raise ConfigError(f"sources.{name}: not found in the config text to write its max_age")
        edits.append(_age_edit(text, source[1], figure(seconds)))
    for start, end, new in sorted((e for e in edits if e is not None), reverse=True):
        text = text[:start] + new + text[end:]
    return text


def _path_nodes(root: yaml.Node) -> list[yaml.Node]:
    """The scalars of the paths a config names besides its tree: ``dbc``, ``events``, ``state.file``, ``eds``."""
    dbc = _mapping_get(root, "dbc")
    out: list[yaml.Node] = [] if dbc is None else dbc[1].value if isinstance(dbc[1], yaml.SequenceNode) else [dbc[1]]
    state = _mapping_get(root, "state")
    canopen = _mapping_get(root, "canopen")
    drives = canopen[1].value if canopen is not None and isinstance(canopen[1], yaml.MappingNode) else []
    found = [_mapping_get(root, "events"), state and _mapping_get(state[1], "file"),
             *(_mapping_get(drive, "eds") for _key, drive in drives)]
    return out + [hit[1] for hit in found if hit is not None]


def _absolute(node: yaml.Node, config_dir: Path) -> tuple[int, int, str] | None:
    """The edit that makes a relative path scalar absolute (None: already absolute, or not a path)."""
    if not isinstance(node, yaml.ScalarNode) or not node.value:
        return None
    path = Path(node.value).expanduser()
    if path.is_absolute():
        return None
    return node.start_mark.index, node.end_mark.index, json.dumps(str((config_dir / path).resolve()))


def _age_edit(text: str, mapping: yaml.Node, value: str) -> tuple[int, int, str]:
    """Where and what to write for a source's ``max_age``: in place, or added to its mapping."""
    hit = _mapping_get(mapping, "max_age")
    if hit is not None:
        return hit[1].start_mark.index, hit[1].end_mark.index, value
    assert isinstance(mapping, yaml.MappingNode)
    if mapping.flow_style:
        close = text.rindex("}", 0, mapping.end_mark.index)
        body = text[mapping.start_mark.index + 1:close].strip()
        return close, close, (", " if body else "") + f"max_age: {value}"
    last = mapping.value[-1][1]
    first_key = mapping.value[0][0]
    indent = " " * first_key.start_mark.column
    end = text.find("\n", last.end_mark.index)
    end = len(text) if end < 0 else end
    return end, end, f"\n{indent}max_age: {value}"
