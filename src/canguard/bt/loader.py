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
The four steps live in their own modules: :mod:`.xmlread` (1, 2), :mod:`.validate` (3),
:mod:`.build` (4); :mod:`.registry` holds the node registry, :mod:`.loaded` the loaded
tree, :mod:`.checks` the tree against its config, :mod:`.display` the renderings.
This module is the one place callers import from.
"""

from __future__ import annotations

from canguard.bt.build import load_tree
from canguard.bt.checks import (
    TreeReport,
    check_tree,
    context_for,
    guard_coverage,
    load_config_tree,
    partial_tree_problems,
    require_guard_coverage,
    show_tree,
)
from canguard.bt.display import nodes_model_xml, render_dot, render_text
from canguard.bt.loaded import GuardView, LoadedTree, NodeInfo
from canguard.bt.registry import ENTRY_POINT_GROUP, Registry, build_registry, known_node_ids, node_kind

__all__ = [
    "ENTRY_POINT_GROUP",
    "GuardView",
    "LoadedTree",
    "NodeInfo",
    "Registry",
    "TreeReport",
    "build_registry",
    "check_tree",
    "context_for",
    "guard_coverage",
    "known_node_ids",
    "load_config_tree",
    "load_tree",
    "node_kind",
    "nodes_model_xml",
    "partial_tree_problems",
    "render_dot",
    "render_text",
    "require_guard_coverage",
    "show_tree",
]
