"""The running tree as BehaviorTree.CPP numbers it: node UIDs, subtree instances, Groot2's FULLTREE XML.

Built once per engine, never per tick. UIDs count from 1 depth-first, as BT.CPP's factory gives them; a
``<SubTree>`` is a node of its own (py_trees inlines the subtree: it is put back here, with the status of the
subtree's root), and each subtree instance a ``<BehaviorTree ID _fullpath>``, as BT.CPP's
``WriteTreeToXML(tree, add_metadata=true, add_builtin_models=true)`` writes it.
"""

from __future__ import annotations

import uuid
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.parsers import expat

import py_trees

from canguard.bt.loader import LoadedTree, nodes_model_xml


@dataclass
class LayoutNode:
    """One node of the tree as Groot2 sees it."""

    uid: int
    node_id: str
    """The registration ID (``IsCurrentSafe``, ``SubTree``...)."""
    name: str
    behaviour: py_trees.behaviour.Behaviour | None
    """The py_trees node; for a ``SubTree`` node, the root of its subtree (whose status it shows)."""
    subtree: str = ""
    """For a ``SubTree`` node: the ``<BehaviorTree ID>`` it runs, and its instance path (``_fullpath``)."""
    path: str = ""
    attrs: dict[str, str] = field(default_factory=dict)
    """The node's attributes as written in the tree file (ports, pre/post conditions)."""
    children: list[LayoutNode] = field(default_factory=list)

    def as_json(self) -> dict[str, Any]:
        """Uid, type, name and children (the page's static tree; statuses come with each snapshot)."""
        out: dict[str, Any] = {"uid": self.uid, "type": self.node_id, "name": self.name}
        if self.subtree:
            out["subtree"] = self.subtree
        out["children"] = [c.as_json() for c in self.children]
        return out


@dataclass(frozen=True)
class LayoutRecord:
    """What the monitor process needs of a :class:`TreeLayout`: plain data, sent to it once per tree."""

    main_id: str
    tree: dict[str, Any]
    """The static tree: ``{uid, type, name, children}`` (:meth:`LayoutNode.as_json`); statuses come per snapshot."""
    xml: str
    """Groot2's FULLTREE XML, the tree's 16-byte id in its replies, and the ``_fullpath`` of each subtree instance
    (Groot2's BLACKBOARD names them)."""
    uuid: bytes
    paths: tuple[str, ...]


@dataclass
class _Instance:
    tree_id: str
    path: str
    root: LayoutNode | None = None


class TreeLayout:
    """UIDs, subtree instances and the FULLTREE XML of one loaded tree."""

    def __init__(self, loaded: LoadedTree, context: Any = None) -> None:
        self.main_id = loaded.main_id
        self._loaded = loaded
        self._sources = _SourceAttrs()
        self.instances: list[_Instance] = [_Instance(loaded.main_id, "")]
        self.nodes: list[LayoutNode] = []
        """Every node, in UID order (``nodes[uid - 1]``)."""
        self.root = self._place(loaded.root, self.instances[0], loaded.main_id)
        self.instances[0].root = self.root
        self.behaviours: tuple[py_trees.behaviour.Behaviour | None, ...] = tuple(n.behaviour for n in self.nodes)
        """Whose status each UID shows, in UID order (what a snapshot reads per tick)."""
        self.xml = self._fulltree_xml(context)
        self.uuid = uuid.uuid4().bytes
        """The tree's 16-byte id in Groot2's replies: a reload's new tree has a new one, so Groot2 asks for it."""
        self.record = LayoutRecord(self.main_id, self.root.as_json(), self.xml, self.uuid,
                                   tuple(i.path for i in self.instances[1:]))
        """The plain-data form the snapshots carry (the monitor process has no tree of its own)."""

    def _new(self, node_id: str, name: str, behaviour: Any, **kw: Any) -> LayoutNode:
        node = LayoutNode(len(self.nodes) + 1, node_id, name, behaviour, **kw)
        self.nodes.append(node)
        return node

    def _place(self, behaviour: py_trees.behaviour.Behaviour, instance: _Instance, tree_id: str) -> LayoutNode:
        info = self._loaded.nodes.get(behaviour.id)
        if info is not None and info.tree != tree_id:
            # py_trees inlined a <SubTree> here: give it back its own node and instance.
            path = behaviour.name.rsplit("/", 1)[0] if "/" in behaviour.name else info.tree
            sub = self._new("SubTree", path.rsplit("/", 1)[-1], behaviour, subtree=info.tree, path=path,
                            attrs={"ID": info.tree})
            inner = _Instance(info.tree, path)
            self.instances.append(inner)
            inner.root = self._place(behaviour, inner, info.tree)
            sub.children.append(inner.root)
            return sub
        node_id = info.node_id if info is not None else type(behaviour).__name__
        attrs = self._sources.attrs(info.file, info.line, node_id) if info is not None else {}
        node = self._new(node_id, behaviour.name, behaviour, attrs=attrs)
        for child in behaviour.children:
            node.children.append(self._place(child, instance, tree_id))
        return node

    def _fulltree_xml(self, context: Any) -> str:
        doc = ET.Element("root", {"BTCPP_format": "4"})
        for instance in self.instances:
            tree = ET.SubElement(doc, "BehaviorTree", {"ID": instance.tree_id, "_fullpath": instance.path})
            if instance.root is not None:
                self._element(instance.root, tree)
        models = ET.fromstring(nodes_model_xml(context)).find("TreeNodesModel")
        if models is not None:
            doc.append(models)
        return ET.tostring(doc, encoding="unicode")

    def _element(self, node: LayoutNode, parent: ET.Element) -> None:
        if node.subtree:
            ET.SubElement(parent, "SubTree", {"ID": node.subtree, "_fullpath": node.path, "_uid": str(node.uid)})
            return  # its nodes are in the subtree instance's own <BehaviorTree>
        attrs = {k: v for k, v in node.attrs.items() if k not in ("ID", "name")}
        name = node.attrs.get("name", node.node_id)  # as in the file: BT.CPP's name, not the page's unique one
        elem = ET.SubElement(parent, node.node_id, {"name": name, "_uid": str(node.uid), **attrs})
        for child in node.children:
            self._element(child, elem)


class _SourceAttrs:
    """The attributes of the elements of a tree file, found by line (the loader keeps each node's line)."""

    def __init__(self) -> None:
        self._files: dict[Path, dict[int, list[tuple[str, dict[str, str]]]]] = {}

    def attrs(self, path: Path, line: int, node_id: str) -> dict[str, str]:
        """The attributes of the element for ``node_id`` that starts at ``line`` of ``path`` ({} if unknown)."""
        elements = self._read(path).get(line, [])
        for tag, attrs in elements:
            if node_id in (tag, attrs.get("ID")):
                return attrs
        return dict(elements[0][1]) if elements else {}

    def _read(self, path: Path) -> dict[int, list[tuple[str, dict[str, str]]]]:
        if path not in self._files:
            by_line: dict[int, list[tuple[str, dict[str, str]]]] = {}
            parser = expat.ParserCreate()

            def start(tag: str, attrs: dict[str, str]) -> None:
                by_line.setdefault(parser.CurrentLineNumber, []).append((tag, attrs))

            parser.StartElementHandler = start
            try:
                parser.Parse(path.read_bytes(), True)
            except (OSError, expat.ExpatError):
                by_line = {}  # changed on disk since it was loaded: the names and UIDs are still right
            self._files[path] = by_line
        return self._files[path]
