"""BehaviorTree.CPP XML trees on py_trees: registry, loader, validation and display tools.

Loading a tree (:func:`load_tree`) is four steps, none of which builds a tree
by itself — py_trees' own parser does that:

1. **Read** the file with expat, keeping every element's line number, and inline
   ``<include path="..."/>`` files (each element keeps its own file and line).
2. **Rewrite** BehaviorTree.CPP v3 spellings to v4 tags: ``<Condition ID="X" .../>``,
   ``<Action ID="X"/>``, ``<Decorator ID="X">``, ``<Control ID="X">`` become ``<X .../>``
   (v4 accepts both too), ``SequenceStar`` is ``SequenceWithMemory``,
   ``RetryUntilSuccesful`` (v3's typo) is ``RetryUntilSuccessful``, ``SubTreePlus`` is
   ``SubTree``, Parallel's ``success_threshold`` / ``failure_threshold`` are
   ``success_count`` / ``failure_count``, and ``{=}`` is ``{<port name>}``.
   A root with or without ``BTCPP_format="4"`` is accepted.
3. **Validate** every node against the registry before py_trees sees it: unknown
   node ID (the known IDs are listed, closest first), unknown port (the node's
   ports listed), ill-typed constant (``max_current="abc"``), constant where a
   ``{key}`` is needed or the reverse, unknown choice (``operator="GE"``), missing
   required port, wrong number of children, unknown SubTree, SubTree cycles. Each
   is a :class:`~canguard.errors.TreeError` naming file, line, node and port.
4. **Parse** the rewritten XML with
   :func:`py_trees.parsers.behaviour_tree_xml.parse_behaviour_tree_xml` and an
   explicit, closed registry (:func:`build_registry`): ``{key}`` remapping, SubTree
   with remapping and ``main_tree_to_execute`` are py_trees'. Then every node gets
   a readable name (its ``name`` attribute, else its ID; ``#2``, ``#3`` for
   repeats; ``SubTreeName/`` in front inside a SubTree) and every canguard node is
   bound (:meth:`~canguard.bt.nodes.base.CanguardNode.bind`): sources resolved,
   protection models built and subscribed. Errors there are TreeErrors too.

Node names are made readable *after* parsing because py_trees prefixes the names
of children of named composites with the parent's name (``Seq.Guard``) and gives
unnamed nodes a uuid; the loader hands the parser unique placeholder names and
maps them back.
"""

from __future__ import annotations

import difflib
import functools
import inspect
import math
import re
import shutil
import tempfile
import xml.etree.ElementTree as ET
import xml.parsers.expat
from collections.abc import Collection, Iterator, Mapping
from dataclasses import dataclass, field
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any, Literal, cast

import py_trees
from py_trees.parsers.behaviour_tree_xml import XMLParserError, is_key, parse_behaviour_tree_xml
from py_trees.ports import PortInformation, PortsMixin
from py_trees.ports_utils import convert_str_to_type

from canguard.bt.context import Context
from canguard.bt.nodes import BUILTIN_NODES, CanguardNode, ConfiguredAction, GuardNode, PortError
from canguard.config.schema import Config, PartialConfig, SourceKind
from canguard.errors import TreeError
from canguard.protect.base import ProtectionModel, Snapshot

ENTRY_POINT_GROUP = "canguard.nodes"
"""Entry-point group through which other packages add node types (``NodeID = "pkg.mod:Class"``)."""

_V3_WRAPPERS = ("Action", "Condition", "Decorator", "Control")
_TAG_ALIASES = {
    "SequenceStar": "SequenceWithMemory",
    "RetryUntilSuccesful": "RetryUntilSuccessful",
    "SubTreePlus": "SubTree",
}
_PORT_ALIASES: dict[str, dict[str, str]] = {
    "Parallel": {
        "success_threshold": "success_count",
        "failure_threshold": "failure_count",
        "threshold": "success_count",
    },
}
_SUBTREE = "SubTree"
_TOKEN = "@"
"""Placeholder node names handed to py_trees are ``@<n>``."""

Registry = dict[str, functools.partial]


# ---------------------------------------------------------------------------------------
# Registry
# ---------------------------------------------------------------------------------------
def plugin_entry_points() -> dict[str, EntryPoint]:
    """The ``canguard.nodes`` entry points by node ID (not loaded)."""
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def _load_plugin(ep: EntryPoint) -> type[PortsMixin]:
    try:
        cls = ep.load()
    except Exception as exc:  # a broken plug-in must name itself, whatever it raised
        raise TreeError(f"node type {ep.name} ({ENTRY_POINT_GROUP} entry point {ep.value}): {exc}") from exc
    if not (inspect.isclass(cls) and issubclass(cls, PortsMixin) and issubclass(cls, py_trees.behaviour.Behaviour)):
        raise TreeError(
            f"node type {ep.name} ({ENTRY_POINT_GROUP} entry point {ep.value}) is not a "
            "py_trees.ports.PortsMixin + py_trees Behaviour class"
        )
    return cls


