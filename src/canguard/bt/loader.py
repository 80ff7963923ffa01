"""BehaviorTree.CPP XML trees on py_trees: registry, loader, validation and display tools.

:func:`load_tree` reads the file with every element's file and line and inlines its includes,
rewrites BT.CPP v3 spellings to v4 (:mod:`.xmlread`; docs/trees.md, "XML dialects"), validates
every node against the registry (:mod:`.validate`, :mod:`.registry`), then lets py_trees' parser
build the tree and binds every node (:mod:`.build`). Nodes reach py_trees' parser under placeholder
names (it prefixes children's names with their parent's and names unnamed nodes by uuid) and get
their readable names back after it. Every problem is a :class:`~canguard.errors.TreeError` naming
file, line, node and port. :mod:`.loaded` holds the loaded tree, :mod:`.checks` the tree against its
config, :mod:`.display` the renderings. This module is the one place callers import from.
"""

from __future__ import annotations

from canguard.bt.build import load_tree
from canguard.bt.checks import (
    check_tree,
    context_for,
    guard_coverage,
    halt_ahead,
    load_config_tree,
    partial_tree_problems,
    require_guard_coverage,
    show_tree,
)
from canguard.bt.display import nodes_model_xml, render_dot, render_text
from canguard.bt.loaded import GuardView, LoadedTree
from canguard.bt.nodes.base import node_kind
from canguard.bt.registry import build_registry

__all__ = ["GuardView", "LoadedTree", "build_registry", "check_tree", "context_for", "guard_coverage", "halt_ahead",
           "load_config_tree", "load_tree", "node_kind", "nodes_model_xml", "partial_tree_problems", "render_dot",
           "render_text", "require_guard_coverage", "show_tree"]
