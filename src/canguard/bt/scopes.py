"""The blackboard scope of each SubTree instance: BT.CPP's remapping entries, for scripts and SetBlackboard.

py_trees' parser gives each SubTree instance a namespace and remaps the ports inside; a
:class:`Scope` gives scripts, pre/post conditions and Set/UnsetBlackboard the same view: a
remapped name is the parent's entry, a literal on the element a typed entry of the instance,
``@key`` the root's (docs/trees.md, "The blackboard").
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field

from py_trees.blackboard import Blackboard

INT_TEXT = re.compile(r"-?[0-9]+\Z")
REAL_TEXT = re.compile(r"-?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?\Z")

SUBTREE = "SubTree"


def typed_literal(text: str) -> int | float | str:
    """A literal port value on a SubTree element as BT.CPP stores it: an integer, else a real, else the text."""
    if INT_TEXT.match(text):
        return int(text)
    if REAL_TEXT.match(text):
        return float(text)
    return text


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

    private: str
    """The path (under the parent's namespace) of its ``_private`` entries and its literal ports."""
    remaps: Mapping[str, str]
    """Port -> the parent's entry name it remaps to (``out="{result}"``)."""
    literals: Mapping[str, str]
    """Port -> the literal text given on the element (``q="7;8"``): a typed entry of the instance."""


@dataclass
class Scope:
    """The names of one SubTree instance's blackboard (``namespace``: py_trees' namespace of it)."""

    namespace: str
    aliases: dict[str, str] = field(default_factory=dict)
    """Local name -> the storage key of the parent's entry it remaps to."""
    literals: dict[str, int | float | str] = field(default_factory=dict)
    """Local entries created from literal values on the SubTree element (storage key -> value)."""
    parent: str = ""
    """The namespace of the tree the SubTree element is written in ("" for the main tree's scope)."""
    element: ET.Element | None = None
    """The ``<SubTree>`` element (None for the main tree's scope)."""
    private: str = ""
    """In an inlined ``_autoremap`` subtree: the path its ``_`` entries live under (BT.CPP keeps them in the
    subtree; see :mod:`canguard.bt.xmlread`)."""

    def inlined(self, inline: Inline) -> Scope:
        """This scope as seen from inside an inlined ``_autoremap`` subtree: its remapped ports are aliases of
        the parent's entries, its literal ports and ``_`` entries its own."""
        own = self.namespace + inline.private + "/"
        aliases = dict(self.aliases)
        aliases.update({port: self.key(name) for port, name in inline.remaps.items()})
        aliases.update({port: own + port for port in inline.literals})
        literals = {own + port: typed_literal(text) for port, text in inline.literals.items()}
        return Scope(self.namespace, aliases, literals, self.parent, self.element, inline.private)

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


def subtree_scopes(trees: Mapping[str, ET.Element], main_id: str) -> dict[str, Scope]:
    """Every SubTree instance's scope under the tree ``main_id``, by namespace (``/`` is the main tree's).

    ``trees``: the validated ``<BehaviorTree>`` elements by ID, every SubTree element named
    (the validator gives each a unique ``name``, which py_trees uses for its namespace).
    """
    root = Scope("/")
    scopes = {"/": root}

    def walk(elem: ET.Element, scope: Scope) -> None:
        for child in elem:
            if child.tag != SUBTREE:
                walk(child, scope)
                continue
            target = child.attrib.get("ID", "")
            sub = Scope(scope.namespace + child.attrib.get("name", target) + "/", parent=scope.namespace, element=child)
            remaps, literals = subtree_ports(child)
            sub.aliases.update({port: scope.key(name) for port, name in remaps.items()})
            sub.literals.update({sub.namespace + port: typed_literal(text) for port, text in literals.items()})
            scopes[sub.namespace] = sub
            if target in trees:
                walk(trees[target], sub)

    if main_id in trees:
        walk(trees[main_id], root)
    return scopes


class TreeBlackboard:
    """The scripting language's view of py_trees' blackboard, inside one (sub)tree's scope.

    A name is the scope's entry (its namespace), or, when the SubTree element remaps it
    (``input="{x}"``), the parent's entry it aliases; ``@name`` is the root's.
    """

    def __init__(self, namespace: str, scope: Scope | None = None, declared: Mapping[str, type] | None = None) -> None:
        self.namespace = namespace if namespace.endswith("/") else namespace + "/"
        self.scope = scope if scope is not None else Scope(self.namespace)
        self.declared: Mapping[str, type] = declared if declared is not None else {}
        """Entries a typed port fixed the type of, by storage key (BT.CPP creates them at load)."""

    def has(self, key: str) -> bool:
        full = self.scope.key(key)
        return full in Blackboard.storage or full in self.declared

    def get(self, key: str) -> object:
        return Blackboard.storage[self.scope.key(key)]

    def set(self, key: str, value: object) -> None:
        Blackboard.storage[self.scope.key(key)] = value

    def declared_type(self, key: str) -> type | None:
        return self.declared.get(self.scope.key(key))

    def unset(self, key: str) -> None:
        Blackboard.storage.pop(self.scope.key(key), None)