def _takes_context(cls: type) -> bool:
    if issubclass(cls, CanguardNode):
        return True
    try:
        return "context" in inspect.signature(cls).parameters
    except (TypeError, ValueError):
        return False


def build_registry(ctx: Context, only: Collection[str] | None = None) -> Registry:
    """The closed table of node types for one tree: ``{node ID: partial(cls, context=ctx, ...)}``.

    Built-in node types, one :class:`~canguard.bt.nodes.actions.ConfiguredAction` per
    ``ctx.actions`` entry, and the ``canguard.nodes`` entry points. Plug-ins are
    imported lazily: only those named in ``only`` (all when None). A config action
    named like a built-in node is a TreeError; a plug-in named like a built-in or
    an action is ignored (built-ins and the config win).
    """
    registry: Registry = {node_id: functools.partial(cls, context=ctx) for node_id, cls in BUILTIN_NODES.items()}
    for name, action in ctx.actions.items():
        if name in registry or name == _SUBTREE:
            raise TreeError(f"actions: {name!r} is the ID of a built-in node type; give the action another name")
        registry[name] = functools.partial(ConfiguredAction, context=ctx, action=action)
    for name, ep in plugin_entry_points().items():
        if name in registry or (only is not None and name not in only):
            continue
        cls = _load_plugin(ep)
        registry[name] = functools.partial(cls, context=ctx) if _takes_context(cls) else functools.partial(cls)
    return registry


def known_node_ids(ctx: Context | None = None) -> list[str]:
    """Every node ID a tree may use (built-ins, config actions, plug-ins, SubTree), sorted."""
    ids = set(BUILTIN_NODES) | set(plugin_entry_points()) | {_SUBTREE}
    if ctx is not None:
        ids |= set(ctx.actions)
    return sorted(ids)


def node_kind(cls: type) -> str:
    """Action, Condition, Control or Decorator."""
    kind = getattr(cls, "KIND", None)
    if isinstance(kind, str):
        return kind
    if issubclass(cls, py_trees.decorators.Decorator):
        return "Decorator"
    if issubclass(cls, py_trees.composites.Composite):
        return "Control"
    return "Action"


# ---------------------------------------------------------------------------------------
# Loaded tree
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NodeInfo:
    """Where a node of a loaded tree comes from."""

    node_id: str
    """Its node type (``IsCurrentSafe``, ``PerformRecovery``...)."""
    name: str
    """Its readable, unique name (as in events and ``canguard tree``)."""
    file: Path
    line: int
    tree: str
    """The ``<BehaviorTree ID>`` it is written in."""


GuardKind = Literal["threshold", "i2t"]


@dataclass(frozen=True)
class GuardView:
    """One guarded signal of a loaded tree, for reports, plots and the demo."""

    node: str
    """The guard node's readable name."""
    source: str
    role: str
    """The signal's role in the source (``current``, or a joint name)."""
    kind: GuardKind
    """``threshold`` (IsCurrentNormal, IsCurrentSafe, IsJointEffortNormal) or ``i2t`` (IsI2tSafe)."""
    model: ProtectionModel

    def snapshot(self) -> Snapshot:
        """The model's present state (the peak latch untouched)."""
        return self.model.snapshot()

    def threshold(self) -> float:
        """The trip threshold in force (A or N·m; for I²t the trip level of the accumulator)."""
        return self.model.snapshot().threshold


