"""The blackboard scope of each SubTree instance, as py_trees' parser remaps ports, for scripts and SetBlackboard."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

from py_trees.blackboard import Blackboard

INT_TEXT = re.compile(r"-?[0-9]+\Z")
REAL_TEXT = re.compile(r"-?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?\Z")

SUBTREE = "SubTree"


def typed_literal(text: str) -> int | float | str:
    """A literal port value on a SubTree element as BT.CPP stores it: an integer, else a real, else the text."""
    return int(text) if INT_TEXT.match(text) else float(text) if REAL_TEXT.match(text) else text


def subtree_ports(elem: ET.Element) -> tuple[dict[str, str], dict[str, str]]:
    """A ``<SubTree>`` element's ports: those remapped (port -> the parent's entry name), and the literals."""
    remaps: dict[str, str] = {}
    literals: dict[str, str] = {}
    for attr, value in elem.attrib.items():
        if attr in ("ID", "name") or attr.startswith("_"):
            continue
        text = value.strip()
        if text.startswith("{") and text.endswith("}"):
            inner = text[1:-1].strip()
            remaps[attr] = attr if inner == "=" else inner
        else:
            literals[attr] = value
    return remaps, literals


@dataclass(frozen=True)
class Inline:
    """An inlined ``_autoremap`` subtree instance: where its ``_`` entries live, and its element's ports."""

    private: str  # the path of its _private entries and literal ports, under the parent's namespace
    remaps: Mapping[str, str]  # port -> the parent's entry name
    literals: Mapping[str, str]  # port -> the literal text on the element


@dataclass(eq=False)
class TreeBlackboard:
    """One SubTree instance's blackboard scope (``namespace``: py_trees' namespace of it), and the scripting
    language's view of py_trees' blackboard inside it."""

    namespace: str
    aliases: dict[str, str] = field(default_factory=dict)  # local name -> the parent's storage key
    literals: dict[str, int | float | str] = field(default_factory=dict)  # storage key -> literal value
    parent: str = ""  # the namespace the SubTree element is written in ("" for the main tree)
    element: ET.Element | None = None  # the <SubTree> element (None for the main tree)
    private: str = ""  # in an inlined _autoremap subtree: the path its _ entries live under
    declared: Mapping[str, type] = field(default_factory=dict)  # typed ports' entries, by storage key

    def inlined(self, inline: Inline) -> TreeBlackboard:
        """This scope as seen from inside an inlined ``_autoremap`` subtree."""
        own = self.namespace + inline.private + "/"
        aliases = {**self.aliases, **{port: self.key(name) for port, name in inline.remaps.items()},
                   **{port: own + port for port in inline.literals}}
        literals = {own + port: typed_literal(text) for port, text in inline.literals.items()}
        return replace(self, aliases=aliases, literals=literals, private=inline.private)

    def key(self, name: str) -> str:
        """The storage key of entry ``name`` as seen from this scope (``@name``: the root's)."""
        if name.startswith("@"):
            return "/" + name[1:]
        if name.startswith("/"):
            return name
        if self.private and name.startswith("_"):
            return self.namespace + self.private + "/" + name
        alias = self.aliases.get(name)
        return alias if alias is not None else self.namespace + name

    def has(self, key: str) -> bool:
        """Whether the entry exists (with or without a value: a typed port declares it)."""
        full = self.key(key)
        return full in Blackboard.storage or full in self.declared

    def get(self, key: str) -> object:
        """The entry's value; KeyError when the entry does not exist or holds no value."""
        return Blackboard.storage[self.key(key)]

    def set(self, key: str, value: object) -> None:
        """Create or overwrite the entry's value."""
        Blackboard.storage[self.key(key)] = value

    def declared_type(self, key: str) -> type | None:
        """The type a typed port declared the entry with, or None: any type."""
        return self.declared.get(self.key(key))

    def unset(self, key: str) -> None:
        """Remove the entry (nothing when there is none)."""
        Blackboard.storage.pop(self.key(key), None)


def subtree_scopes(trees: Mapping[str, ET.Element], main_id: str,
                   declared: Mapping[str, type]) -> dict[str, TreeBlackboard]:
    """Every SubTree instance's scope under the validated tree ``main_id``, by namespace (``/``: the main's)."""
    root = TreeBlackboard("/", declared=declared)
    scopes = {"/": root}

    def walk(elem: ET.Element, scope: TreeBlackboard) -> None:
        for child in elem:
            if child.tag != SUBTREE:
                walk(child, scope)
                continue
            target = child.attrib.get("ID", "")
            sub = TreeBlackboard(scope.namespace + child.attrib.get("name", target) + "/", parent=scope.namespace,
                                 element=child, declared=declared)
            remaps, literals = subtree_ports(child)
            sub.aliases.update({port: scope.key(name) for port, name in remaps.items()})
            sub.literals.update({sub.namespace + port: typed_literal(text) for port, text in literals.items()})
            scopes[sub.namespace] = sub
            if target in trees:
                walk(trees[target], sub)

    if main_id in trees:
        walk(trees[main_id], root)
    return scopes
