"""Test kit for node and tree tests: sources, a context on a manual clock, trees from XML text.

Sources and actions are built as dataclasses directly, so these tests do not
depend on the YAML loader or the DBC files.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import py_trees
import pytest
from tests.feed import dispatch

from canguard.bt import loader as tree_module
from canguard.bt.context import Context
from canguard.bt.loaded import LoadedTree
from canguard.bt.loader import load_tree
from canguard.bt.nodes import CanguardNode, port_info
from canguard.bt.nodes.base import halted
from canguard.bt.wakeup import tick_once
from canguard.config.schema import ActionConfig, FrameSpec, SignalRef, SourceConfig, SourceKind
from canguard.io.clock import ManualClock
from canguard.io.frame import Sample
from checkout import REPO

TREES = REPO / "config" / "trees"

Status = py_trees.common.Status
S, F, R = Status.SUCCESS, Status.FAILURE, Status.RUNNING

_ids = itertools.count(0x100)


def tick(loaded: LoadedTree) -> Status:
    """Tick the root exactly once, BT.CPP's ``tickExactlyOnce()`` (``ctx.tree_start`` set at the first tick, as the
    engine does)."""
    if loaded.context.tree_start is None:
        loaded.context.tree_start = loaded.context.clock.now()
    return tick_once(loaded, exactly_once=True).status


def find(loaded: LoadedTree, name: str) -> Any:
    """The node of ``loaded`` with that readable name (KeyError: none)."""
    return {node.name: node for node in loaded.root.iterate()}[name]


def sig(role: str, minimum: float | None = None, maximum: float | None = None) -> SignalRef:
    """A signal reference with made-up DBC coordinates."""
    return SignalRef(
        role=role,
        bus="main",
        message=f"M{role}",
        frame_id=next(_ids),
        is_extended_id=False,
        signal=role,
        minimum=minimum,
        maximum=maximum,
    )


def source(name: str, kind: SourceKind, roles: Iterable[str], max_age_s: float = 0.5) -> SourceConfig:
    """A configured source with one signal per role."""
    return SourceConfig(name=name, kind=kind, bus="main", signals=tuple(sig(r) for r in roles), max_age_s=max_age_s)


def standard_sources(joints: int = 4) -> dict[str, SourceConfig]:
    """/battery_state (current, present), /joint_states (axis0..), axis0 (current), as in canguard.yaml."""
    return {
        "/battery_state": source("/battery_state", "battery", ("current", "present")),
        "/joint_states": source("/joint_states", "joints", [f"axis{i}" for i in range(joints)]),
        "axis0": source("axis0", "current", ("current",)),
    }


def frame(label: str) -> FrameSpec:
    """A frame spec named ``label``."""
    return FrameSpec(bus="main", arbitration_id=next(_ids) & 0x7FF, data=b"\x01", label=label)


ACTION_NAMES = (
    "PerformDiagnostics",
    "PerformRecovery",
    "PerformTimedAction",
    "NavigateToPose",
    "ComputePath",
    "FollowPath",
    "ProcessSensorData",
    "ContinueOperation",
)


class ListSink:
    """A frame sink that keeps every frame it was given, with its origin."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, FrameSpec]] = []

    def send(self, frames: Iterable[FrameSpec], origin: str) -> None:
        self.sent.extend((origin, f) for f in frames)


