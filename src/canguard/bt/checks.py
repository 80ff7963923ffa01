"""A loaded tree against its config (sources, guard coverage, `canguard check`) and shown (text, Graphviz,
the Groot2 nodes model, the stop roles of `canguard tree`)."""

from __future__ import annotations

import itertools
import shutil
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import py_trees
from py_trees.ports import PortsMixin

from canguard.bt import loader
from canguard.bt.context import Context
from canguard.bt.loaded import LoadedTree, _preorder
from canguard.bt.loader import load_tree, type_name
from canguard.bt.nodes import BUILTIN_NODES, ConfiguredAction, GuardNode
from canguard.bt.nodes.actions import EmitStop, ExecuteTask, ResetStop, assign_roles
from canguard.bt.nodes.base import RUNNING, node_kind
from canguard.config.schema import Config
from canguard.errors import TreeError, quote
from canguard.io.clock import ManualClock
from canguard.protect.hysteresis import Hysteresis
from canguard.protect.i2t import _I2tModel

if TYPE_CHECKING:
    from canguard.bt.loader import Palette


@dataclass(frozen=True)
class TreeReport:
    """``canguard check``'s view of the config's tree."""

    text: str  # a summary line and the tree drawing
    warnings: list[str]  # configured sources the tree does not read


def context_for(cfg: Config) -> Context:
    """A context for ``cfg`` (sources, actions, stop frames) on a ManualClock at 0."""
    return Context(ManualClock(), cfg.sources, actions=cfg.actions, stop_frames=cfg.stop.frames)


def load_config_tree(cfg: Config, palette: Palette | None = None) -> LoadedTree:
    """Load the tree ``cfg.tree`` names (TreeError when the config has none); ``palette``: ``--nodes`` files."""
    if cfg.tree is None:
        raise TreeError(f"{cfg.path}: tree: missing, expected {{file: TREE.xml, main: ID, tick_hz: HZ}}")
    return load_tree(cfg.tree.file, context_for(cfg), cfg.tree.main, palette)


def check_tree(cfg: Config, palette: Palette | None = None) -> TreeReport:
    """Load and validate the config's tree against the config (and ``--nodes`` palettes); TreeError on any problem."""
    loaded = load_config_tree(cfg, palette)  # binding checks every guard's topic_name against cfg.sources
    head = (f"tree: {loaded.main_id} from {loaded.path} (BTCPP_format {loaded.format_version}), "
            f"{len(loaded.nodes)} nodes, reads {', '.join(sorted(loaded.context.read_sources)) or 'no source'}")
    require_guard_coverage(loaded)
    unread = [n for n in cfg.sources if n not in loaded.context.read_sources]
    return TreeReport(f"{head}\n{render_text(loaded.root)}", [
        f"source {quote(n)} is configured but the tree does not read it (only stale events)" for n in unread])


def _path_to(node: py_trees.behaviour.Behaviour) -> list[py_trees.behaviour.Behaviour]:
    """``node`` and its ancestors, root last."""
    path = [node]
    while path[-1].parent is not None:
        path.append(path[-1].parent)
    return path


def require_guard_coverage(loaded: LoadedTree) -> None:
    """TreeError naming the guards placed before ExecuteTask's branch under a composite with memory: ticked once,
    then skipped while the task runs, so an overcurrent during the task would never stop it."""
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
                info = loaded.nodes[guard.id]
                out.append(f"{info.file}:{info.line}: {guard.name} is checked only before {task.name} starts: under "
                           f"{common.name} ({loaded.nodes[common.id].node_id}, which keeps its place while a child is "
                           "RUNNING) it is not ticked again while the task runs, so the task would go on through an "
                           "overcurrent or a dead sensor; put them under a ReactiveSequence to guard the task at "
                           "every tick")
    if out:
        raise TreeError("\n".join(out))


def halt_ahead(loaded: LoadedTree) -> Callable[[], bool] | None:
    """What says, at a protection model's edge, that the coming tick halts the running task: ExecuteTask runs and a
    model of a guard whose failure surely halts it has tripped (the model's peak latch fails the guard at that
    tick). None when no guard is such (the config actions' roles assigned first).

    A guard's failure surely halts the task when the guard and every node above it are ReactiveSequences'
    children without pre-/post-conditions (each tick starts at the first child; a failing child fails the
    sequence and halts its running children; a RUNNING child before it halts all the others), ExecuteTask is
    the tree's one task node and lies in no child before the guard's branch, and no port of the guard is
    wired (a ``{key}`` threshold may change in the tick).
    """
    from canguard.bt.nodes.control import ReactiveSequence

    nodes = list(loaded.root.iterate())
    tasks = [n for n in nodes if isinstance(n, ExecuteTask) or (isinstance(n, ConfiguredAction) and n.role == "task")]
    if len(tasks) != 1 or not isinstance(tasks[0], ExecuteTask):
        return None
    task = tasks[0]

    def halts(guard: Any) -> bool:
        path = _path_to(guard)
        if guard.wired_keys() or any("tick" in vars(n) for n in path):  # conditions wrap a node's own tick
            return False
        return all(type(parent) is ReactiveSequence and not any(task in c.iterate() for c in
                                                                parent.children[:parent.children.index(child)])
                   for child, parent in itertools.pairwise(path))

    models = [m for g in loaded.guard_nodes() if halts(g) for _, m, _ in g.guarded()]
    if not models:
        return None
    return lambda: task.status == RUNNING and any(m.tripped for m in models)


