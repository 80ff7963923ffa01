"""BehaviorTree.CPP XML trees on py_trees: the one place callers import the loader and its tools from.

:mod:`.xmlread` reads (lines, includes, v3 spellings), :mod:`.validate` checks every node against
the registry, :mod:`.build` lets py_trees' parser build the tree under placeholder names and binds
it; :mod:`.loaded` holds the result, :mod:`.checks` checks it against its config.
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
