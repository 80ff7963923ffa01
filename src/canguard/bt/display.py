"""Showing a tree: text, Graphviz, the Groot2 nodes model, the stop roles of `canguard tree`."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import py_trees
from py_trees.ports import PortsMixin

from canguard.bt import registry
from canguard.bt.context import Context
from canguard.bt.nodes import BUILTIN_NODES, ConfiguredAction
from canguard.bt.nodes.base import node_kind
from canguard.bt.registry import _load_plugin
from canguard.bt.xmlread import _type_name
from canguard.errors import TreeError


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


def _default_text(value: Any) -> str:
    if isinstance(value, bool):  # BT.CPP writes and reads bools as true/false
        return "true" if value else "false"
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
        for name, ep in registry.plugin_entry_points().items():
            if name not in BUILTIN_NODES:
                cls = _load_plugin(ep)
                entries.append((name, cls, getattr(cls, "DESCRIPTION", "") or f"plug-in {ep.value}"))
    for name, cls, description in entries:
        elem = ET.SubElement(model, node_kind(cls), {"ID": name})
        for direction, ports in (("input_port", cls.input_ports()), ("output_port", cls.output_ports())):
            for port_name, info in ports.items():
                attrs = {"name": port_name, "type": _type_name(info.data_type, cpp=True)}
                if info.has_default:
                    attrs["default"] = _default_text(info.default_value)
                port = ET.SubElement(elem, direction, attrs)
                port.text = info.description
        if description:  # BT.CPP 4 writes manifest metadata this way; Groot2 shows it
            fields = ET.SubElement(elem, "MetadataFields")
            ET.SubElement(fields, "Metadata", {"description": description})
    ET.indent(doc, space="  ")
    return ET.tostring(doc, encoding="unicode") + "\n"