@dataclass
class LoadedTree:
    """A parsed, validated and bound tree."""

    root: py_trees.behaviour.Behaviour
    tree: py_trees.trees.BehaviourTree
    main_id: str
    path: Path
    context: Context
    format_version: int
    """4 with ``BTCPP_format="4"``, else 3."""
    tree_ids: tuple[str, ...]
    """Every ``<BehaviorTree ID>`` of the document (includes inlined)."""
    nodes: dict[Any, NodeInfo] = field(default_factory=dict)
    """NodeInfo by behaviour id (``node.id``)."""

    def tick(self) -> py_trees.common.Status:
        """Tick the root once (sets ``ctx.tree_start`` at the first tick, as the engine does)."""
        if self.context.tree_start is None:
            self.context.tree_start = self.context.now()
        self.root.tick_once()
        return self.root.status

    def halt(self) -> None:
        """Halt the whole tree (every RUNNING node is stopped)."""
        self.root.stop(py_trees.common.Status.INVALID)

    def find(self, name: str) -> py_trees.behaviour.Behaviour:
        """The node with that readable name; KeyError listing the names."""
        for node in self.root.iterate():
            if node.name == name:
                return node
        raise KeyError(f"no node named {name!r}; nodes: {', '.join(n.name for n in self.root.iterate())}")

    def info(self, node: py_trees.behaviour.Behaviour) -> NodeInfo:
        """Where ``node`` is written."""
        return self.nodes[node.id]

    def guard_nodes(self) -> list[GuardNode]:
        """Every guard condition (the nodes that read sources), in tree order."""
        return [n for n in _preorder(self.root) if isinstance(n, GuardNode)]

    def guards(self) -> list[GuardView]:
        """One :class:`GuardView` per guarded signal (a joints guard gives one per joint), in tree order."""
        return [
            GuardView(node.name, node.topic_name, role, cast("GuardKind", kind), model)
            for node in self.guard_nodes()
            for role, model, kind in node.guarded()
        ]


# ---------------------------------------------------------------------------------------
# Reading XML with line numbers
# ---------------------------------------------------------------------------------------
Where = tuple[Path, int]


def _read_xml(path: Path, where: dict[ET.Element, Where]) -> ET.Element:
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


def _closest(word: str, choices: Collection[str]) -> list[str]:
    """``choices`` sorted by similarity to ``word``, closest first (ties alphabetical)."""
    lw = word.lower()
    return sorted(choices, key=lambda c: (-difflib.SequenceMatcher(None, lw, c.lower()).ratio(), c))


def _type_name(data_type: Any) -> str:
    names = {float: "float", int: "int", str: "string", bool: "bool"}
    return names.get(data_type, getattr(data_type, "__name__", str(data_type)))


