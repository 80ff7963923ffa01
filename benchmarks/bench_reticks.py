"""What a tree that keeps waking itself costs the loop: one capped tickOnce() vs one tickExactlyOnce().

Run from anywhere (``python benchmarks/bench_reticks.py``; the package is found in ``src/``
next to this file when it is not installed).

``Repeat num_cycles="-1"`` over a child that succeeds at once never returns from BT.CPP's
``tickOnce()``; canguard re-ticks the root at most ``MAX_RETICKS`` times per tick. Each tree
below is timed both ways in the same run (best of 5 repeats of 200 ticks): the capped tick
in ms, and its ratio to one pass of the same tree. Goal: ratio <= 2 * (MAX_RETICKS + 1),
i.e. the bound costs what its passes cost and nothing more.
"""

from __future__ import annotations

import sys
import tempfile
import timeit
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "src") not in sys.path:
    sys.path.insert(0, str(ROOT / "src"))

from canguard.bt.context import Context, NullTaskGate  # noqa: E402
from canguard.bt.loader import load_tree  # noqa: E402
from canguard.bt.wakeup import MAX_RETICKS  # noqa: E402
from canguard.io.clock import ManualClock  # noqa: E402

TREES = {
    "Repeat[AlwaysSuccess]": '<Repeat num_cycles="-1"><AlwaysSuccess/></Repeat>',
    "Repeat[Sequence of 5 Script]": '<Repeat num_cycles="-1"><Sequence>'
    + '<Script code="x := 1"/>' * 5 + "</Sequence></Repeat>",
}


def main() -> int:
    """Print one line per tree; exit 1 when a ratio misses the goal."""
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        for name, body in TREES.items():
            path = Path(tmp) / "t.xml"
            path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="M"><BehaviorTree ID="M">{body}'
                            "</BehaviorTree></root>", encoding="utf-8")
            loaded = load_tree(path, Context(ManualClock(), {}, task=NullTaskGate()))
            capped = min(timeit.repeat(loaded.tick_once, number=200, repeat=5)) / 200
            once = min(timeit.repeat(lambda t=loaded: t.tick_once(exactly_once=True), number=200, repeat=5)) / 200
            ratio = capped / once
            goal = 2 * (MAX_RETICKS + 1)
            ok = ok and ratio <= goal
            print(f"{name:30s} capped tick {capped * 1e3:7.3f} ms   one pass {once * 1e6:7.1f} µs   "
                  f"ratio {ratio:6.1f} (goal <= {goal:.0f})")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
