"""Tick cost of a loaded tree vs the same tree from bare py_trees behaviours; Profile's overhead.

Run from anywhere (``python benchmarks/bench_tree.py``; the package is found in
``src/`` next to this file when it is not installed).

1. **Loader vs bare.** MultiCurrentMonitoring (config/trees/multi_current_monitoring.xml)
   built by :func:`canguard.bt.loader.load_tree` — ports, context, events, readable
   names — against the same logic assembled by hand from bare py_trees
   behaviours (no ports, no edge journal): a non-memory Sequence of a battery
   check, a four-joint effort check and an action that sends its (empty) frame
   list. Both read the same SourceHealth and poll the same kind of Threshold
   models, fed with the same samples, and are timed in the same run with
   ``timeit``, interleaved, best of several repeats. Goal: ratio <= 1.2.
2. **Profile overhead.** One tick of ``Profile(last_ms, avg_ms, max_ms, count
   wired)[leaf]`` minus one tick of the bare leaf, and the same with no output
   wired. Goal: <= 3 µs per tick.

Figures on the development machine (2 shared vCPUs, Python 3.11.7, py_trees 2.6.0),
three runs of ``python benchmarks/bench_tree.py``::

    MultiCurrentMonitoring, one tick      loader 22.5-23.0 µs   bare 22.4-23.0 µs   ratio 0.99-1.03  (goal <= 1.2)
    Profile, 4 outputs wired              +1.47-1.56 µs per tick                                 (goal <= 3 µs)
    Profile, no output wired              +1.18-1.23 µs per tick

The ports cost nothing per tick because constant ports are read once at load
time and wired outputs are written straight to ``Blackboard.storage`` with the
key resolved at set-up (py_trees' ``Client.set`` costs ~1.6 µs per write,
``PortsMixin._set_output`` ~2.2 µs: four of them made Profile cost ~9 µs).
"""

from __future__ import annotations

import gc
import sys
import timeit
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "src") not in sys.path:
    sys.path.insert(0, str(ROOT / "src"))

import py_trees  # noqa: E402

from canguard.bt.context import Context, ListSink  # noqa: E402
from canguard.bt.loader import load_tree  # noqa: E402
from canguard.config.loader import ActionConfig, SignalRef, SourceConfig  # noqa: E402
from canguard.io.clock import ManualClock  # noqa: E402
from canguard.io.frame import Sample  # noqa: E402
from canguard.protect.staleness import SourceHealth  # noqa: E402
from canguard.protect.threshold import Threshold  # noqa: E402

Status = py_trees.common.Status
JOINTS = ("axis0", "axis1", "axis2", "axis3")


def _sig(role: str, frame_id: int) -> SignalRef:
    return SignalRef(role, "main", f"M{frame_id}", frame_id, False, role)


def sources() -> dict[str, SourceConfig]:
    """The bundled config's battery and joints sources, as dataclasses."""
    return {
        "/battery_state": SourceConfig("/battery_state", "battery", "main", (_sig("current", 1), _sig("present", 2))),
        "/joint_states": SourceConfig(
            "/joint_states", "joints", "main", tuple(_sig(j, 10 + i) for i, j in enumerate(JOINTS))
        ),
    }


def feed(ctx: Context, t: float) -> None:
    """One healthy sample of every signal at ``t``."""
    ctx.dispatch(Sample("/battery_state", "present", 1.0, t))
    ctx.dispatch(Sample("/battery_state", "current", 20.0, t))
    for j in JOINTS:
        ctx.dispatch(Sample("/joint_states", j, 10.0, t))


# -- the bare tree: the same logic without ports ------------------------------------------
class BareCurrentNormal(py_trees.behaviour.Behaviour):
    """IsCurrentNormal's logic: health, then the latched Threshold."""

    def __init__(self, name: str, ctx: Context, src: str, limit: float) -> None:
        super().__init__(name)
        self.clock = ctx.clock
        self.health = ctx.health[src]
        self.model = Threshold(limit)
        ctx.subscribe(src, "current", self.model)

    def update(self) -> Status:
        now = self.clock.now()
        snap = self.model.poll(now)
        reason = self.health.reason(now, "current") or (snap.reason if snap.tripped else "")
        return Status.FAILURE if reason else Status.SUCCESS


class BareEffortNormal(py_trees.behaviour.Behaviour):
    """IsJointEffortNormal's logic: every joint's health and latched Threshold."""

    def __init__(self, name: str, ctx: Context, src: str, limit: float) -> None:
        super().__init__(name)
        self.clock = ctx.clock
        self.health: SourceHealth = ctx.health[src]
        self.models = []
        for role in ctx.sources[src].value_roles:
            m = Threshold(limit)
            ctx.subscribe(src, role, m)
            self.models.append((role, m))

    def update(self) -> Status:
        now = self.clock.now()
        failed = False
        for role, model in self.models:
            snap = model.poll(now)
            if not failed and (self.health.reason(now, role) or snap.tripped):
                failed = True
        return Status.FAILURE if failed or not self.models else Status.SUCCESS


