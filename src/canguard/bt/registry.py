"""The node registry: canguard's node library, plug-ins (``canguard.nodes`` entry points) and v3 aliases."""

from __future__ import annotations

import functools
import inspect
from collections.abc import Collection
from importlib.metadata import EntryPoint, distributions, entry_points

import py_trees
from py_trees.ports import PortsMixin

from canguard.bt.context import Context
from canguard.bt.nodes import BUILTIN_NODES, CanguardNode, ConfiguredAction
from canguard.errors import TreeError

Registry = dict[str, functools.partial]

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
_TOKEN = "@"  # placeholder node names handed to py_trees are @<n>


def plugin_entry_points() -> dict[str, EntryPoint]:
    """The ``canguard.nodes`` entry points by node ID (not loaded); none parsed unless a distribution names
    the group (a cheaper scan)."""
    if not any(ENTRY_POINT_GROUP in (dist.read_text("entry_points.txt") or "") for dist in distributions()):
        return {}
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

    Built-ins, one ConfiguredAction per ``ctx.actions`` entry, and the plug-ins, only those in ``only``
    (all when None). An action named like a built-in is a TreeError; a plug-in named like either is ignored.
    """
    registry: Registry = {
        node_id: functools.partial(BUILTIN_NODES[node_id], context=ctx)
        for node_id in BUILTIN_NODES
        if only is None or node_id in only
    }
    for name, action in ctx.actions.items():
        if name in BUILTIN_NODES or name == _SUBTREE:
            raise TreeError(f"actions: {name!r} is the ID of a built-in node type; give the action another name")
        registry[name] = functools.partial(ConfiguredAction, context=ctx, action=action)
    for name, ep in plugin_entry_points().items():
        if name in BUILTIN_NODES or name in registry or (only is not None and name not in only):
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


def children_problem(kind: str, n: int) -> str | None:
    """What is wrong with ``n`` children under a node of ``kind`` (Action, Condition, Decorator...); None: nothing."""
    if kind == "Decorator":
        return None if n == 1 else f"a decorator takes exactly one child, found {n}"
    if kind == "Control":
        return None if n else "a control node needs at least one child"
    return f"{kind.lower()} nodes take no children, found {n}" if n else None
