"""docs/trees.md's node reference is the output of scripts/node_reference.py, so it cannot drift from the code."""

from __future__ import annotations

import importlib.util
from types import ModuleType

from checkout import REPO


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("node_reference", REPO / "scripts" / "node_reference.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class TestNodeReference:
    def test_readme_table_is_the_generated_one(self) -> None:
        """The text between the node-reference markers of docs/trees.md equals `python scripts/node_reference.py`."""
        ref = _script()
        readme = (REPO / "docs" / "trees.md").read_text(encoding="utf-8")
        assert ref.BEGIN in readme and ref.END in readme, "docs/trees.md lacks the node-reference markers"
        start = readme.index(ref.BEGIN)
        end = readme.index(ref.END) + len(ref.END) + 1
        assert readme[start:end] == ref.render(), (
            "docs/trees.md's node reference is out of date: replace it with `python scripts/node_reference.py`"
        )

    def test_every_builtin_node_is_listed(self) -> None:
        """Every node ID of the closed registry has a row in the generated reference."""
        from canguard.bt.nodes import BUILTIN_NODES

        text = _script().render()
        for node_id in BUILTIN_NODES:
            assert f"| `{node_id}` |" in text, node_id