# ---------------------------------------------------------------------------------------
# The loader
# ---------------------------------------------------------------------------------------
class _Loader:
    """One load: the document, its trees, the registry, the placeholder names."""

    def __init__(self, path: Path, ctx: Context) -> None:
        self.path = path
        self.ctx = ctx
        self.where: dict[ET.Element, Where] = {}
        self.trees: dict[str, ET.Element] = {}
        self.format_version = 3
        self.main_attr: str | None = None
        self.infos: dict[str, NodeInfo] = {}
        self.registry: Registry = {}
        self.classes: dict[str, type[PortsMixin]] = {}
        self.errors: list[str] = []
        """Every problem found so far (one load reports them all, not only the first)."""
        self.broken_trees: set[str] = set()
        """BehaviorTrees whose rewrite failed: not validated further (no follow-on errors)."""
        self.source_check: Literal["with_others", "always", "never"] = "with_others"
        """When :meth:`validate` checks guards' sources: with other problems (binding checks them
        otherwise), always (a tree checked without binding), or never (the sources are unknown)."""
        self.unsure_sources: Collection[str] = ()
        """Source names a config declares but could not build: not reported as unknown (follow-on)."""

    # -- errors ------------------------------------------------------------------------
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

    def check(self, main: str | None) -> str:
        """Steps 1 to 3: read, rewrite, choose the main tree, validate every node; the main tree's ID.

        Problems are collected in ``errors``; a file that cannot be read or parsed raises at once.
        """
        self.read()
        self.rewrite()
        try:
            main_id = self.choose_main(main)
        except TreeError as exc:
            self.errors.extend(exc.problems)
            main_id = ""
        self.make_registry()
        self.validate()
        return main_id

    # -- step 1: read, includes ---------------------------------------------------------
    def read(self) -> None:
        root = _read_xml(self.path, self.where)
        if root.tag != "root":
            raise TreeError(
                f"{self.at(root)}: the document element is <{root.tag}>, expected <root> (BehaviorTree.CPP XML)"
            )
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
                continue  # Groot's palette: informative only
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
        inc_root = _read_xml(target, self.where)
        if inc_root.tag != "root":
            raise TreeError(f"{self.at(inc_root)}: the document element is <{inc_root.tag}>, expected <root>")
        self._collect(inc_root, target, seen)

    # -- step 2: rewrite v3 spellings ---------------------------------------------------
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
        for attr, value in list(elem.attrib.items()):
            if value.strip() == "{=}":
                elem.attrib[attr] = "{" + attr + "}"
        for child in elem:
            self._rewrite(child, tree_id)

    # -- registry -------------------------------------------------------------------------
    def make_registry(self) -> None:
        used: set[str] = set()
        for bt in self.trees.values():
            used.update(e.tag for e in bt.iter() if e is not bt)
        self.registry = build_registry(self.ctx, only=used)
        for node_id, entry in self.registry.items():
            self.classes[node_id] = cast("type[PortsMixin]", entry.func)

    # -- step 3: validation ---------------------------------------------------------------
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
            raise TreeError(f"{self.path}: no BehaviorTree with ID {chosen!r}; trees in the file: {known}")
        return chosen

    def validate(self) -> None:
        """Check every node of every tree, collecting every problem (see :meth:`raise_collected`)."""
        counter = 0
        pending: list[tuple[int, str]] = []
        """Unknown sources, with their place in ``errors``: reported only with other problems."""
        for tree_id, bt in self.trees.items():
            if tree_id in self.broken_trees:
                continue
            subtree_names: dict[str, int] = {}
            for elem in bt[0].iter():
                if elem.tag == _SUBTREE:
                    try:
                        self._check_subtree(elem, tree_id, subtree_names)
                    except TreeError as exc:
                        self.errors.extend(exc.problems)
                else:
                    cls = self._check_node(elem, tree_id)
                    if cls is not None and issubclass(cls, GuardNode):
                        source_error = self._check_source(elem, cls, tree_id)
                        if source_error is not None:
                            pending.append((len(self.errors), source_error))
                    counter += 1
                    token = f"{_TOKEN}{counter}"
                    file, line = self.where.get(elem, (self.path, 0))
                    readable = elem.attrib.get("name") or elem.tag
                    self.infos[token] = NodeInfo(elem.tag, readable, file, line, tree_id)
                    elem.attrib["name"] = token
        if self.source_check == "always" or (self.errors and self.source_check == "with_others"):
            # The tree will not be built, so binding (which resolves the sources and reports an
            # unknown one) will not run: the guards' unknown sources join this report, in place.
            for place, text in reversed(pending):
                self.errors.insert(place, text)

    def _check_source(self, elem: ET.Element, cls: type, tree_id: str) -> str | None:
        """The problem of a guard's constant ``topic_name`` naming no configured source of its kinds."""
        value = elem.attrib.get("topic_name")
        try:
            if value is None or is_key(value) or self.source_check == "never":
                return None
        except ValueError:
            return None  # a malformed {key}: already reported
        if value in self.unsure_sources and value not in self.ctx.sources:
            return None
        read_before = set(self.ctx.read_sources)
        try:
            self.ctx.source(value, cls.SOURCE_KINDS)  # type: ignore[attr-defined]
        except (KeyError, ValueError) as exc:
            return str(self.error(elem, str(exc.args[0]), tree_id, "topic_name"))
        finally:
            self.ctx.read_sources.intersection_update(read_before)  # only a check: nothing is read yet
        return None

    def _check_subtree(self, elem: ET.Element, tree_id: str, names: dict[str, int]) -> None:
        target = elem.attrib.get("ID")
        if not target:
            raise self.error(elem, 'SubTree without ID="..."', tree_id)
        if target not in self.trees:
            known = ", ".join(_closest(target, self.trees))
            raise self.error(elem, f"unknown BehaviorTree {target!r}; trees in the file: {known}", tree_id)
        if len(elem):
            raise self.error(elem, "a SubTree takes no child elements (its ports are attributes)", tree_id)
        for attr, value in elem.attrib.items():
            if attr in ("ID", "name"):
                continue
            if attr.startswith("_"):
                raise self.error(elem, f"attribute {attr} is not supported", tree_id)
            self._check_key_syntax(elem, attr, value, tree_id)
        name = elem.attrib.get("name") or ""
        explicit = bool(name)
        name = (name or target).replace(".", "_")
        n = names.get(name, 0) + 1
        names[name] = n
        if n > 1:
            if explicit:
                raise self.error(
                    elem, f"two SubTrees named {name!r} in BehaviorTree {tree_id}: names must differ", tree_id
                )
            name = f"{name}_{n}"
        elem.attrib["name"] = name

    def _check_key_syntax(self, elem: ET.Element, attr: str, value: str, tree_id: str) -> re.Match | None:
        try:
            match = is_key(value)
        except ValueError:
            raise self.error(
                elem, f"malformed blackboard reference {value!r} (expected {{key}})", tree_id, attr
            ) from None
        if match and match.group(1).startswith("@"):
            raise self.error(
                elem,
                f"{value}: root-blackboard references {{@key}} are not supported; use {{key}}",
                tree_id,
                attr,
            )
        return match

    def _check_node(self, elem: ET.Element, tree_id: str) -> type[PortsMixin] | None:
        """Record every problem of one node (ID, each port, children); its class, or None if unknown."""
        node_id = elem.tag
        cls = self.classes.get(node_id)
        if cls is None:
            known = _closest(node_id, known_node_ids(self.ctx))
            self.errors.append(
                f"{self.at(elem)}: unknown node ID {node_id!r} (BehaviorTree {tree_id}); "
                f"known node IDs, closest first: {', '.join(known)}"
            )
            return None
        ports: dict[str, tuple[str, PortInformation]] = {
            **{n: ("input", i) for n, i in cls.input_ports().items()},
            **{n: ("output", i) for n, i in cls.output_ports().items()},
        }
        const_ports: Collection[str] = getattr(cls, "CONST_PORTS", frozenset())
        key_ports: Collection[str] = getattr(cls, "KEY_PORTS", frozenset())
        choices: Mapping[str, tuple[str, ...]] = getattr(cls, "CHOICES", {})
        for attr, value in elem.attrib.items():
            if attr == "name":
                continue
            try:
                self._check_port(elem, tree_id, attr, value, ports, const_ports, key_ports, choices)
            except TreeError as exc:
                self.errors.extend(exc.problems)
        missing = [
            n for n, (_, info) in ports.items() if info.required and not info.has_default and n not in elem.attrib
        ]
        if missing:
            self.errors.append(str(self.error(
                elem,
                f"missing required port {', '.join(missing)} (ports of {node_id}: {', '.join(ports)})",
                tree_id,
            )))
        n = len(elem)
        kind_error: str | None = None
        if issubclass(cls, py_trees.decorators.Decorator):
            if n != 1:
                kind_error = f"a decorator takes exactly one child, found {n}"
        elif issubclass(cls, py_trees.composites.Composite):
            if n == 0:
                kind_error = "a control node needs at least one child"
        elif n:
            kind_error = f"{node_kind(cls).lower()} nodes take no children, found {n}"
        if kind_error is not None:
            self.errors.append(str(self.error(elem, kind_error, tree_id)))
        return cls

    def _check_port(
        self,
        elem: ET.Element,
        tree_id: str,
        attr: str,
        value: str,
        ports: Mapping[str, tuple[str, PortInformation]],
        const_ports: Collection[str],
        key_ports: Collection[str],
        choices: Mapping[str, tuple[str, ...]],
    ) -> None:
        """Raise the TreeError of one attribute of a node (unknown port, bad value...), if any."""
        node_id = elem.tag
        if attr.startswith("_"):
            raise self.error(elem, f"attribute {attr} (BT.CPP pre/post-conditions) is not supported", tree_id)
        if attr not in ports:
            listing = ", ".join(_closest(attr, ports)) if ports else "(none)"
            raise self.error(elem, f"unknown port {attr!r}; ports of {node_id}: {listing}", tree_id)
        direction, info = ports[attr]
        match = self._check_key_syntax(elem, attr, value, tree_id)
        if match:
            if attr in const_ports:
                raise self.error(
                    elem,
                    f"takes a constant (it configures the node at load time), not {value}",
                    tree_id,
                    attr,
                )
            return
        if direction == "output":
            raise self.error(
                elem,
                f"an output port takes a blackboard key like {{{attr}}}, not {value!r}",
                tree_id,
                attr,
            )
        if attr in key_ports:
            raise self.error(elem, f"takes a blackboard key like {{{attr}}}, not {value!r}", tree_id, attr)
        try:
            converted, parsed = convert_str_to_type(value, info.data_type)
        except (ValueError, TypeError):
            converted, parsed = False, None
        if not converted:
            raise self.error(elem, f"{value!r} is not a valid {_type_name(info.data_type)}", tree_id, attr)
        if isinstance(parsed, float) and math.isnan(parsed):
            raise self.error(elem, f"{value!r} is not a number", tree_id, attr)
        allowed = choices.get(attr)
        if allowed is not None and parsed not in allowed:
            raise self.error(elem, f"unknown value {value!r}; expected one of {', '.join(allowed)}", tree_id, attr)

    def check_cycles(self, main_id: str) -> None:
        def visit(tree_id: str, stack: list[str]) -> None:
            for elem in self.trees[tree_id].iter(_SUBTREE):
                target = elem.attrib["ID"]
                if target in stack:
                    chain = " -> ".join([*stack[stack.index(target) :], target])
                    raise self.error(elem, f"SubTree cycle: {chain}", tree_id)
                visit(target, [*stack, target])

        visit(main_id, [main_id])

    # -- step 4: parse with py_trees --------------------------------------------------------
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
            except (
                XMLParserError,
                ValueError,
                KeyError,
                TypeError,
                AssertionError,
                RuntimeError,
                NotImplementedError,
            ) as exc:
                raise TreeError(f"{self.path}: BehaviorTree {main_id}: {self._untoken(str(exc))}") from exc

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
        nodes = list(root.iterate())
        placed: list[tuple[py_trees.behaviour.Behaviour, NodeInfo, str]] = []
        for node in nodes:
            parts = node.name.split(".")
            info = self.infos[parts[-1]]
            prefix = [p for p in parts[:-1] if p not in self.infos]
            placed.append((node, info, "/".join([*prefix, info.name])))
        order = {id(n): i for i, n in enumerate(_preorder(root))}
        placed.sort(key=lambda t: order[id(t[0])])
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
                info = loaded_nodes[node.id]
                try:
                    node.bind()
                except PortError as exc:
                    self.errors.append(
                        f"{info.file}:{info.line}: node {info.name} (BehaviorTree {info.tree}), "
                        f"port {exc.port}: {exc.message}"
                    )
                except (ValueError, KeyError, TypeError) as exc:
                    self.errors.append(
                        f"{info.file}:{info.line}: node {info.name} (BehaviorTree {info.tree}): {exc}"
                    )
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
        )


