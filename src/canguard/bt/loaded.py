"""A loaded tree and what the engine and the tools read from it (node info, guard views)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, cast

import py_trees

from canguard.bt.context import Context
from canguard.bt.nodes import GuardNode
from canguard.bt.wakeup import WakeUpSignal
from canguard.protect.base import ProtectionModel, Snapshot
from canguard.units import I2T_LIMIT_PCT


@dataclass(frozen=True)
class NodeInfo:
    """Where a node of a loaded tree comes from."""

    node_id: str  # its node type
    name: str  # its readable, unique name (events, canguard tree)
    file: Path
    line: int
    tree: str  # the <BehaviorTree ID> it is written in

    @property
    def where(self) -> str:
        """``file:line: node name (BehaviorTree ID)``, as a problem of the node names it."""
        return f"{self.file}:{self.line}: node {self.name} (BehaviorTree {self.tree})"


GuardKind = Literal["threshold", "i2t"]


@dataclass(frozen=True)
class GuardView:
    """One guarded signal of a loaded tree, for reports, plots and the demo."""

    node: str  # the guard node's readable name
    source: str
    role: str  # the signal's role in the source (current, or a joint name)
    kind: GuardKind
    model: ProtectionModel
    unit: str = ""  # the signal's unit as the DBC gives it

    @property
    def threshold_unit(self) -> str:
        """The unit of :meth:`threshold` and of the value a trip event compares with it (I²t: A²s or θ)."""
        return self.model.THRESHOLD_UNIT or self.unit

    @property
    def margin_unit(self) -> str:
        """The unit of the replay summary's peak, threshold and margin (I²t: % of its limit)."""
        return I2T_LIMIT_PCT if self.kind == "i2t" else self.unit

    def snapshot(self) -> Snapshot:
        """The model's present state (the peak latch untouched)."""
        return self.model.snapshot()

    def threshold(self) -> float:
        """The trip threshold in force (A or N·m; for I²t the trip level of the accumulator)."""
        return self.model.snapshot().threshold


@dataclass
class LoadedTree:
    """A parsed, validated and bound tree."""

    root: py_trees.behaviour.Behaviour
    main_id: str
    path: Path
    context: Context
    format_version: int  # 4 with BTCPP_format="4", else 3
    nodes: dict[Any, NodeInfo] = field(default_factory=dict)  # by node.id
    wake_up: WakeUpSignal = field(default_factory=WakeUpSignal)

    def guard_nodes(self) -> list[GuardNode]:
        """Every guard condition (the nodes that read sources), in tree order."""
        return [n for n in _preorder(self.root) if isinstance(n, GuardNode)]

    def guards(self) -> list[GuardView]:
        """One :class:`GuardView` per guarded signal (a joints guard gives one per joint), in tree order."""
        return [GuardView(node.name, node.topic_name, role, cast("GuardKind", kind), model,
                          self.context.unit(node.topic_name, role))
                for node in self.guard_nodes() for role, model, kind in node.guarded()]


def _preorder(node: py_trees.behaviour.Behaviour) -> Iterator[py_trees.behaviour.Behaviour]:
    yield node
    for child in node.children:
        yield from _preorder(child)
