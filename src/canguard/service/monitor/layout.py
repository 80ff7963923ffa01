"""The running tree as BehaviorTree.CPP numbers it: node UIDs, subtree instances, Groot2's FULLTREE XML."""

from __future__ import annotations

import uuid
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.parsers import expat

import py_trees

from canguard.bt.checks import nodes_model_xml
from canguard.bt.loaded import LoadedTree


@dataclass(frozen=True)
class LayoutRecord:
    """What the monitor process needs of a :class:`TreeLayout`: plain data, sent to it once per tree."""

    main_id: str
    tree: dict[str, Any]
    """The static tree: ``{uid, type, name, [subtree], children}``; statuses come per snapshot."""
    xml: str
    """Groot2's FULLTREE XML, the tree's 16-byte id, and each subtree instance's ``_fullpath``."""
    uuid: bytes
    paths: tuple[str, ...]


class TreeLayout:
    """UIDs, subtree instances and the FULLTREE XML of one loaded tree, made in one depth-first pass."""

    def __init__(self, loaded: LoadedTree, context: Any = None) -> None:
        self._loaded = loaded
        self._files: dict[Path, dict[int, list[tuple[str, dict[str, str]]]]] = {}
        """Per tree file, its elements (tag, attributes) by the line they start at (the loader keeps each node's)."""
        self._paths: list[str] = []
        self.behaviours: list[py_trees.behaviour.Behaviour] = []
        """Whose status each UID shows, in UID order (what a snapshot reads per tick)."""
        self._doc = ET.Element("root", {"BTCPP_format": "4"})
        main = ET.SubElement(self._doc, "BehaviorTree", {"ID": loaded.main_id, "_fullpath": ""})
        tree = self._place(loaded.root, loaded.main_id, main)
        models = ET.fromstring(nodes_model_xml(context)).find("TreeNodesModel")
        if models is not None:
            self._doc.append(models)
        # a reload's new tree has a new id, so Groot2 asks for it
        self.record = LayoutRecord(loaded.main_id, tree, ET.tostring(self._doc, encoding="unicode"),
                                   uuid.uuid4().bytes, tuple(self._paths))
        """The plain-data form the snapshots carry (the monitor process has no tree of its own)."""

    def _place(self, behaviour: py_trees.behaviour.Behaviour, tree_id: str, parent: ET.Element) -> dict[str, Any]:
        """``behaviour``'s node (and its children's) as the page's static tree, its element put under ``parent``."""
        uid = len(self.behaviours) + 1
        self.behaviours.append(behaviour)  # a SubTree node shows the status of its subtree's root
        info = self._loaded.nodes.get(behaviour.id)
        if info is not None and info.tree != tree_id:  # py_trees inlined a <SubTree> here: its own node and instance
            path = behaviour.name.rsplit("/", 1)[0] if "/" in behaviour.name else info.tree
            ET.SubElement(parent, "SubTree", {"ID": info.tree, "_fullpath": path, "_uid": str(uid)})
            self._paths.append(path)
            inner = ET.SubElement(self._doc, "BehaviorTree", {"ID": info.tree, "_fullpath": path})
            return {"uid": uid, "type": "SubTree", "name": path.rsplit("/", 1)[-1], "subtree": info.tree,
                    "children": [self._place(behaviour, info.tree, inner)]}
        node_id = info.node_id if info is not None else type(behaviour).__name__
        attrs = self._attrs(info.file, info.line, node_id) if info is not None else {}
        name = attrs.get("name", node_id)  # as in the file: BT.CPP's name, not the page's unique one
        elem = ET.SubElement(parent, node_id, {"name": name, "_uid": str(uid),
                                               **{k: v for k, v in attrs.items() if k not in ("ID", "name")}})
        return {"uid": uid, "type": node_id, "name": behaviour.name,
                "children": [self._place(child, tree_id, elem) for child in behaviour.children]}

    def _attrs(self, path: Path, line: int, node_id: str) -> dict[str, str]:
        """The attributes of the element for ``node_id`` that starts at ``line`` of ``path`` ({} if unknown)."""
        if path not in self._files:
            self._files[path] = _elements(path)
        elements = self._files[path].get(line, [])
        for tag, attrs in elements:
            if node_id in (tag, attrs.get("ID")):
                return attrs
        return dict(elements[0][1]) if elements else {}


def _elements(path: Path) -> dict[int, list[tuple[str, dict[str, str]]]]:
    by_line: dict[int, list[tuple[str, dict[str, str]]]] = {}
    parser = expat.ParserCreate()

    def start(tag: str, attrs: dict[str, str]) -> None:
        by_line.setdefault(parser.CurrentLineNumber, []).append((tag, attrs))

    parser.StartElementHandler = start
    try:
        parser.Parse(path.read_bytes(), True)
    except (OSError, expat.ExpatError):
        return {}  # changed on disk since it was loaded: the names and UIDs are still right
    return by_line