_STOP_ROLES = ((ExecuteTask, "TASK task frames; asks to release the stop"), (EmitStop, "STOP sends the stop frames"),
               (ResetStop, "RESET releases a manual stop"))


def _stop_role(node: py_trees.behaviour.Behaviour) -> str:
    """What ``node`` does to a stop, in words ("" when nothing)."""
    if isinstance(node, GuardNode):
        holds = []  # how long its failure holds: its models' recovery rules
        for _, model, _ in node.guarded():
            if isinstance(model, Hysteresis):
                holds.append(f"holds until |I| <= {model.recovery_a:g} A (hysteresis)")
            elif isinstance(model, _I2tModel):
                holds.append(f"holds until the I²t level < {model.recover_fraction * 100:g} % (i2t)")
            else:
                holds.append("holds for the tick it fails in (threshold)")
        return "LATCH trips a stop; " + ("; ".join(dict.fromkeys(holds)) or "fails while its source is stale")
    if isinstance(node, ConfiguredAction):
        return ("TASK frames withheld while stopped; asks to release the stop" if node.role == "task"
                else "RECOVERY frames sent during a stop too")
    return next((role for cls, role in _STOP_ROLES if isinstance(node, cls)), "")


def _with_stop_roles(text: str, root: py_trees.behaviour.Behaviour, stop: Any) -> str:
    """The drawing with, per node, what it does to a stop (LATCH, TASK, RECOVERY...), and the release rule."""
    assign_roles(root)
    lines = text.splitlines()
    nodes = list(_preorder(root))
    if len(lines) != len(nodes):  # not the one-line-per-node drawing: leave it as it is
        return text
    width = max(len(line) for line in lines) + 2
    roles = map(_stop_role, nodes)
    out = [f"{line:<{width}}{role}".rstrip() if role else line for line, role in zip(lines, roles, strict=True)]
    manual = ", with ResetStop ticked (stop.release: manual)" if stop.release == "manual" else ""
    out.append("stop: latches when the tree fails, a LATCH node halts the task or a read source goes stale; released "
               "at the end of a tick without FAILURE that reaches the task, no inhibit left, after stop.min_stop "
               f"{stop.min_stop_s:g} s{manual}")
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
        raise TreeError(f"{out}: drawing .{fmt} needs Graphviz's `dot` program, which is not installed "
                        "(e.g. apt install graphviz); a .dot file works without it")
    try:
        graph.write(str(out), format=fmt)
    except (OSError, AssertionError) as exc:  # pydot reports dot's own failures as AssertionError
        raise TreeError(f"{out}: Graphviz failed: {exc}") from exc
    return out


def nodes_model_xml(ctx: Context | None = None) -> str:
    """A Groot2 ``<TreeNodesModel>`` of every canguard node type and its ports (with ``ctx``, the config's actions)."""
    doc = ET.Element("root", {"BTCPP_format": "4"})
    model = ET.SubElement(doc, "TreeNodesModel")
    actions = ctx.actions if ctx is not None else {}
    entries: list[tuple[str, type[PortsMixin], str]] = [
        *((n, c, getattr(c, "DESCRIPTION", "")) for n, c in BUILTIN_NODES.items()),
        *((n, ConfiguredAction, f"config action: {len(a.frames)} frame(s)") for n, a in actions.items()),
    ]
    for name, ep in loader.plugin_entry_points().items():
        if name not in BUILTIN_NODES:
            cls = loader.load_plugin(ep)
            entries.append((name, cls, getattr(cls, "DESCRIPTION", "") or f"plug-in {ep.value}"))
    for name, cls, description in entries:
        elem = ET.SubElement(model, node_kind(cls), {"ID": name})
        for direction, ports in (("input_port", cls.input_ports()), ("output_port", cls.output_ports())):
            for port_name, info in ports.items():
                attrs = {"name": port_name, "type": type_name(info.data_type, cpp=True)}
                if info.has_default:  # BT.CPP writes and reads bools as true/false
                    value = info.default_value
                    attrs["default"] = str(value).lower() if isinstance(value, bool) else str(value)
                port = ET.SubElement(elem, direction, attrs)
                port.text = info.description
        if description:  # BT.CPP 4 writes manifest metadata this way; Groot2 shows it
            fields = ET.SubElement(elem, "MetadataFields")
            ET.SubElement(fields, "Metadata", {"description": description})
    ET.indent(doc, space="  ")
    return ET.tostring(doc, encoding="unicode") + "\n"
