"""The package stays a house a newcomer can walk through.

- the layers along the data path hold, and inside io/ and sim/ (import-linter's contracts in pyproject.toml);
- no import cycle between modules, ``if TYPE_CHECKING:`` imports included (a ring of annotations is a ring
  of concepts too);
- functions stay under a complexity budget: ruff's C901 (``max-complexity`` in pyproject.toml, checked by
  the lint step), not files under a line cap;
- every node type the node library registers is a reserved ID for ``actions:`` in the config layer;
- docs/layout.md lists every module as the tree has it (``python scripts/layout.py`` regenerates the table).
"""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from checkout import REPO

SRC = REPO / "src" / "canguard"


def test_layers_contract_is_kept() -> None:
    """lint-imports (import-linter) reports every contract kept."""
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip("import-linter is not installed (pip install -e '.[test]')")
    proc = subprocess.run([exe, "--no-cache"], capture_output=True, text=True, timeout=120,
                          cwd=SRC.parents[1])
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout


def strongly_connected(adj: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm, iterative: the groups of modules that import each other in a ring."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []
    counter = 0
    for root in sorted(adj):
        if root in index:
            continue
        work = [(root, iter(sorted(adj[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(adj.get(w, ())))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    group = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        group.append(w)
                        if w == v:
                            break
                    if len(group) > 1:
                        groups.append(sorted(group))
    return groups


def test_strongly_connected_finds_a_ring() -> None:
    """The cycle finder itself: a -> b -> c -> a is one group, d alone is none."""
    assert strongly_connected({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycle() -> None:
    """No two modules of canguard import each other, directly or around a ring, annotations included."""
    import grimp  # here, not at module level: every pytest-xdist worker imports this module at collection

    graph = grimp.build_graph("canguard", exclude_type_checking_imports=False)
    adj = {m: set(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    assert strongly_connected(adj) == []


def test_config_reserves_every_node_id() -> None:
    """An action may not be named like a registered node type: the config layer's table knows them all."""
    from canguard.bt.nodes import BUILTIN_NODES
    from canguard.config.node_ids import RESERVED_NODE_IDS

    assert set(BUILTIN_NODES) - RESERVED_NODE_IDS == set()


def test_layout_doc_lists_every_module() -> None:
    """docs/layout.md's module table is the one scripts/layout.py makes from the tree: every module, none gone."""
    spec = importlib.util.spec_from_file_location("layout_doc", REPO / "scripts" / "layout.py")
    assert spec is not None and spec.loader is not None
    layout = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(layout)
    text = layout.DOC.read_text(encoding="utf-8")
    assert layout.rewritten(text) == text, (
        "docs/layout.md does not list the modules of src/canguard as they are (a module added, removed or its "
        "docstring's first line changed): run `python scripts/layout.py` and commit docs/layout.md")