def _preorder(node: py_trees.behaviour.Behaviour) -> Iterator[py_trees.behaviour.Behaviour]:
    yield node
    for child in node.children:
        yield from _preorder(child)


def load_tree(path: str | Path, ctx: Context, main: str | None = None) -> LoadedTree:
    """Load, validate and bind the BehaviorTree.CPP XML tree ``main`` of ``path`` for ``ctx``.

    ``main`` defaults to the root's ``main_tree_to_execute``, or to the only tree.
    Every problem is a :class:`~canguard.errors.TreeError` naming file and line.
    """
    loader = _Loader(Path(path), ctx)
    main_id = loader.check(main)
    loader.raise_collected()  # every node problem of every tree at once
    loader.check_cycles(main_id)
    root = loader.parse(main_id)
    return loader.finish(root, main_id)


# ---------------------------------------------------------------------------------------
# Checks against the config
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ConfigCheck:
    """What ``canguard check`` reports about a tree and its config beyond hard errors."""

    unread_sources: tuple[str, ...]
    """Configured sources no node of the tree reads (stale events only)."""

    def warnings(self) -> list[str]:
        """One line per finding."""
        return [
            f"source {name!r} is configured but the tree does not read it (only stale events)"
            for name in self.unread_sources
        ]


def validate_against_config(loaded: LoadedTree, cfg: Config) -> ConfigCheck:
    """Check every guard's ``topic_name`` against ``cfg.sources``; report sources nobody reads.

    TreeError (file, line, node, the configured sources with their kinds) when a
    topic_name names no source, or a source of the wrong kind.
    """
    listing = ", ".join(f"{n} ({s.kind})" for n, s in sorted(cfg.sources.items())) or "(none configured)"
    read: set[str] = set()
    errors: list[str] = []
    for guard in loaded.guard_nodes():
        info = loaded.info(guard)
        name = guard.topic_name
        kinds: tuple[SourceKind, ...] = guard.SOURCE_KINDS
        src = cfg.sources.get(name)
        where = f"{info.file}:{info.line}: node {info.name} (BehaviorTree {info.tree}), port topic_name"
        if src is None:
            errors.append(f"{where}: unknown source {name!r}; configured sources: {listing}")
            continue
        if src.kind not in kinds:
            errors.append(
                f"{where}: source {name!r} is of kind {src.kind}, {info.node_id} needs "
                f"{' or '.join(kinds)}; configured sources: {listing}"
            )
            continue
        read.add(name)
    if errors:
        raise TreeError(errors)
    return ConfigCheck(unread_sources=tuple(n for n in cfg.sources if n not in read))


