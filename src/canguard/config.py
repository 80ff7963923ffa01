"""YAML config -> frozen dataclasses, validated once.

The dataclasses below are the typed, immutable view every other module reads.
``load_config(path)`` builds them; every problem it finds names the file, the key
path (``sources./battery_state.current``), what was found and what was expected,
and all problems of one file are reported together in one :class:`ConfigError`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

SourceKind = Literal["battery", "joints", "current"]


@dataclass(frozen=True)
class BusConfig:
    """One python-can bus: ``kwargs`` are passed to ``can.Bus(**kwargs)`` as given."""

    name: str
    kwargs: Mapping[str, Any]

    @property
    def interface(self) -> str:
        """The python-can interface name (``socketcan``, ``virtual``, ``udp_multicast``...)."""
        return str(self.kwargs.get("interface", ""))

    @property
    def channel(self) -> str | None:
        """The channel as configured (``can0``), or None."""
        ch = self.kwargs.get("channel")
        return None if ch is None else str(ch)


@dataclass(frozen=True)
class SignalRef:
    """One DBC signal a source reads, resolved against the loaded DBC files.

    ``role`` is the name the signal has inside its source: ``current`` or
    ``present`` for battery / current sources, the joint name for joints.
    """

    role: str
    bus: str
    message: str
    frame_id: int
    is_extended_id: bool
    signal: str
    unit: str | None = None
    minimum: float | None = None
    maximum: float | None = None


@dataclass(frozen=True)
class SourceConfig:
    """A named source trees refer to with ``topic_name="..."``."""

    name: str
    kind: SourceKind
    bus: str
    signals: tuple[SignalRef, ...]
    max_age_s: float = 0.5

    def signal(self, role: str) -> SignalRef | None:
        """The signal with that role, or None."""
        for s in self.signals:
            if s.role == role:
                return s
        return None

    @property
    def value_roles(self) -> tuple[str, ...]:
        """The roles that carry values guards check (every role but ``present``)."""
        return tuple(s.role for s in self.signals if s.role != "present")


@dataclass(frozen=True)
class FrameSpec:
    """A frame canguard may send, encoded once at load time."""

    bus: str
    arbitration_id: int
    data: bytes
    is_extended_id: bool = False
    is_fd: bool = False
    label: str = ""
    """The DBC message name, or the hex id of a raw frame (for events and logs)."""


@dataclass(frozen=True)
class TreeConfig:
    """``tree:``: which BehaviorTree.CPP XML file and tree to run, and how often to tick."""

    file: Path
    main: str | None = None
    tick_hz: float = 100.0


@dataclass(frozen=True)
class TaskConfig:
    """``task:``: frames ExecuteTask sends every ``period_s`` while the task runs."""

    period_s: float = 0.02
    frames: tuple[FrameSpec, ...] = ()


@dataclass(frozen=True)
class StopConfirm:
    """``stop.confirm``: the stop counts as obeyed once ``source.signal <op> value`` holds."""

    source: str
    signal: str
    op: Literal["<", "<=", ">", ">=", "==", "!="]
    value: float
    deadline_s: float


@dataclass(frozen=True)
class StopConfig:
    """``stop:``: frames sent when the tree stops the task, repeated every ``repeat_s``."""

    repeat_s: float = 0.05
    frames: tuple[FrameSpec, ...] = ()
    confirm: StopConfirm | None = None
    escalate: tuple[FrameSpec, ...] = ()


@dataclass(frozen=True)
class ActionConfig:
    """One ``actions:`` entry: an action node ID and the frames it sends when ticked."""

    name: str
    frames: tuple[FrameSpec, ...] = ()


@dataclass(frozen=True)
class StateConfig:
    """``state:``: where I²t heat is kept across restarts."""

    file: Path | None = None
    on_corrupt: Literal["hot", "cold"] = "hot"
    save_period_s: float = 5.0


@dataclass(frozen=True)
class Config:
    """The whole validated config file."""

    path: Path
    dbc_files: tuple[Path, ...]
    buses: Mapping[str, BusConfig]
    sources: Mapping[str, SourceConfig]
    tree: TreeConfig | None
    task: TaskConfig
    stop: StopConfig
    actions: Mapping[str, ActionConfig]
    events: Path | None
    state: StateConfig = field(default_factory=StateConfig)
    database: Any = field(default=None, compare=False, repr=False)
    """The merged ``cantools.database.Database`` of every DBC file."""
