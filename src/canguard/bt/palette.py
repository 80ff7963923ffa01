"""Groot2 / BehaviorTree.CPP palettes: ``<TreeNodesModel>`` declarations of node types canguard does not implement.

Tree nodes are checked against their declaration; a declared node runs only once bound to a config
action or a plug-in (docs/trees.md, "Palettes").
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from canguard.bt.registry import children_problem
from canguard.bt.xmlsrc import Where, _read_xml
from canguard.errors import TreeError, quote

KINDS = ("Action", "Condition", "Decorator", "Control", "SubTree")
DIRECTIONS = {"input_port": "input", "output_port": "output", "inout_port": "inout", "bidirectional_port": "inout"}


@dataclass(frozen=True)
class PalettePort:
    """One declared port."""

    name: str
    direction: str  # input, output or inout
    default: str | None
    type: str
    description: str
    required: bool = False
    """``required="true"``, a canguard extension: BT.CPP's palettes have no required ports."""


@dataclass(frozen=True)
class PaletteNode:
    """One node type a palette declares."""

    node_id: str
    kind: str
    ports: Mapping[str, PalettePort]
    file: Path
    line: int

    @property
    def where(self) -> str:
        return f"{self.file}:{self.line}"


@dataclass
class Palette:
    """Every node type declared by the palettes of one load, by ID (the first declaration wins)."""

    nodes: dict[str, PaletteNode] = field(default_factory=dict)

    def add(self, node: PaletteNode, problems: list[str]) -> None:
        first = self.nodes.get(node.node_id)
        if first is None:
            self.nodes[node.node_id] = node
        elif (first.kind, dict(first.ports)) != (node.kind, dict(node.ports)):
            problems.append(f"{node.where}: {node.kind} {node.node_id} is declared again differently "
                            f"(first at {first.where})")


def read_model(model: ET.Element, where: Mapping[ET.Element, Where], path: Path,
               palette: Palette, problems: list[str]) -> None:
    """Add the node types of one ``<TreeNodesModel>`` element to ``palette``; problems with file:line."""

    def at(elem: ET.Element) -> Where:
        return where.get(elem, (path, 0))

    for decl in model:
        file, line = at(decl)
        if decl.tag not in KINDS:
            problems.append(f"{file}:{line}: <{decl.tag}> in <TreeNodesModel>: expected one of {', '.join(KINDS)}")
            continue
        node_id = decl.attrib.get("ID")
        if not node_id:
            problems.append(f"{file}:{line}: <{decl.tag}> in <TreeNodesModel> without ID=\"...\"")
            continue
        ports: dict[str, PalettePort] = {}
        for port in decl:
            pfile, pline = at(port)
            if port.tag in ("description", "metadata"):
                continue
            direction = DIRECTIONS.get(port.tag)
            if direction is None:
                problems.append(f"{pfile}:{pline}: <{port.tag}> in {node_id}: expected "
                                f"{', '.join(DIRECTIONS)}")
                continue
            name = port.attrib.get("name")
            if not name:
                problems.append(f"{pfile}:{pline}: <{port.tag}> of {node_id} without name=\"...\"")
                continue
            if name in ports:
                problems.append(f"{pfile}:{pline}: port {quote(name)} of {node_id} declared twice")
                continue
            required = port.attrib.get("required", "").strip().lower() in ("true", "1")
            ports[name] = PalettePort(name, direction, port.attrib.get("default"), port.attrib.get("type", ""),
                                      (port.text or "").strip(), required and direction != "output")
        palette.add(PaletteNode(node_id, decl.tag, ports, file, line), problems)


def read_palettes(paths: Iterable[Path]) -> Palette:
    """Every ``--nodes`` file read into one palette; a TreeError listing every problem of every file."""
    palette = Palette()
    problems: list[str] = []
    for path in map(Path, paths):
        where: dict[ET.Element, Where] = {}
        try:
            root = _read_xml(path, where)
        except TreeError as exc:
            problems.extend(exc.problems)
            continue
        models = [root] if root.tag == "TreeNodesModel" else list(root.iter("TreeNodesModel"))
        if root.tag not in ("root", "TreeNodesModel"):
            problems.append(f"{path}:{where.get(root, (path, 1))[1]}: the document element is <{root.tag}>, "
                            "expected <root> holding a <TreeNodesModel> (a Groot2 / BT.CPP palette)")
        elif not models:
            problems.append(f"{path}:{where.get(root, (path, 1))[1]}: no <TreeNodesModel> in the palette file")
        for model in models:
            read_model(model, where, path, palette, problems)
    if problems:
        raise TreeError(problems)
    return palette


def check_node(elem: ET.Element, decl: PaletteNode, at: str, tree_id: str) -> list[str]:
    """The problems of one tree node against its palette declaration (ports, children)."""
    problems = []
    head = f"{at}: node {elem.tag} (BehaviorTree {tree_id}, declared at {decl.where})"
    for attr in elem.attrib:
        if attr == "name" or attr.startswith("_"):
            continue
        if attr not in decl.ports:
            listing = ", ".join(decl.ports) or "(none)"
            problems.append(f"{head}: unknown port {quote(attr)}; ports of {elem.tag}: {listing}")
    missing = [p.name for p in decl.ports.values() if p.required and p.name not in elem.attrib]
    if missing:
        problems.append(f"{head}: missing required port {', '.join(missing)} (declared required=\"true\")")
    kind_error = children_problem(decl.kind, len(elem))
    return [*problems, f"{head}: {kind_error}"] if kind_error else problems


def unbound_message(node_id: str, at: str, decl: PaletteNode) -> str:
    """Why a palette-declared node cannot run, and how to bind it (an action or condition: two ways)."""
    plugin = f"a `canguard.nodes` entry point named {node_id} (a Python plug-in)"
    if decl.kind in ("Decorator", "Control", "SubTree"):
        how = plugin  # a config action is a leaf: it cannot hold children
    else:
        how = (f"an `actions: {node_id}:` entry in the config (its frames are sent when the node is ticked) "
               f"or {plugin}")
    return (f"{at}: node {node_id} is declared by a palette ({decl.where}) but canguard does not implement it; "
            f"to run the tree bind it: {how}")