class TaskRecorder:
    """A task gate that records each run and halt ExecuteTask asks for."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, str, float]] = []

    def run(self, node: str, now: float) -> None:
        self.calls.append(("run", node, now))

    def halt(self, node: str, now: float) -> None:
        self.calls.append(("halt", node, now))


class Rig:
    """A context on a manual clock with a list sink, a recording task gate and an event list."""

    def __init__(
        self,
        start: float = 1000.0,
        sources: dict[str, SourceConfig] | None = None,
        actions: Iterable[str] = ACTION_NAMES,
        stop_frames: tuple[FrameSpec, ...] = (),
    ) -> None:
        self.clock = ManualClock(start)
        self.sink = ListSink()
        self.task = TaskRecorder()
        self.events: list[dict[str, Any]] = []
        self.ctx = Context(
            self.clock,
            sources if sources is not None else standard_sources(),
            sink=self.sink,
            actions={a: ActionConfig(a, (frame(a),)) for a in actions},
            task=self.task,
            on_event=self.events.append,
            stop_frames=stop_frames,
        )
        self.loaded: LoadedTree | None = None

    # -- trees -------------------------------------------------------------------------
    def failure_reason(self) -> str:
        """Why the tree's last failing guard fails: the last trip's reason, or, before any trip, the
        reason a never-judged guard gives (no data yet is a failure, not a trip)."""
        assert self.loaded is not None
        for node in self.loaded.guard_nodes():
            if node.ok is None and node.reason:
                return str(node.reason)
        return str(self.trips()[-1]["reason"])

    def load(self, path: Path, main: str | None = None) -> LoadedTree:
        """Load a tree file for this context."""
        self.loaded = load_tree(path, self.ctx, main)
        return self.loaded

    def load_text(self, tmp_path: Path, xml: str, main: str | None = None, name: str = "tree.xml") -> LoadedTree:
        """Write ``xml`` to ``tmp_path/name`` and load it."""
        path = tmp_path / name
        path.write_text(xml, encoding="utf-8")
        return self.load(path, main)

    def tick(self) -> Status:
        """Tick the loaded tree once."""
        assert self.loaded is not None
        return tick(self.loaded)

    def node(self, name: str) -> Any:
        """A node of the loaded tree by readable name."""
        assert self.loaded is not None
        return find(self.loaded, name)

    # -- time and samples ----------------------------------------------------------------
    def now(self) -> float:
        """The clock's time."""
        return self.clock.now()

    def advance(self, dt: float) -> None:
        """Move the clock forward."""
        self.clock.advance_to(self.clock.now() + dt)

    def feed(self, src: str, role: str, value: float, t: float | None = None, reason: str = "") -> bool:
        """Dispatch one sample (at now unless ``t``)."""
        return dispatch(self.ctx, Sample(src, role, value, self.now() if t is None else t, reason))

    def battery(self, current: float, present: float = 1.0, name: str = "/battery_state") -> None:
        """One battery frame: current and present."""
        self.feed(name, "present", present)
        self.feed(name, "current", current)

    def joints(self, *efforts: float, name: str = "/joint_states") -> None:
        """One sample per joint, axis0 first."""
        for i, e in enumerate(efforts):
            self.feed(name, f"axis{i}", e)

    def labels(self) -> list[str]:
        """Labels of every frame sent so far."""
        return [f.label for _, f in self.sink.sent]

    def trips(self) -> list[dict[str, Any]]:
        """trip / recover events so far."""
        return [e for e in self.events if e["event"] in ("trip", "recover")]


def xml_tree(body: str, tree_id: str = "T", v4: bool = True) -> str:
    """A one-tree document around ``body``."""
    fmt = ' BTCPP_format="4"' if v4 else ""
    head = f'<root{fmt} main_tree_to_execute="{tree_id}">\n<BehaviorTree ID="{tree_id}">\n'
    return f"{head}{body}\n</BehaviorTree>\n</root>\n"


class Scripted(CanguardNode, py_trees.behaviour.Behaviour):
    """Test leaf: returns the statuses of ``script`` ("S,R,F"; the last repeats); logs ticks and halts."""

    KIND = "Action"
    NEEDS_CONTEXT = False
    INPUT_PORTS = {"script": port_info(str, "statuses to return, e.g. R,R,S")}  # noqa: RUF012
    OUTPUT_PORTS = {}  # noqa: RUF012
    journal: list[tuple[str, str]] = []  # noqa: RUF012
    CODES = {"S": S, "F": F, "R": R}  # noqa: RUF012

    def bind(self) -> None:
        self.queue = [self.CODES[c.strip()] for c in str(self.port("script")).split(",")]
        self.ticks = 0

    def update(self) -> Status:
        status = self.queue[min(self.ticks, len(self.queue) - 1)]
        self.ticks += 1
        self.journal.append((self.name, status.name[0]))
        return status

    def terminate(self, new_status: Status) -> None:
        if halted(self, new_status):
            self.journal.append((self.name, "halt"))


class FakeEntryPoint:
    """Enough of importlib.metadata.EntryPoint for the registry."""

    def __init__(self, name: str, target: Any, calls: list[str] | None = None) -> None:
        self.name = name
        self.value = f"tests:{name}"
        self.target = target
        self.calls = calls if calls is not None else []

    def load(self) -> Any:
        self.calls.append(self.name)
        if isinstance(self.target, Exception):
            raise self.target
        return self.target


def install_scripted(monkeypatch: pytest.MonkeyPatch) -> list[tuple[str, str]]:
    """Make ``<Scripted script=".."/>`` available (as a plug-in) and return its fresh log."""
    monkeypatch.setattr(tree_module, "plugin_entry_points", lambda: {"Scripted": FakeEntryPoint("Scripted", Scripted)})
    Scripted.journal = []
    return Scripted.journal
