"""``canguard tree FILE.xml --tick N``: a tree ticked on its own, no config, on a manual clock."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

from py_trees.blackboard import Blackboard

from canguard.bt.context import Context
from canguard.bt.loader import Palette, load_tree
from canguard.bt.wakeup import tick_once
from canguard.io.clock import ManualClock


def root_blackboard() -> dict[str, Any]:
    """The root namespace's entries (``/key``), without the loader's port constants: numbers, strings and
    booleans as they are, NaN/inf and anything else as text."""
    out = {}
    for key, value in Blackboard.storage.items():
        name = key[1:]
        if key.startswith("/") and "/" not in name and not name.endswith("__const"):
            plain = value is None or isinstance(value, str | int) or (isinstance(value, float) and math.isfinite(value))
            out[name] = value if plain else str(value)
    return dict(sorted(out.items()))


def dry_run(path: Path, ticks: int, dt: float, main: str | None = None, palette: Palette | None = None, *,
            exactly_once: bool = False) -> dict[str, Any]:
    """Load ``path`` and tick it ``ticks`` times ``dt`` s apart (clock from 0): each tick's root status and the
    root blackboard. Each tick is ``tickOnce()`` (``tickExactlyOnce()`` with ``exactly_once``)."""
    Blackboard.clear()
    clock = ManualClock()
    ctx = Context(clock, {}, on_event=lambda event: print(f"canguard tree: {event.get('reason')}", file=sys.stderr))
    loaded = load_tree(path, ctx, main, palette)
    statuses = []
    ctx.tree_start = 0.0  # the first tick's time
    for i in range(ticks):
        clock.set(i * dt)
        try:
            ticked = tick_once(loaded, exactly_once=exactly_once)
        except Exception as exc:  # as the engine does: a tick that raises is a FAILURE, and says why
            print(f"canguard tree: tick {i + 1}: a node raised {type(exc).__name__}: {exc}", file=sys.stderr)
            statuses.append("FAILURE")
            continue
        finally:
            for node in loaded.root.iterate():  # every script that failed in the tick: where, the script, why
                error = getattr(node, "script_error", None)
                if error:
                    info = loaded.nodes[node.id]  # every node of a loaded tree has one
                    print(f"canguard tree: tick {i + 1}: {info.file}:{info.line}: node {node.name}: script {error}",
                          file=sys.stderr)
                    node.script_error = None  # type: ignore[attr-defined]
        statuses.append("SKIPPED" if ticked.skipped else ticked.status.name)
    return {"ticks": statuses, "blackboard": root_blackboard()}