# ---------------------------------------------------------------------------------------
# Display tools (canguard tree)
# ---------------------------------------------------------------------------------------
def render_text(root: py_trees.behaviour.Behaviour, show_status: bool = False) -> str:
    """py_trees' unicode drawing of the tree, with the loader's readable node names."""
    return py_trees.display.unicode_tree(root, show_status=show_status)


def render_dot(root: py_trees.behaviour.Behaviour, path: str | Path) -> Path:
    """Write the tree as Graphviz: ``.dot`` text always; ``.png`` / ``.svg`` / ``.pdf`` need ``dot``."""
    out = Path(path)
    fmt = out.suffix.lower().lstrip(".")
    graph = py_trees.display.dot_tree(root)
    if fmt in ("dot", "gv"):
        out.write_text(graph.to_string(), encoding="utf-8")
        return out
    if fmt not in ("png", "svg", "pdf"):
        raise TreeError(f"{out}: unknown drawing format {out.suffix!r}; use .dot, .png, .svg or .pdf")
    if shutil.which("dot") is None:
        raise TreeError(
            f"{out}: drawing .{fmt} needs Graphviz's `dot` program, which is not installed "
            "(e.g. apt install graphviz); a .dot file works without it"
        )
    try:
        graph.write(str(out), format=fmt)
    except (OSError, AssertionError) as exc:  # pydot reports dot's own failures as AssertionError
        raise TreeError(f"{out}: Graphviz failed: {exc}") from exc
    return out


