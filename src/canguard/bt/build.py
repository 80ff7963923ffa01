"""Building the py_trees tree from the validated XML: names made readable, canguard nodes bound."""

from __future__ import annotations

import re
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING, Any

import py_trees
from py_trees.blackboard import Blackboard
from py_trees.parsers.behaviour_tree_xml import XMLParserError, parse_behaviour_tree_xml

from canguard.bt import conditions
from canguard.bt.context import Context
from canguard.bt.loaded import LoadedTree, NodeInfo, _preorder
from canguard.bt.nodes import CanguardNode, PortError
from canguard.bt.nodes.base import port_table
from canguard.bt.registry import _TOKEN
from canguard.bt.scopes import TreeBlackboard, subtree_scopes
from canguard.bt.validate import _Validator
from canguard.bt.wakeup import WakeUpSignal
from canguard.bt.xmlread import _type_name
from canguard.errors import TreeError

if TYPE_CHECKING:
    from canguard.bt.palette import Palette


class _Loader(_Validator):
    """Step 4: parse with py_trees and bind the nodes."""

    def parse(self, main_id: str) -> py_trees.behaviour.Behaviour:
        doc = ET.Element("root", {"BTCPP_format": "4", "main_tree_to_execute": main_id})
        doc.extend(self.trees.values())
        with tempfile.TemporaryDirectory(prefix="canguard-tree-") as tmp:
            rewritten = Path(tmp) / self.path.name
            rewritten.write_bytes(ET.tostring(doc, encoding="utf-8"))
            try:
                return parse_behaviour_tree_xml(str(rewritten), main_tree_id=main_id, node_registry=self.registry)
            except TreeError:
                raise
            except (XMLParserError, ValueError, KeyError, TypeError, AssertionError, RuntimeError,
                    NotImplementedError) as exc:
                raise TreeError(f"{self.path}: BehaviorTree {main_id}: {self._untoken(str(exc))}") from exc

    def scoped_boards(self, main_id: str) -> dict[str, TreeBlackboard]:
        """The scripts' blackboard view of every SubTree instance's scope; its literal entries created."""
        boards = {}
        self.scopes = subtree_scopes(self.trees, main_id)
        self.entry_types: dict[str, type] = {}  # filled by check_entry_types
        for namespace, scope in self.scopes.items():
            Blackboard.storage.update(scope.literals)
            boards[namespace] = TreeBlackboard(namespace, scope, self.entry_types)
        return boards

    def install_subtree_conditions(self, nodes: list[py_trees.behaviour.Behaviour],
                                   boards: dict[str, TreeBlackboard]) -> None:
        """Conditions on a ``<SubTree>`` wrap its instance's root, on the parent's scope (BT.CPP's SubTree node)."""
        for ns, scope in self.scopes.items():
            scripts = self.subtree_conditions.get(scope.element) if scope.element is not None else None
            if not scripts:
                continue
            for node in nodes:  # the instance's root: the one node of its scope whose parent is outside it
                if _namespace(node).startswith(ns) and not _namespace(node.parent).startswith(ns):
                    conditions.install(node, scripts, boards[scope.parent])
                    break

    def check_entry_types(self, nodes: list[py_trees.behaviour.Behaviour], infos: dict[Any, NodeInfo]) -> None:
        """BT.CPP's rule: the first typed port wired to an entry fixes its type (a string converts to any)."""
        first: dict[str, tuple[type, str]] = {}
        for node in nodes:  # in tree order, as BT.CPP creates them
            if not isinstance(node, CanguardNode):
                continue
            info = infos[node.id]
            table = port_table(type(node))
            for port, key in node.wired_keys().items():
                if port in node.UNTYPED_PORTS or port not in table:
                    continue
                kind = table[port][1].data_type
                if key not in first:
                    first[key] = (kind, f"{info.file}:{info.line}, node {info.name}")
                    if kind in (int, float, bool):  # scripts then assign to it with its type
                        self.entry_types[key] = kind
                    continue
                was, at = first[key]
                if was is not kind and was is not str:
                    self.errors.append(
                        f"{info.where}, port {port}: the entry "
                        f"[{key.lstrip('/')}] was created with type [{_type_name(was, cpp=True)}] ({at}) and is used "
                        f"here as [{_type_name(kind, cpp=True)}]; one entry has one type (as in BT.CPP)"
                    )

    def _untoken(self, text: str) -> str:
        def name(m: re.Match) -> str:
            info = self.infos.get(m.group(0))
            return f"{info.node_id} at line {info.line}" if info else m.group(0)

        text = re.sub(re.escape(_TOKEN) + r"\d+", name, text)
        lines: dict[str, list[str]] = {}
        for info in self.infos.values():
            if f"'{info.node_id}'" in text:
                lines.setdefault(info.node_id, []).append(f"{info.file.name}:{info.line}")
        hints = "; ".join(f"{node_id} at {', '.join(where)}" for node_id, where in lines.items())
        return f"{text} ({hints})" if hints else text

    def finish(self, root: py_trees.behaviour.Behaviour, main_id: str) -> LoadedTree:
        nodes = list(_preorder(root))  # BT.CPP creates (and types the entries) in this order
        placed: list[tuple[py_trees.behaviour.Behaviour, NodeInfo, str]] = []
        boards = self.scoped_boards(main_id)
        for node in nodes:
            parts = node.name.split(".")
            info = self.infos[parts[-1]]
            namespace = _namespace(node)
            board = boards.get(namespace, boards["/"])
            inline = self.private_tokens.get(parts[-1])
            if inline is not None:  # a node of an inlined _autoremap subtree: its ports and _keys
                scope = board.scope.inlined(inline)
                Blackboard.storage.update({k: v for k, v in scope.literals.items() if k not in Blackboard.storage})
                board = TreeBlackboard(namespace, scope, self.entry_types)
            if isinstance(node, CanguardNode) and node.USES_BOARD:
                node.board = board  # type: ignore[attr-defined]
            conditions.install(node, self.conditions.get(parts[-1], {}), board)
            prefix = [p for p in parts[:-1] if p not in self.infos]
            placed.append((node, info, "/".join([*prefix, info.name])))
        self.install_subtree_conditions(nodes, boards)
        counts: dict[str, int] = {}
        loaded_nodes: dict[Any, NodeInfo] = {}
        for node, info, readable in placed:
            k = counts.get(readable, 0) + 1
            counts[readable] = k
            name = readable if k == 1 else f"{readable}#{k}"
            node.name = name
            loaded_nodes[node.id] = NodeInfo(info.node_id, name, info.file, info.line, info.tree)
        for node, _, _ in placed:
            if isinstance(node, CanguardNode):
                node.resolve_root_keys()
        self.check_entry_types([n for n, _, _ in placed], loaded_nodes)
        wake_up = WakeUpSignal()
        for node, _, _ in placed:
            if not isinstance(node, CanguardNode):
                continue
            node.wake_up = wake_up  # BT.CPP's factory gives every node of a tree its wake-up signal
            try:
                node.bind()
            except PortError as exc:
                self.errors.append(f"{loaded_nodes[node.id].where}, port {exc.port}: {exc.message}")
            except (ValueError, KeyError, TypeError) as exc:
                self.errors.append(f"{loaded_nodes[node.id].where}: {exc}")
        self.raise_collected()  # every node that cannot bind, not only the first
        return LoadedTree(
            root=root,
            tree=py_trees.trees.BehaviourTree(root=root),
            main_id=main_id,
            path=self.path,
            context=self.ctx,
            format_version=self.format_version,
            tree_ids=tuple(self.trees),
            nodes=loaded_nodes,
            wake_up=wake_up,
        )