class BareAction(py_trees.behaviour.Behaviour):
    """A configured action's logic: hand the frames to the sink when there are any."""

    def __init__(self, name: str, ctx: Context, action: ActionConfig) -> None:
        super().__init__(name)
        self.sink = ctx.sink
        self.frames = action.frames

    def update(self) -> Status:
        if self.frames:
            self.sink.send(self.frames, origin=self.name)
        return Status.SUCCESS


def bare_tree(ctx: Context) -> py_trees.behaviour.Behaviour:
    """MultiCurrentMonitoring by hand."""
    return py_trees.composites.Sequence(
        "ReactiveSequence",
        memory=False,
        children=[
            BareCurrentNormal("IsCurrentNormal", ctx, "/battery_state", 40.0),
            BareEffortNormal("IsJointEffortNormal", ctx, "/joint_states", 150.0),
            BareAction("ContinueOperation", ctx, ctx.actions["ContinueOperation"]),
        ],
    )


def make_ctx() -> Context:
    return Context(
        ManualClock(1000.0),
        sources(),
        sink=ListSink(),
        actions={"ContinueOperation": ActionConfig("ContinueOperation")},
    )


# -- measuring ------------------------------------------------------------------------------
def per_call_us(fns: dict[str, Callable[[], None]], number: int, repeat: int) -> dict[str, float]:
    """Best-of-``repeat`` µs per call of each function, measured interleaved."""
    best = {k: float("inf") for k in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            gc.collect()
            t = timeit.timeit(fn, number=number) / number * 1e6
            best[name] = min(best[name], t)
    return best


def bench_loader_vs_bare(number: int, repeat: int) -> tuple[float, float]:
    py_trees.blackboard.Blackboard.clear()
    ctx_l = make_ctx()
    loaded = load_tree(ROOT / "config" / "trees" / "multi_current_monitoring.xml", ctx_l)
    ctx_b = make_ctx()
    bare = bare_tree(ctx_b)
    for ctx in (ctx_l, ctx_b):
        ctx.tree_start = 1000.0
        feed(ctx, 1000.0)
    assert loaded.tick() == Status.SUCCESS
    bare.tick_once()
    assert bare.status == Status.SUCCESS
    times = per_call_us({"loader": loaded.root.tick_once, "bare": bare.tick_once}, number, repeat)
    assert loaded.root.status == bare.status == Status.SUCCESS
    return times["loader"], times["bare"]


class Leaf(py_trees.behaviour.Behaviour):
    """The cheapest leaf there is."""

    def update(self) -> Status:
        return Status.SUCCESS


def bench_profile(number: int, repeat: int) -> tuple[float, float, float]:
    from canguard.bt.nodes.profile import Profile

    py_trees.blackboard.Blackboard.clear()
    bare = Leaf("leaf")
    wired = Profile("wired", child=Leaf("leaf_w"))
    wired.setup_ports(
        port_remappings={"last_ms": "/l", "avg_ms": "/a", "max_ms": "/m", "count": "/c"}, subtree_namespace="/"
    )
    unwired = Profile("unwired", child=Leaf("leaf_u"))
    unwired.setup_ports(port_remappings={}, subtree_namespace="/")
    times = per_call_us(
        {"bare": bare.tick_once, "wired": wired.tick_once, "unwired": unwired.tick_once}, number, repeat
    )
    assert wired.count > 0 and py_trees.blackboard.Blackboard.get("/c") == wired.count
    return times["bare"], times["wired"], times["unwired"]


def main() -> int:
    number, repeat = 20_000, 7
    loader, bare = bench_loader_vs_bare(number, repeat)
    ratio = loader / bare
    print("MultiCurrentMonitoring, one tick (battery + 4 joints, all healthy):")
    print(f"  loader-built (ports, context, journal) {loader:8.2f} µs")
    print(f"  bare py_trees behaviours               {bare:8.2f} µs")
    print(f"  ratio                                  {ratio:8.3f}   (goal <= 1.2) {'OK' if ratio <= 1.2 else 'MISSED'}")
    leaf, wired, unwired = bench_profile(number * 5, repeat)
    print("Profile decorator, one tick around a trivial leaf:")
    print(f"  bare leaf                              {leaf:8.2f} µs")
    print(f"  Profile, 4 outputs wired               {wired:8.2f} µs  overhead {wired - leaf:6.2f} µs")
    print(f"  Profile, no output wired               {unwired:8.2f} µs  overhead {unwired - leaf:6.2f} µs")
    ok = wired - leaf <= 3.0
    print(f"  goal <= 3 µs per tick (4 outputs wired): {'OK' if ok else 'MISSED'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
