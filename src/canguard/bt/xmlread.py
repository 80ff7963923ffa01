"""Reading BehaviorTree.CPP XML (with line numbers, includes) and v3 -> v4 rewriting."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Collection
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from canguard.bt.context import Context
from canguard.bt.loaded import NodeInfo
from canguard.bt.registry import _PORT_ALIASES, _SUBTREE, _TAG_ALIASES, _TOKEN, _V3_WRAPPERS, Registry, build_registry
from canguard.bt.scopes import Inline, subtree_ports
from canguard.bt.xmlsrc import Where, _read_xml
from canguard.errors import TreeError, closest, quote

if TYPE_CHECKING:
    from canguard.bt.palette import Palette, PaletteNode
    from canguard.bt.scripting import Script as ParsedScript


def _closest(word: str, choices: Collection[str]) -> list[str]:
    """Every one of ``choices``, closest to ``word`` first (ties alphabetical): short lists (trees, ports)."""
    return closest(word, choices, n=len(choices), cutoff=0.0)


def _type_name(data_type: Any, cpp: bool = False) -> str:
    """A port type as errors name it (``float``, ``string``), or with ``cpp`` as BT.CPP and Groot2 do."""
    names = {float: "double", str: "std::string"} if cpp else {float: "float", str: "string"}
    return names.get(data_type, getattr(data_type, "__name__", str(data_type)))


class _Reader:
    """One load: the document, its trees, the registry, the placeholder names."""

    def __init__(self, path: Path, ctx: Context) -> None:
        self.path = path
        self.ctx = ctx
        self.where: dict[ET.Element, Where] = {}
        self.trees: dict[str, ET.Element] = {}
        self.format_version = 3
        self.main_attr: str | None = None
        self.infos: dict[str, NodeInfo] = {}
        self.conditions: dict[str, dict[str, ParsedScript]] = {}  # pre/post conditions by node token
        self.subtree_conditions: dict[ET.Element, dict[str, ParsedScript]] = {}  # run on the parent's board
        self.private: dict[ET.Element, Inline] = {}  # elements of an inlined _autoremap subtree -> it
        self.private_tokens: dict[str, Inline] = {}  # the same, by node token
        self._inlined = 0
        self.registry: Registry = {}
        self.errors: list[str] = []  # every problem found so far: one load reports them all
        self.broken_trees: set[str] = set()  # rewrite failed: not validated further (no follow-on errors)
        self.source_check: Literal["with_others", "always", "never"] = "with_others"
        """When :meth:`validate` checks guards' sources: with other problems (binding checks them
        otherwise), always (a tree checked without binding), or never (the sources are unknown)."""
        self.unsure_sources: Collection[str] = ()  # declared by a config that could not build them
        self._palette: Palette | None = None
        self.unbound: list[str] = []  # why each palette-declared node nothing implements cannot run
        self.palette_ports: list[tuple[ET.Element, list[str]]] = []  # palette-checked, dropped before parsing

    @property
    def palette(self) -> Palette:
        """Node types declared by ``<TreeNodesModel>`` (file, ``--nodes``); made (and imported) when first read."""
        if self._palette is None:
            from canguard.bt.palette import Palette

            self._palette = Palette()
        return self._palette

    def declared(self, node_id: str) -> PaletteNode | None:
        """The palette's declaration of ``node_id`` (None: not declared, or no palette read)."""
        return None if self._palette is None else self._palette.nodes.get(node_id)

    def raise_collected(self) -> None:
        """Raise one TreeError listing every problem collected so far, if there is any."""
        if self.errors:
            raise TreeError(self.errors)

    def at(self, elem: ET.Element) -> str:
        file, line = self.where.get(elem, (self.path, 0))
        return f"{file}:{line}"

    def error(self, elem: ET.Element, msg: str, tree: str | None = None, port: str | None = None) -> TreeError:
        node = elem.tag
        name = elem.attrib.get("name")
        if node == _SUBTREE:
            node += f" {elem.attrib.get('ID', '')}"
        elif name and not name.startswith(_TOKEN):
            node += f' "{name}"'
        where = f"node {node}" + (f" (BehaviorTree {tree})" if tree else "")
        if port is not None:
            where += f", port {port}"
        return TreeError(f"{self.at(elem)}: {where}: {msg}")

    def _document(self, path: Path) -> ET.Element:
        """The ``<root>`` element of the file ``path`` (its elements' lines recorded)."""
        root = _read_xml(path, self.where)
        if root.tag != "root":
            raise TreeError(
                f"{self.at(root)}: the document element is <{root.tag}>, expected <root> (BehaviorTree.CPP XML)"
            )
        return root

    def read(self) -> None:
        root = self._document(self.path)
        fmt = root.attrib.get("BTCPP_format")
        if fmt not in (None, "3", "4"):
            raise TreeError(f'{self.at(root)}: BTCPP_format="{fmt}" is not supported (3 or 4)')
        self.format_version = 4 if fmt == "4" else 3
        self.main_attr = root.attrib.get("main_tree_to_execute")
        self._collect(root, self.path, {self.path.resolve()})

    def _collect(self, root: ET.Element, path: Path, seen: set[Path]) -> None:
        for child in root:
            tag = child.tag
            if tag == "BehaviorTree":
                tree_id = child.attrib.get("ID")
                if not tree_id:
                    raise TreeError(f"{self.at(child)}: <BehaviorTree> without ID")
                if tree_id in self.trees:
                    first = self.at(self.trees[tree_id])
                    raise TreeError(f"{self.at(child)}: BehaviorTree {tree_id} is defined twice (first at {first})")
                self.trees[tree_id] = child
            elif tag == "TreeNodesModel":
                from canguard.bt.palette import read_model

                read_model(child, self.where, path, self.palette, self.errors)  # Groot's palette
            elif tag.lower() in ("include", "import"):
                self._include(child, path, seen)
            else:
                raise TreeError(
                    f"{self.at(child)}: unexpected <{tag}> under <root>; expected <BehaviorTree>, "
                    "<include> or <TreeNodesModel>"
                )

    def _include(self, elem: ET.Element, path: Path, seen: set[Path]) -> None:
        if "ros_pkg" in elem.attrib:
            raise TreeError(f"{self.at(elem)}: <include ros_pkg=...> is not supported; give a path")
        src = elem.attrib.get("path") or elem.attrib.get("src") or elem.attrib.get("file")
        if not src:
            raise TreeError(f'{self.at(elem)}: <{elem.tag}> needs path="other.xml"')
        target = (path.parent / src) if not Path(src).is_absolute() else Path(src)
        key = target.resolve()
        if key in seen:
            return  # already included (or the including file itself)
        seen.add(key)
        self._collect(self._document(target), target, seen)

    def rewrite(self) -> None:
        for tree_id, bt in self.trees.items():
            for attr in [a for a in bt.attrib if a.startswith("_")]:
                del bt.attrib[attr]  # Groot bookkeeping (_fullpath...), meaningless here
            if len(bt) != 1:
                self.errors.append(
                    f"{self.at(bt)}: BehaviorTree {tree_id} must have exactly one root node, found {len(bt)}"
                )
                self.broken_trees.add(tree_id)
                continue
            try:
                if self._autoremapped(bt[0]):
                    bt[0] = self._inline(bt[0], tree_id, (tree_id,))
                self._rewrite(bt[0], tree_id)
            except TreeError as exc:
                self.errors.extend(exc.problems)
                self.broken_trees.add(tree_id)

    def _rewrite(self, elem: ET.Element, tree_id: str) -> None:
        if elem.tag in _V3_WRAPPERS:
            node_id = elem.attrib.pop("ID", None)
            if not node_id:
                raise TreeError(f'{self.at(elem)}: <{elem.tag}> without ID="..." (BehaviorTree {tree_id})')
            elem.tag = node_id
        if elem.tag == _SUBTREE and self.format_version == 3:
            # v3's SubTree (not SubTreePlus) remaps ports to the parent's entries by bare name:
            # <SubTree ID="MoveRobot" target="move_goal"/> is v4's target="{move_goal}"
            for attr, given in list(elem.attrib.items()):
                text = given.strip()
                if attr not in ("ID", "name") and not attr.startswith("_") and text and text[0] != "{":
                    elem.attrib[attr] = "{" + text + "}"
        elem.tag = _TAG_ALIASES.get(elem.tag, elem.tag)
        for old, new in _PORT_ALIASES.get(elem.tag, {}).items():
            if old in elem.attrib and new not in elem.attrib:
                elem.attrib[new] = elem.attrib.pop(old)
        for attr in ("__shared_blackboard", "_autoremap", "__autoremap"):
            value = elem.attrib.pop(attr, None)
            if value is not None and value.strip().lower() not in ("false", "0"):
                raise self.error(
                    elem, f'{attr}="{value}" is not supported: remap the SubTree\'s ports explicitly', tree_id
                )
        for i, child in enumerate(elem):
            if self._autoremapped(child):
                elem[i] = self._inline(child, tree_id, (tree_id,))
        for attr, value in list(elem.attrib.items()):
            if value.strip() == "{=}":
                elem.attrib[attr] = "{" + attr + "}"
        for child in elem:
            self._rewrite(child, tree_id)

    @staticmethod
    def _autoremapped(elem: ET.Element) -> bool:
        """A ``<SubTree _autoremap="true">`` (v4; v3's ``__autoremap`` too)."""
        if _TAG_ALIASES.get(elem.tag, elem.tag) != _SUBTREE:
            return False
        value = elem.attrib.get("_autoremap", elem.attrib.get("__autoremap"))
        return value is not None and value.strip().lower() in ("true", "1")

    def _inline(self, sub: ET.Element, tree_id: str, chain: tuple[str, ...]) -> ET.Element:
        """The subtree of an ``_autoremap="true"`` SubTree, copied in its place on the parent's blackboard: its
        ports renamed or given the element's constants, the element's conditions on the copy's root."""
        target = self.target(sub, tree_id)
        if target in chain:
            raise self.error(sub, f"SubTree cycle: {' -> '.join((*chain, target))}", tree_id)
        body = self.trees[target]
        if len(body) != 1:
            raise self.error(sub, f"BehaviorTree {target} must have exactly one root node", tree_id)
        remaps, literals = subtree_ports(sub)
        rename = {**{port: "{" + name + "}" for port, name in remaps.items()}, **literals}  # {port} -> this
        self._inlined += 1
        private = f"{target}_autoremap{self._inlined}"  # BT.CPP: _autoremap never maps a key starting with _
        copy = self._copy(body[0], rename, Inline(private, remaps, literals))
        copy.attrib.update({a: v for a, v in sub.attrib.items()
                            if a.startswith("_") and a not in ("_autoremap", "__autoremap")})
        for i, child in enumerate(copy):
            if self._autoremapped(child):
                copy[i] = self._inline(child, tree_id, (*chain, target))
        return copy

    def target(self, sub: ET.Element, tree_id: str) -> str:
        """The ID of the BehaviorTree a ``<SubTree>`` runs; a TreeError naming the trees when there is none."""
        target = sub.attrib.get("ID", "")
        if target not in self.trees:
            known = ", ".join(_closest(target, self.trees))
            raise self.error(sub, f"unknown BehaviorTree {quote(target)}; trees in the file: {known}", tree_id)
        return target

    def _copy(self, src: ET.Element, rename: dict[str, str], inline: Inline) -> ET.Element:
        """A deep copy of ``src`` (with its lines), ``{key}``s renamed by ``rename``, ``{_key}``s made private."""
        attrib = {}
        for attr, value in src.attrib.items():
            text = value.strip()
            inner = attr if text == "{=}" else text[1:-1].strip()
            if text.startswith("{") and text.endswith("}") and inner in rename:
                value = rename[inner]
            elif text.startswith("{") and text.endswith("}") and inner.startswith("_"):
                value = "{" + inline.private + "/" + inner + "}"
            attrib[attr] = value
        dst = ET.Element(src.tag, attrib)
        self.private[dst] = inline
        if src in self.where:
            self.where[dst] = self.where[src]
        for child in src:
            dst.append(self._copy(child, rename, inline))
        return dst

    def make_registry(self) -> None:
        used: set[str] = set()
        for bt in self.trees.values():
            used.update(e.tag for e in bt.iter() if e is not bt)
        self.registry = build_registry(self.ctx, only=used)

    def choose_main(self, main: str | None) -> str:
        if not self.trees:
            raise TreeError(f"{self.path}: no <BehaviorTree> in the file")
        chosen = main or self.main_attr
        if chosen is None:
            if len(self.trees) == 1:
                return next(iter(self.trees))
            raise TreeError(
                f"{self.path}: several BehaviorTrees ({', '.join(self.trees)}) and no main_tree_to_execute; "
                "name the one to run (tree: main: in the config)"
            )
        if chosen not in self.trees:
            known = ", ".join(_closest(chosen, self.trees))
            raise TreeError(f"{self.path}: no BehaviorTree with ID {quote(chosen)}; trees in the file: {known}")
        return chosen