_GROOT_TYPES = {float: "double", int: "int", str: "std::string", bool: "bool"}


def _default_text(value: Any) -> str:
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return str(value)


def nodes_model_xml(ctx: Context | None = None, include_plugins: bool = True) -> str:
    """A Groot2 ``<TreeNodesModel>`` of every canguard node type and its ports.

    With ``ctx``, the config's actions are included (each with its ``output_time`` port).
    """
    doc = ET.Element("root", {"BTCPP_format": "4"})
    model = ET.SubElement(doc, "TreeNodesModel")
    entries: list[tuple[str, type[PortsMixin], str]] = [
        (n, c, getattr(c, "DESCRIPTION", "")) for n, c in BUILTIN_NODES.items()
    ]
    if ctx is not None:
        for name, action in ctx.actions.items():
            entries.append((name, ConfiguredAction, f"config action: {len(action.frames)} frame(s)"))
    if include_plugins:
        for name, ep in plugin_entry_points().items():
            if name not in BUILTIN_NODES:
                cls = _load_plugin(ep)
                entries.append((name, cls, getattr(cls, "DESCRIPTION", "") or f"plug-in {ep.value}"))
    for name, cls, description in entries:
        elem = ET.SubElement(model, node_kind(cls), {"ID": name})
        for direction, ports in (("input_port", cls.input_ports()), ("output_port", cls.output_ports())):
            for port_name, info in ports.items():
                attrs = {
                    "name": port_name,
                    "type": _GROOT_TYPES.get(info.data_type, _type_name(info.data_type)),
                }
                if info.has_default:
                    attrs["default"] = _default_text(info.default_value)
                port = ET.SubElement(elem, direction, attrs)
                port.text = info.description
        if description:  # BT.CPP 4 writes manifest metadata this way; Groot2 shows it
            fields = ET.SubElement(elem, "MetadataFields")
            ET.SubElement(fields, "Metadata", {"description": description})
    ET.indent(doc, space="  ")
    return ET.tostring(doc, encoding="unicode") + "\n"


# ---------------------------------------------------------------------------------------
# What the CLI calls (canguard check / canguard tree)
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TreeReport:
    """``canguard check``'s view of the config's tree."""

    loaded: LoadedTree
    text: str
    """A summary line and the tree drawing."""
    warnings: list[str]


def context_for(cfg: Config, clock: Any = None) -> Context:
    """A context for ``cfg`` (sources, actions, stop frames) on ``clock`` (a ManualClock at 0 by default)."""
    from canguard.io.clock import ManualClock

    return Context(
        clock if clock is not None else ManualClock(),
        cfg.sources,
        actions=cfg.actions,
        stop_frames=cfg.stop.frames,
    )


def load_config_tree(cfg: Config, ctx: Context | None = None) -> LoadedTree:
    """Load the tree ``cfg.tree`` names (TreeError when the config has none)."""
    if cfg.tree is None:
        raise TreeError(f"{cfg.path}: tree: missing, expected {{file: TREE.xml, main: ID, tick_hz: HZ}}")
    return load_tree(cfg.tree.file, ctx if ctx is not None else context_for(cfg), cfg.tree.main)


def partial_tree_problems(partial: PartialConfig | None) -> list[str]:
    """The problems of the tree of a config that has problems itself (``ConfigError.partial``).

    The tree is checked without being built: node IDs, ports, values, children, and the
    guards' sources against the sources that loaded (a source the config declares but got
    wrong is not reported again). Empty when the config names no readable tree.
    """
    if partial is None or partial.tree is None:
        return []
    from canguard.io.clock import ManualClock

    loader = _Loader(partial.tree.file, Context(ManualClock(), partial.sources, actions=partial.actions))
    loader.source_check = "always" if partial.sources_ok else "never"
    loader.unsure_sources = partial.declared_sources
    try:
        loader.check(partial.tree.main)
    except TreeError as exc:  # unreadable or not well-formed XML, a broken include
        return [*loader.errors, *exc.problems]
    return loader.errors


