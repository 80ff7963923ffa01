"""Loading BehaviorTree.CPP XML trees onto py_trees: read, checked against the node registry, built, bound."""

from __future__ import annotations

import functools
import inspect
import math
import re
import xml.etree.ElementTree as ET
import xml.parsers.expat
from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint, distributions, entry_points
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, NamedTuple, cast

import py_trees
from py_trees.blackboard import Blackboard
from py_trees.parsers import behaviour_tree_xml as pyxml
from py_trees.ports import PortInformation, PortsMixin
from py_trees.ports_utils import convert_str_to_type

from canguard.bt.context import Context
from canguard.bt.loaded import LoadedTree, NodeInfo, _preorder
from canguard.bt.nodes import BUILTIN_NODES, CanguardNode, ConfiguredAction, GuardNode, PortError
from canguard.bt.nodes.base import CONDITIONS, install_conditions, node_kind, port_table, take_conditions
from canguard.bt.scopes import SUBTREE, Inline, TreeBlackboard, subtree_ports, subtree_scopes
from canguard.errors import TreeError, closest, quote
from canguard.io.clock import ManualClock

if TYPE_CHECKING:
    from canguard.bt.scripting.script import Script
    from canguard.config.schema import PartialConfig

Registry = dict[str, functools.partial]
Where = tuple[Path, int]

ENTRY_POINT_GROUP = "canguard.nodes"
"""Entry-point group through which other packages add node types (``NodeID = "pkg.mod:Class"``)."""

_V3_WRAPPERS = ("Action", "Condition", "Decorator", "Control")
_TAG_ALIASES = {"SequenceStar": "SequenceWithMemory", "RetryUntilSuccesful": "RetryUntilSuccessful",
                "SubTreePlus": SUBTREE}
_PORT_ALIASES = {"Parallel": {"success_threshold": "success_count", "failure_threshold": "failure_count",
                              "threshold": "success_count"}}
_TOKEN = "@"  # placeholder node names handed to py_trees are @<n>
_KINDS = ("Action", "Condition", "Decorator", "Control", "SubTree")
_DIRECTIONS = {"input_port": "input", "output_port": "output", "inout_port": "inout", "bidirectional_port": "inout"}


def _closest(word: str, choices: Collection[str]) -> list[str]:
    """Every one of ``choices``, closest to ``word`` first (ties alphabetical): short lists (trees, ports)."""
    return closest(word, choices, n=len(choices), cutoff=0.0)


def type_name(data_type: Any, cpp: bool = False) -> str:
    """A port type as errors name it (``float``, ``string``), or with ``cpp`` as BT.CPP and Groot2 do."""
    names = {float: "double", str: "std::string"} if cpp else {float: "float", str: "string"}
    return names.get(data_type, getattr(data_type, "__name__", str(data_type)))


