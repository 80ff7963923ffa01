"""The config's typed, frozen schema: what every other module reads (built by :mod:`.loader`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

SourceKind = Literal["battery", "joints", "current"]

NON_VALUE_ROLES = frozenset({"present", "counter", "nmt", "emcy", "emcy_code", "emcy_data", "fault"})
"""Roles that say whether a source can be trusted rather than carry a value a guard checks."""


@dataclass(frozen=True)
class BusConfig:
    """One python-can bus: ``kwargs`` are passed to ``can.Bus(**kwargs)`` as given (all but ``filter``)."""

    name: str
    kwargs: Mapping[str, Any]
    filter: bool = True  # receive only the frames the config reads (kernel filters on SocketCAN); False: every frame

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
    """One DBC signal a source reads; ``role``: its name in the source (``current``, ``present``, a joint's name)."""

    role: str
    bus: str
    message: str
    frame_id: int
    is_extended_id: bool
    signal: str
    unit: str | None = None
    minimum: float | None = None
    maximum: float | None = None
    max_age_s: float | None = None  # its own timeout (a CANopen drive's heartbeat); None: the source's


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
        return next((s for s in self.signals if s.role == role), None)

    @property
    def value_roles(self) -> tuple[str, ...]:
        """The roles that carry values guards check (not :data:`NON_VALUE_ROLES`)."""
        return tuple(s.role for s in self.signals if s.role not in NON_VALUE_ROLES)


@dataclass(frozen=True)
class FrameSpec:
    """A frame canguard may send, encoded once at load time."""

    bus: str
    arbitration_id: int
    data: bytes
    is_extended_id: bool = False
    is_fd: bool = False
    label: str = ""  # the DBC message name, or the hex id of a raw frame


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
    min_stop_s: float = 0.0  # a stop lasts at least this long, whatever the tree says
    release: Literal["auto", "manual"] = "auto"  # manual: a release also needs a ResetStop node ticked in that tick


@dataclass(frozen=True)
class ActionConfig:
    """One ``actions:`` entry: an action node ID and the frames it sends when ticked."""

    name: str
    frames: tuple[FrameSpec, ...] = ()
    role: Literal["auto", "task", "recovery"] = "auto"
    """``task``: withheld while stopped; ``recovery``: sends during a stop too; ``auto``: task unless the tree has
    an ExecuteTask node."""


@dataclass(frozen=True)
class StateConfig:
    """``state:``: where I²t heat is kept across restarts."""

    file: Path | None = None
    on_corrupt: Literal["hot", "cold"] = "hot"
    save_period_s: float = 5.0


@dataclass(frozen=True)
class MonitorConfig:
    """``monitor:``: ``HOST:PORT`` of the status page (``http``; ``token``: the bearer token it requires, needed when
    not loopback) and of the Groot2 monitor (``groot2``: REP on PORT, PUB on PORT + 1); both off unless configured."""

    http: str | None = None
    token: str | None = None
    groot2: str | None = None


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
    actions: Mapping[str, ActionConfig]  # every well-formed action node ID declared
    events: Path | None
    state: StateConfig = field(default_factory=StateConfig)
    monitor: MonitorConfig = field(default_factory=MonitorConfig)
    simulation: bool = False  # a bench, not a robot: the config may guard only ``virtual`` buses under systemd
    database: Any = field(default=None, compare=False, repr=False)
    """The merged ``cantools.database.Database`` of every DBC file and the ``canopen:`` drives' frames."""
    canopen: Mapping[str, Any] = field(default_factory=dict)
    """The ``canopen:`` drives by name (:class:`canguard.config.canopen.CanopenDrive`, which reads this module)."""
    dbc_notes: tuple[str, ...] = ()  # what the DBC files get wrong where this config does not read them (check -v)


@dataclass(frozen=True)
class PartialConfig:
    """The sound parts of a config that has problems (``ConfigError.partial``): ``check`` judges the tree by them."""

    tree: TreeConfig | None  # ``tree:`` when it names an existing file
    sources: Mapping[str, SourceConfig]  # the sources that were built (some may miss signals)
    declared_sources: frozenset[str]  # every source name declared (a tree naming one not built is a follow-on error)
    sources_ok: bool  # False when ``sources:`` itself is unusable (the tree's source names are not checked)
    actions: Mapping[str, ActionConfig]  # every well-formed action node ID declared