def check_tree(cfg: Config) -> TreeReport:
    """Load and validate the config's tree against the config; TreeError on any problem."""
    loaded = load_config_tree(cfg)
    check = validate_against_config(loaded, cfg)
    count = sum(1 for _ in loaded.root.iterate())
    head = (
        f"tree: {loaded.main_id} from {loaded.path} (BTCPP_format {loaded.format_version}), {count} nodes, "
        f"reads {', '.join(sorted(loaded.context.read_sources)) or 'no source'}"
    )
    require_guard_coverage(loaded)
    return TreeReport(loaded, f"{head}\n{render_text(loaded.root)}", check.warnings())


def require_guard_coverage(loaded: LoadedTree) -> None:
    """TreeError when a guard would not be re-checked while the task runs (see :func:`guard_coverage`).

    Such a tree would keep sending the task's frames through an overcurrent or
    a dead sensor: the daemon refuses it rather than run it.
    """
    problems = guard_coverage(loaded)
    if problems:
        raise TreeError("\n".join(problems))


def _path_to(node: py_trees.behaviour.Behaviour) -> list[py_trees.behaviour.Behaviour]:
    """``node`` and its ancestors, root last."""
    path = [node]
    while path[-1].parent is not None:
        path.append(path[-1].parent)
    return path


def guard_coverage(loaded: LoadedTree) -> list[str]:
    """Warnings for guards that are not re-checked while the task runs.

    Under a composite with memory (BT.CPP's Sequence, SequenceWithMemory,
    Fallback), a guard placed before the branch holding ExecuteTask is ticked
    once, then skipped while ExecuteTask stays RUNNING: an overcurrent during the
    task would never stop it. ReactiveSequence re-checks every tick.
    """
    from canguard.bt.nodes.actions import ExecuteTask

    tasks = [n for n in loaded.root.iterate() if isinstance(n, ExecuteTask)]
    out: list[str] = []
    for guard in loaded.guard_nodes():
        g_path = _path_to(guard)
        for task in tasks:
            t_path = _path_to(task)
            common = next(a for a in g_path if a in t_path)
            if not isinstance(common, py_trees.composites.Composite) or not getattr(common, "memory", False):
                continue
            g_child = g_path[g_path.index(common) - 1]
            t_child = t_path[t_path.index(common) - 1]
            if common.children.index(g_child) < common.children.index(t_child):
                info = loaded.info(guard)
                out.append(
                    f"{info.file}:{info.line}: {guard.name} is checked only before {task.name} starts: under "
                    f"{common.name} ({loaded.info(common).node_id}, which keeps its place while a child is RUNNING) "
                    f"it is not ticked again while the task runs, so the task would go on through an overcurrent "
                    f"or a dead sensor; put them under a ReactiveSequence to guard the task at every tick"
                )
    return out


def _with_stop_roles(text: str, root: py_trees.behaviour.Behaviour, stop: Any) -> str:
    """The drawing with, per node, what it does to a stop (LATCH, TASK, RECOVERY...), and the release rule."""
    from canguard.bt.nodes.actions import stop_roles

    roles = stop_roles(root)
    lines = text.splitlines()
    nodes = list(_preorder(root))
    if len(lines) != len(nodes):  # not the one-line-per-node drawing: leave it as it is
        return text
    width = max(len(line) for line in lines) + 2
    out = [f"{line:<{width}}{roles[n]}".rstrip() if n in roles else line for line, n in zip(lines, nodes, strict=True)]
    manual = ", with ResetStop ticked (stop.release: manual)" if stop.release == "manual" else ""
    out.append(
        f"stop: latches when the tree fails, a LATCH node halts the task or a read source goes stale; released at "
        f"the end of a tick without FAILURE that reaches the task, no inhibit left, after stop.min_stop "
        f"{stop.min_stop_s:g} s{manual}"
    )
    return "\n".join(out) + "\n"


def show_tree(config_path: str | Path, dot: str | Path | None = None) -> str:
    """The text drawing of a config's tree; with ``dot``, also render it there (see :func:`render_dot`)."""
    from canguard.config.loader import load_config

    cfg = load_config(config_path)
    loaded = load_config_tree(cfg)
    text = _with_stop_roles(render_text(loaded.root), loaded.root, cfg.stop)
    if dot is not None:
        text += f"wrote {render_dot(loaded.root, dot)}\n"
    return text