def read_xml(path: Path, where: dict[ET.Element, Where]) -> ET.Element:
    """Parse ``path`` with expat, recording each element's (file, line) in ``where``."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise TreeError(f"{path}: cannot read the tree file: {exc.strerror or exc}") from None
    builder = ET.TreeBuilder()
    parser = xml.parsers.expat.ParserCreate()

    def start(tag: str, attrs: dict[str, str]) -> None:
        where[builder.start(tag, attrs)] = (path, parser.CurrentLineNumber)

    parser.StartElementHandler = start
    parser.EndElementHandler = builder.end
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as exc:
        msg = xml.parsers.expat.ErrorString(exc.code)
        raise TreeError(f"{path}:{exc.lineno}: not well-formed XML: {msg} (column {exc.offset + 1})") from None
    return builder.close()


# -- the node registry ------------------------------------------------------------------------------------------

def plugin_entry_points() -> dict[str, EntryPoint]:
    """The ``canguard.nodes`` entry points by node ID (not loaded; parsed only if a distribution names the group)."""
    if not any(ENTRY_POINT_GROUP in (dist.read_text("entry_points.txt") or "") for dist in distributions()):
        return {}
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def load_plugin(ep: EntryPoint) -> type[PortsMixin]:
    """The node class of a ``canguard.nodes`` entry point; a TreeError naming it when it is not one."""
    try:
        cls = ep.load()
    except Exception as exc:  # a broken plug-in must name itself, whatever it raised
        raise TreeError(f"node type {ep.name} ({ENTRY_POINT_GROUP} entry point {ep.value}): {exc}") from exc
    if not (inspect.isclass(cls) and issubclass(cls, PortsMixin) and issubclass(cls, py_trees.behaviour.Behaviour)):
        raise TreeError(f"node type {ep.name} ({ENTRY_POINT_GROUP} entry point {ep.value}) is not a "
                        "py_trees.ports.PortsMixin + py_trees Behaviour class")
    return cls


def build_registry(ctx: Context, only: Collection[str] | None = None) -> Registry:
    """The closed table of node types for one tree: built-ins, config actions, plug-ins (those in ``only``, all
    when None). An action named like a built-in is a TreeError; a plug-in named like either is ignored."""
    registry: Registry = {node_id: functools.partial(BUILTIN_NODES[node_id], context=ctx)  # imported when used
                          for node_id in BUILTIN_NODES if only is None or node_id in only}
    for name, action in ctx.actions.items():
        if name in BUILTIN_NODES or name == SUBTREE:
            raise TreeError(f"actions: {name!r} is the ID of a built-in node type; give the action another name")
        registry[name] = functools.partial(ConfiguredAction, context=ctx, action=action)
    for name, ep in plugin_entry_points().items():
        if name not in BUILTIN_NODES and name not in registry and (only is None or name in only):
            cls = load_plugin(ep)
            try:
                takes_context = issubclass(cls, CanguardNode) or "context" in inspect.signature(cls).parameters
            except (TypeError, ValueError):
                takes_context = False
            registry[name] = functools.partial(cls, context=ctx) if takes_context else functools.partial(cls)
    return registry


def _children_problem(kind: str, n: int) -> str | None:
    """What is wrong with ``n`` children under a node of ``kind`` (Action, Condition, Decorator...); None: nothing."""
    if kind == "Decorator":
        return None if n == 1 else f"a decorator takes exactly one child, found {n}"
    if kind == "Control":
        return None if n else "a control node needs at least one child"
    return f"{kind.lower()} nodes take no children, found {n}" if n else None


# -- palettes: Groot2 / BT.CPP <TreeNodesModel> declarations of node types canguard does not implement ----------

class PalettePort(NamedTuple):
    """One declared port (``required="true"``: a canguard extension, BT.CPP's palettes have none)."""

    direction: str  # input, output or inout
    default: str | None
    type: str
    description: str
    required: bool


@dataclass(frozen=True)
class PaletteNode:
    """One node type a palette declares."""

    node_id: str
    kind: str
    ports: Mapping[str, PalettePort]
    where: str  # file:line


@dataclass
class Palette:
    """Every node type declared by the palettes of one load, by ID (the first declaration wins)."""

    nodes: dict[str, PaletteNode] = field(default_factory=dict)

    def read(self, model: ET.Element, where: Mapping[ET.Element, Where], path: Path, problems: list[str]) -> None:
        """Add the node types of one ``<TreeNodesModel>`` element; problems with file:line."""
        def at(elem: ET.Element) -> str:
            return "{}:{}".format(*where.get(elem, (path, 0)))

        for decl in model:
            node_id = decl.attrib.get("ID")
            if decl.tag not in _KINDS or not node_id:
                problems.append(f"{at(decl)}: <{decl.tag}> in <TreeNodesModel>: expected one of {', '.join(_KINDS)}"
                                if decl.tag not in _KINDS else
                                f"{at(decl)}: <{decl.tag}> in <TreeNodesModel> without ID=\"...\"")
                continue
            ports: dict[str, PalettePort] = {}
            for port in decl:
                direction, name = _DIRECTIONS.get(port.tag), port.attrib.get("name")
                if port.tag in ("description", "metadata"):
                    continue
                if direction is None:
                    problems.append(f"{at(port)}: <{port.tag}> in {node_id}: expected {', '.join(_DIRECTIONS)}")
                elif not name:
                    problems.append(f"{at(port)}: <{port.tag}> of {node_id} without name=\"...\"")
                elif name in ports:
                    problems.append(f"{at(port)}: port {quote(name)} of {node_id} declared twice")
                else:
                    required = port.attrib.get("required", "").strip().lower() in ("true", "1")
                    ports[name] = PalettePort(direction, port.attrib.get("default"), port.attrib.get("type", ""),
                                              (port.text or "").strip(), required and direction != "output")
            first = self.nodes.setdefault(node_id, PaletteNode(node_id, decl.tag, ports, at(decl)))
            if (first.kind, dict(first.ports)) != (decl.tag, ports):
                problems.append(f"{at(decl)}: {decl.tag} {node_id} is declared again differently "
                                f"(first at {first.where})")

    def check(self, elem: ET.Element, decl: PaletteNode, at: str, tree_id: str) -> list[str]:
        """The problems of one tree node against its declaration ``decl`` (ports, children)."""
        head = f"{at}: node {elem.tag} (BehaviorTree {tree_id}, declared at {decl.where})"
        problems = [f"{head}: unknown port {quote(attr)}; ports of {elem.tag}: {', '.join(decl.ports) or '(none)'}"
                    for attr in elem.attrib if attr != "name" and not attr.startswith("_") and attr not in decl.ports]
        missing = [name for name, p in decl.ports.items() if p.required and name not in elem.attrib]
        if missing:
            problems.append(f"{head}: missing required port {', '.join(missing)} (declared required=\"true\")")
        kind_error = _children_problem(decl.kind, len(elem))
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


def read_palettes(paths: Iterable[Path]) -> Palette:
    """Every ``--nodes`` file read into one palette; a TreeError listing every problem of every file."""
    palette = Palette()
    problems: list[str] = []
    for path in map(Path, paths):
        where: dict[ET.Element, Where] = {}
        try:
            root = read_xml(path, where)
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
            palette.read(model, where, path, problems)
    if problems:
        raise TreeError(problems)
    return palette


# -- one load ---------------------------------------------------------------------------------------------------

def _autoremapped(elem: ET.Element) -> bool:
    """A ``<SubTree _autoremap="true">`` (v4; v3's ``__autoremap`` too)."""
    value = elem.attrib.get("_autoremap", elem.attrib.get("__autoremap"))
    return _TAG_ALIASES.get(elem.tag, elem.tag) == SUBTREE and (value or "").strip().lower() in ("true", "1")


def _namespace(node: py_trees.behaviour.Behaviour | None) -> str:
    """The namespace py_trees' parser gave ``node`` (its SubTree instance's; ``/`` in the main tree)."""
    return (getattr(node, "_subtree_namespace", None) or "/").rstrip("/") + "/"


class _Load:
    """One load of a tree file: read and rewritten (:meth:`read`), checked (:meth:`check`), built (:meth:`build`)."""

    def __init__(self, path: Path, ctx: Context, palette: Palette | None = None) -> None:
        self.path = path
        self.ctx = ctx
        self.where: dict[ET.Element, Where] = {}
        self.trees: dict[str, ET.Element] = {}
        self.format_version = 3
        self.palette = Palette(dict(palette.nodes) if palette is not None else {})
        self.registry: Registry = {}
        self.tokens: dict[str, tuple[ET.Element, NodeInfo]] = {}  # the node's element and info by its token
        self.conditions: dict[ET.Element, dict[str, Script]] = {}  # a SubTree's run on the parent's board
        self.private: dict[ET.Element, Inline] = {}  # elements of an inlined _autoremap subtree -> it
        self.inlined = 0
        self.errors: list[str] = []  # every problem found so far: one load reports them all
        self.broken_trees: set[str] = set()  # rewrite failed: not validated further (no follow-on errors)
        self.source_check: Literal["with_others", "always", "never"] = "with_others"
        """When guards' sources are checked: with other problems (else binding does), always, or never (unknown)."""
        self.unsure_sources: Collection[str] = ()  # declared by a config that could not build them
        self.unbound: list[str] = []  # why each palette-declared node nothing implements cannot run
        self.entry_types: dict[str, type] = {}  # typed entries (filled by _check_entry_types)

    def at(self, elem: ET.Element) -> str:
        """``file:line`` of ``elem``."""
        return "{}:{}".format(*self.where.get(elem, (self.path, 0)))

    def error(self, elem: ET.Element, msg: str, tree: str | None = None, port: str | None = None) -> TreeError:
        """A TreeError about node ``elem`` of BehaviorTree ``tree`` (its ``port``)."""
        node, name = elem.tag, elem.attrib.get("name")
        if node == SUBTREE:
            node += f" {elem.attrib.get('ID', '')}"
        elif name and not name.startswith(_TOKEN):
            node += f' "{name}"'
        where = f"node {node}" + (f" (BehaviorTree {tree})" if tree else "") + (f", port {port}" if port else "")
        return TreeError(f"{self.at(elem)}: {where}: {msg}")

    def _document(self, path: Path) -> ET.Element:
        """The ``<root>`` element of the file ``path`` (its elements' lines recorded)."""
        root = read_xml(path, self.where)
        if root.tag != "root":
            raise TreeError(f"{self.at(root)}: the document element is <{root.tag}>, expected <root> "
                            "(BehaviorTree.CPP XML)")
        return root

    def read(self, main: str | None) -> str:
        """Read the file and its includes, rewrite every tree; the main tree's ID ("" when there is none)."""
        root = self._document(self.path)
        fmt = root.attrib.get("BTCPP_format")
        if fmt not in (None, "3", "4"):
            raise TreeError(f'{self.at(root)}: BTCPP_format="{fmt}" is not supported (3 or 4)')
        self.format_version = 4 if fmt == "4" else 3
        self._collect(root, self.path, {self.path.resolve()})
        for tree_id, bt in self.trees.items():
            for attr in [a for a in bt.attrib if a.startswith("_")]:
                del bt.attrib[attr]  # Groot bookkeeping (_fullpath...), meaningless here
            try:
                if len(bt) != 1:
                    raise TreeError(f"{self.at(bt)}: BehaviorTree {tree_id} must have exactly one root node, "
                                    f"found {len(bt)}")
                if _autoremapped(bt[0]):
                    bt[0] = self._inline(bt[0], tree_id, (tree_id,))
                self._rewrite(bt[0], tree_id)
            except TreeError as exc:
                self.errors.extend(exc.problems)
                self.broken_trees.add(tree_id)
        try:
            return self._choose_main(main or root.attrib.get("main_tree_to_execute"))
        except TreeError as exc:
            self.errors.extend(exc.problems)
            return ""

    def _collect(self, root: ET.Element, path: Path, seen: set[Path]) -> None:
        for child in root:
            tag, tree_id = child.tag, child.attrib.get("ID")
            if tag == "BehaviorTree" and not tree_id:
                raise TreeError(f"{self.at(child)}: <BehaviorTree> without ID")
            if tag == "BehaviorTree" and tree_id in self.trees:
                first = self.at(self.trees[tree_id])
                raise TreeError(f"{self.at(child)}: BehaviorTree {tree_id} is defined twice (first at {first})")
            if tag == "BehaviorTree":
                self.trees[cast("str", tree_id)] = child
            elif tag == "TreeNodesModel":
                self.palette.read(child, self.where, path, self.errors)  # Groot's palette
            elif tag.lower() in ("include", "import"):
                self._include(child, path, seen)
            else:
                raise TreeError(f"{self.at(child)}: unexpected <{tag}> under <root>; expected <BehaviorTree>, "
                                "<include> or <TreeNodesModel>")

    def _include(self, elem: ET.Element, path: Path, seen: set[Path]) -> None:
        if "ros_pkg" in elem.attrib:
            raise TreeError(f"{self.at(elem)}: <include ros_pkg=...> is not supported; give a path")
        src = elem.attrib.get("path") or elem.attrib.get("src") or elem.attrib.get("file")
        if not src:
            raise TreeError(f'{self.at(elem)}: <{elem.tag}> needs path="other.xml"')
        target = path.parent / src  # an absolute src stays itself
        if target.resolve() not in seen:  # not already included (nor the including file itself)
            seen.add(target.resolve())
            self._collect(self._document(target), target, seen)

    def _rewrite(self, elem: ET.Element, tree_id: str) -> None:
        if elem.tag in _V3_WRAPPERS:
            node_id = elem.attrib.pop("ID", None)
            if not node_id:
                raise TreeError(f'{self.at(elem)}: <{elem.tag}> without ID="..." (BehaviorTree {tree_id})')
            elem.tag = node_id
        if elem.tag == SUBTREE and self.format_version == 3:
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
                raise self.error(elem, f'{attr}="{value}" is not supported: remap the SubTree\'s ports explicitly',
                                 tree_id)
        for i, child in enumerate(elem):
            if _autoremapped(child):
                elem[i] = self._inline(child, tree_id, (tree_id,))
        for attr, value in list(elem.attrib.items()):
            if value.strip() == "{=}":
                elem.attrib[attr] = "{" + attr + "}"
        for child in elem:
            self._rewrite(child, tree_id)

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
        self.inlined += 1  # BT.CPP: _autoremap never maps a key starting with _: they live under their own path
        copy = self._copy(body[0], rename, Inline(f"{target}_autoremap{self.inlined}", remaps, literals))
        copy.attrib.update({a: v for a, v in sub.attrib.items()
                            if a.startswith("_") and a not in ("_autoremap", "__autoremap")})
        for i, child in enumerate(copy):
            if _autoremapped(child):
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
        dst.extend(self._copy(child, rename, inline) for child in src)
        return dst

    def _choose_main(self, chosen: str | None) -> str:
        if not self.trees:
            raise TreeError(f"{self.path}: no <BehaviorTree> in the file")
        if chosen is None and len(self.trees) == 1:
            return next(iter(self.trees))
        if chosen is None:
            raise TreeError(f"{self.path}: several BehaviorTrees ({', '.join(self.trees)}) and no "
                            "main_tree_to_execute; name the one to run (tree: main: in the config)")
        if chosen not in self.trees:
            known = ", ".join(_closest(chosen, self.trees))
            raise TreeError(f"{self.path}: no BehaviorTree with ID {quote(chosen)}; trees in the file: {known}")
        return chosen

    def check(self) -> None:
        """Check every node of every tree against the registry, collecting every problem."""
        self.registry = build_registry(self.ctx, only={e.tag for bt in self.trees.values() for e in bt.iter()})
        pending: list[tuple[int, str]] = []  # unknown sources, with their place in errors
        for tree_id, bt in self.trees.items():
            if tree_id in self.broken_trees:
                continue
            subtree_names: dict[str, int] = {}
            for elem in bt[0].iter():
                subtree = elem.tag == SUBTREE
                scripts, problems = take_conditions(elem.attrib)  # a SubTree's: on that node, as BT.CPP
                what = f"SubTree {elem.attrib.get('ID')}" if subtree else f"node {elem.tag}"
                self.errors.extend(f"{self.at(elem)}: {what} (BehaviorTree {tree_id}), {p}" for p in problems)
                self.conditions[elem] = scripts
                if subtree:
                    try:
                        self._check_subtree(elem, tree_id, subtree_names)
                    except TreeError as exc:
                        self.errors.extend(exc.problems)
                    continue
                cls = self._check_node(elem, tree_id)
                source_error = self._check_source(elem, cls, tree_id)
                if source_error is not None:
                    pending.append((len(self.errors), source_error))
                token = f"{_TOKEN}{len(self.tokens) + 1}"
                file, line = self.where.get(elem, (self.path, 0))
                self.tokens[token] = elem, NodeInfo(elem.tag, elem.attrib.get("name") or elem.tag, file, line, tree_id)
                elem.attrib["name"] = token
        if self.source_check == "always" or (self.errors and self.source_check == "with_others"):
            # The tree will not be built, so binding (which resolves the sources and reports an
            # unknown one) will not run: the guards' unknown sources join this report, in place.
            for place, text in reversed(pending):
                self.errors.insert(place, text)

    def _check_source(self, elem: ET.Element, cls: type | None, tree_id: str) -> str | None:
        """The problem of a guard's constant ``topic_name`` naming no configured source of its kinds."""
        value = elem.attrib.get("topic_name")
        try:
            if cls is None or not issubclass(cls, GuardNode) or value is None or pyxml.is_key(value):
                return None
        except ValueError:
            return None  # a malformed {key}: already reported
        if self.source_check == "never" or (value in self.unsure_sources and value not in self.ctx.sources):
            return None
        read_before = set(self.ctx.read_sources)
        try:
            self.ctx.source(value, cls.SOURCE_KINDS)
        except (KeyError, ValueError) as exc:
            return str(self.error(elem, str(exc.args[0]), tree_id, "topic_name"))
        finally:
            self.ctx.read_sources.intersection_update(read_before)  # only a check: nothing is read yet
        return None

    def _check_subtree(self, elem: ET.Element, tree_id: str, names: dict[str, int]) -> None:
        if not elem.attrib.get("ID"):
            raise self.error(elem, 'SubTree without ID="..."', tree_id)
        target = self.target(elem, tree_id)
        if len(elem):
            raise self.error(elem, "a SubTree takes no child elements (its ports are attributes)", tree_id)
        for attr, value in elem.attrib.items():
            if attr.startswith("_"):
                raise self.error(elem, f"attribute {attr} is not supported", tree_id)
            if attr not in ("ID", "name"):
                self._key(elem, attr, value, tree_id)
        explicit = elem.attrib.get("name") or ""
        name = (explicit or target).replace(".", "_")
        names[name] = n = names.get(name, 0) + 1
        if n > 1 and explicit:
            raise self.error(elem, f"two SubTrees named {quote(name)} in BehaviorTree {tree_id}: names must differ",
                             tree_id)
        elem.attrib["name"] = f"{name}_{n}" if n > 1 else name

    def _key(self, elem: ET.Element, attr: str, value: str, tree_id: str) -> re.Match | None:
        """The ``{key}`` match of a port's ``value`` (None: a constant); a TreeError when it is malformed."""
        try:
            return pyxml.is_key(value)
        except ValueError:
            raise self.error(elem, f"malformed blackboard reference {quote(value)} (expected {{key}})", tree_id,
                             attr) from None

    def _check_node(self, elem: ET.Element, tree_id: str) -> type[PortsMixin] | None:
        """Record every problem of one node (ID, each port, children); its class, or None if unknown."""
        node_id = elem.tag
        entry = self.registry.get(node_id)
        cls = cast("type[PortsMixin] | None", entry.func if entry is not None else None)
        decl = self.palette.nodes.get(node_id)
        if decl is not None and (cls is None or issubclass(cls, ConfiguredAction)):
            # declared by a palette: checked against the declaration; it runs only when bound
            self.errors.extend(self.palette.check(elem, decl, self.at(elem), tree_id))
            if cls is None:
                self.unbound.append(unbound_message(node_id, self.at(elem), decl))
            for attr in [a for a in elem.attrib if a in decl.ports]:
                del elem.attrib[attr]  # checked against the palette; the bound config action does not read them
            return cls
        if cls is None:
            known = {*BUILTIN_NODES, *plugin_entry_points(), SUBTREE, *self.ctx.actions, *self.palette.nodes}
            near = closest(node_id, known, 5) or _closest(node_id, known)[:5]  # the five closest known IDs
            self.errors.append(f"{self.at(elem)}: unknown node ID {quote(node_id)} (BehaviorTree {tree_id}); "
                               f"known node IDs, closest first: {', '.join(near)} ({len(known)} in all: "
                               "`canguard tree --nodes-model FILE` writes every one with its ports)")
            return None
        ports = port_table(cls)
        for attr, value in elem.attrib.items():
            try:
                if attr != "name":
                    self._check_port(elem, tree_id, attr, value, ports, cls)
            except TreeError as exc:
                self.errors.extend(exc.problems)
        missing = [n for n, (_, info) in ports.items()
                   if info.required and not info.has_default and n not in elem.attrib]
        if missing:
            why = f"missing required port {', '.join(missing)} (ports of {node_id}: {', '.join(ports)})"
            self.errors.append(str(self.error(elem, why, tree_id)))
        kind_error = _children_problem(node_kind(cls), len(elem))
        if kind_error is not None:
            self.errors.append(str(self.error(elem, kind_error, tree_id)))
        return cls

    def _check_port(self, elem: ET.Element, tree_id: str, attr: str, value: str,
                    ports: Mapping[str, tuple[str, PortInformation]], cls: type) -> None:
        """Raise the TreeError of one attribute of a node of ``cls`` (unknown port, bad value...), if any."""
        if attr.startswith("_"):
            raise self.error(elem, f"attribute {attr} (BT.CPP pre/post-conditions) is not supported; "
                                   f"the supported ones: {', '.join(CONDITIONS)}", tree_id)
        if attr not in ports:
            listing = ", ".join(_closest(attr, ports)) if ports else "(none)"
            raise self.error(elem, f"unknown port {quote(attr)}; ports of {elem.tag}: {listing}", tree_id)
        direction, info = ports[attr]
        if self._key(elem, attr, value, tree_id):
            if attr in getattr(cls, "CONST_PORTS", ()):
                raise self.error(elem, f"takes a constant (it configures the node at load time), not {value}",
                                 tree_id, attr)
            return
        if direction == "output":
            raise self.error(elem, f"an output port takes a blackboard key like {{{attr}}}, not {quote(value)}",
                             tree_id, attr)
        if attr in getattr(cls, "KEY_PORTS", ()):
            raise self.error(elem, f"takes a blackboard key like {{{attr}}}, not {quote(value)}", tree_id, attr)
        try:
            converted, parsed = convert_str_to_type(value, info.data_type)
        except (ValueError, TypeError):
            converted, parsed = False, None
        if not converted:
            raise self.error(elem, f"{quote(value)} is not a valid {type_name(info.data_type)}", tree_id, attr)
        if isinstance(parsed, float) and math.isnan(parsed):
            raise self.error(elem, f"{quote(value)} is not a number", tree_id, attr)
        allowed = getattr(cls, "CHOICES", {}).get(attr)
        if allowed is not None and parsed not in allowed:
            raise self.error(elem, f"unknown value {quote(value)}; expected one of {', '.join(allowed)}", tree_id, attr)

    def check_cycles(self, main_id: str) -> None:
        """A TreeError at the first SubTree that runs a tree it is part of."""
        def visit(tree_id: str, stack: list[str]) -> None:
            for elem in self.trees[tree_id].iter(SUBTREE):
                target = elem.attrib["ID"]
                if target in stack:
                    chain = " -> ".join([*stack[stack.index(target) :], target])
                    raise self.error(elem, f"SubTree cycle: {chain}", tree_id)
                visit(target, [*stack, target])

        visit(main_id, [main_id])

    def build(self, main_id: str) -> LoadedTree:
        """The tree ``main_id`` built by py_trees' parser, its nodes named, given their scopes and bound."""
        main = self.trees[main_id]
        try:
            root = pyxml.build_tree_from_xml(main, pyxml.build_subtree_remapping(main, self.trees, {}, "/"),
                                             self.registry, self.trees)
        except TreeError:
            raise
        except (pyxml.XMLParserError, ValueError, KeyError, TypeError, AssertionError, RuntimeError,
                NotImplementedError) as exc:
            raise TreeError(f"{self.path}: BehaviorTree {main_id}: {self._untoken(str(exc))}") from exc
        nodes = list(_preorder(root))  # BT.CPP creates (and types the entries) in this order
        boards = subtree_scopes(self.trees, main_id, self.entry_types)
        for board in boards.values():
            Blackboard.storage.update(board.literals)
        loaded = LoadedTree(root, main_id, self.path, self.ctx, self.format_version)
        counts: dict[str, int] = {}
        for node in nodes:
            parts = node.name.split(".")
            elem, info = self.tokens[parts[-1]]
            board = boards.get(_namespace(node), boards["/"])
            if elem in self.private:  # a node of an inlined _autoremap subtree: its ports and _keys
                board = board.inlined(self.private[elem])
                Blackboard.storage.update({k: v for k, v in board.literals.items() if k not in Blackboard.storage})
            if isinstance(node, CanguardNode):
                node.board = board
            install_conditions(node, self.conditions.get(elem, {}), board)
            readable = "/".join([*(p for p in parts[:-1] if p not in self.tokens), info.name])
            counts[readable] = k = counts.get(readable, 0) + 1
            node.name = readable if k == 1 else f"{readable}#{k}"
            loaded.nodes[node.id] = NodeInfo(info.node_id, node.name, info.file, info.line, info.tree)
        self._install_subtree_conditions(nodes, boards)
        self._bind(nodes, loaded)
        return loaded

    def _install_subtree_conditions(self, nodes: list[py_trees.behaviour.Behaviour],
                                    boards: dict[str, TreeBlackboard]) -> None:
        """Conditions on a ``<SubTree>`` wrap its instance's root, on the parent's scope (BT.CPP's SubTree node)."""
        for ns, scope in boards.items():
            scripts = self.conditions.get(scope.element) if scope.element is not None else None
            if not scripts:
                continue
            for node in nodes:  # the instance's root: the one node of its scope whose parent is outside it
                if _namespace(node).startswith(ns) and not _namespace(node.parent).startswith(ns):
                    install_conditions(node, scripts, boards[scope.parent])
                    break

    def _bind(self, nodes: list[py_trees.behaviour.Behaviour], loaded: LoadedTree) -> None:
        """Type the entries, give every node the tree's wake-up signal and bind it, collecting every problem."""
        ours = [node for node in nodes if isinstance(node, CanguardNode)]
        self._check_entry_types(ours, loaded.nodes)
        for node in ours:
            node.wake_up = loaded.wake_up  # BT.CPP's factory gives every node of a tree its wake-up signal
            try:
                node.bind()
            except PortError as exc:
                self.errors.append(f"{loaded.nodes[node.id].where}, port {exc.port}: {exc.message}")
            except (ValueError, KeyError, TypeError) as exc:
                self.errors.append(f"{loaded.nodes[node.id].where}: {exc}")
        if self.errors:
            raise TreeError(self.errors)

    def _check_entry_types(self, nodes: list[CanguardNode], infos: dict[Any, NodeInfo]) -> None:
        """BT.CPP's rule: the first typed port wired to an entry fixes its type (a string converts to any)."""
        first: dict[str, tuple[type, str]] = {}
        for node in nodes:  # in tree order, as BT.CPP creates them
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
                    self.errors.append(f"{info.where}, port {port}: the entry [{key.lstrip('/')}] was created with "
                                       f"type [{type_name(was, cpp=True)}] ({at}) and is used here as "
                                       f"[{type_name(kind, cpp=True)}]; one entry has one type (as in BT.CPP)")

    def _untoken(self, text: str) -> str:
        def name(m: re.Match) -> str:
            _, info = self.tokens.get(m.group(0), (None, None))
            return f"{info.node_id} at line {info.line}" if info else m.group(0)

        text = re.sub(re.escape(_TOKEN) + r"\d+", name, text)
        lines: dict[str, list[str]] = {}
        for _, info in self.tokens.values():
            if f"'{info.node_id}'" in text:
                lines.setdefault(info.node_id, []).append(f"{info.file.name}:{info.line}")
        hints = "; ".join(f"{node_id} at {', '.join(where)}" for node_id, where in lines.items())
        return f"{text} ({hints})" if hints else text


def _checked(path: str | Path, ctx: Context, main: str | None, palette: Palette | None,
             *, to_run: bool) -> tuple[_Load, str]:
    """The checked load and the main tree's ID; a TreeError listing every problem (``to_run``: unbound nodes too)."""
    load = _Load(Path(path), ctx, palette)
    main_id = load.read(main)
    load.check()
    if to_run:
        load.errors.extend(load.unbound)
    if load.errors:
        raise TreeError(load.errors)
    load.check_cycles(main_id)
    return load, main_id


def load_tree(path: str | Path, ctx: Context, main: str | None = None, palette: Palette | None = None) -> LoadedTree:
    """Load, validate and bind the tree ``main`` of ``path`` (default: ``main_tree_to_execute``, or the only tree)
    for ``ctx``; ``palette``: ``--nodes`` files. A TreeError names file and line of every problem."""
    load, main_id = _checked(path, ctx, main, palette, to_run=True)
    return load.build(main_id)


def validate_tree(path: str | Path, ctx: Context, main: str | None = None,
                  palette: Palette | None = None) -> tuple[str, list[str]]:
    """Check a tree file without building it: (main tree ID, why each palette-declared node cannot run yet)."""
    load, main_id = _checked(path, ctx, main, palette, to_run=False)
    return main_id, list(load.unbound)


def partial_tree_problems(partial: PartialConfig | None) -> list[str]:
    """The problems of the tree of a config that has problems itself (``ConfigError.partial``), checked
    without being built; a source the config declares but got wrong is not reported again."""
    if partial is None or partial.tree is None:
        return []
    load = _Load(partial.tree.file, Context(ManualClock(), partial.sources, actions=partial.actions))
    load.source_check = "always" if partial.sources_ok else "never"
    load.unsure_sources = partial.declared_sources
    try:
        load.read(partial.tree.main)
        load.check()
    except TreeError as exc:  # unreadable or not well-formed XML, a broken include
        return [*load.errors, *exc.problems]
    return load.errors