def _namespace(node: py_trees.behaviour.Behaviour | None) -> str:
    """The namespace py_trees' parser gave ``node`` (its SubTree instance's; ``/`` in the main tree)."""
    return (getattr(node, "_subtree_namespace", None) or "/").rstrip("/") + "/"


def _checked(path: str | Path, ctx: Context, main: str | None, palette: Palette | None,
             *, to_run: bool) -> tuple[_Loader, str]:
    """The checked loader of ``path`` and the main tree's ID; a TreeError listing every problem of the file
    (``to_run``: palette-declared nodes that nothing implements too)."""
    loader = _Loader(Path(path), ctx)
    if palette is not None:
        loader.palette.nodes.update(palette.nodes)
    main_id = loader.check(main)
    if to_run:
        loader.errors.extend(loader.unbound)
    loader.raise_collected()
    loader.check_cycles(main_id)
    return loader, main_id


def load_tree(path: str | Path, ctx: Context, main: str | None = None, palette: Palette | None = None) -> LoadedTree:
    """Load, validate and bind the BehaviorTree.CPP XML tree ``main`` of ``path`` for ``ctx``.

    ``main`` defaults to ``main_tree_to_execute``, or the only tree; ``palette``: ``--nodes`` files.
    Every problem is a :class:`~canguard.errors.TreeError` naming file and line.
    """
    loader, main_id = _checked(path, ctx, main, palette, to_run=True)
    for elem, attrs in loader.palette_ports:
        for attr in attrs:  # checked against the palette; the bound config action does not read them
            elem.attrib.pop(attr, None)
    root = loader.parse(main_id)
    return loader.finish(root, main_id)


def validate_tree(path: str | Path, ctx: Context, main: str | None = None,
                  palette: Palette | None = None) -> tuple[str, list[str]]:
    """Check a tree file without building it: (main tree ID, why each palette-declared node cannot run yet)."""
    loader, main_id = _checked(path, ctx, main, palette, to_run=False)
    return main_id, list(loader.unbound)
