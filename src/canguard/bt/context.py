"""The context one tree runs in (clock, sources, models, frame sink, events): nodes reach for nothing else."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

from canguard.config.schema import ActionConfig, FrameSpec, SourceConfig, SourceKind
from canguard.errors import quote
from canguard.io.clock import Clock
from canguard.io.frame import Sample
from canguard.protect.base import ProtectionModel
from canguard.protect.staleness import SourceHealth


class FrameSink(Protocol):
    """Takes frames to send; must never block the caller."""

    def send(self, frames: Sequence[FrameSpec], origin: str) -> None:
        """Queue ``frames`` for sending; ``origin`` names the node or action that sent them."""


class TaskGate(Protocol):
    """What ExecuteTask drives: the task's enable / heartbeat frames."""

    def run(self, node: str, now: float) -> None:
        """ExecuteTask was ticked: the task runs (send task frames every period)."""

    def halt(self, node: str, now: float) -> None:
        """ExecuteTask was halted: the task stops (send stop frames at once)."""


class NullSink:
    """A frame sink that drops what it is given (a tree checked or ticked without a bus)."""

    def send(self, frames: Sequence[FrameSpec], origin: str) -> None:
        """Drop the frames."""


class NullTaskGate:
    """A task gate that does nothing (a tree checked or ticked without a task)."""

    def run(self, node: str, now: float) -> None:
        """Nothing runs."""

    def halt(self, node: str, now: float) -> None:
        """Nothing halts."""


EventCallback = Callable[[dict[str, Any]], None]

_DRIVE_EVENT_ROLES = frozenset({"nmt", "emcy"})  # journalled: nmt on a change, emcy each
NMT_STATES = {0x00: "boot_up", 0x04: "stopped", 0x05: "operational", 0x7F: "pre_operational"}  # CiA 301


class Context:
    """Everything a node of one tree may use; built by the engine, shared by all nodes."""

    def __init__(self, clock: Clock, sources: Mapping[str, SourceConfig], sink: FrameSink | None = None,
                 actions: Mapping[str, ActionConfig] | None = None, task: TaskGate | None = None,
                 on_event: EventCallback | None = None, stop_frames: Sequence[FrameSpec] = ()) -> None:
        self.clock = clock
        self.sources = dict(sources)
        self.sink: FrameSink = sink if sink is not None else NullSink()
        self.actions = dict(actions or {})
        self.task: TaskGate = task if task is not None else NullTaskGate()
        self.on_event = on_event
        self.health: dict[str, SourceHealth] = {name: SourceHealth(cfg) for name, cfg in self.sources.items()}
        self._subscribers: dict[tuple[str, str], list[ProtectionModel]] = {}
        self.read_sources: set[str] = set()  # sources some node reads (the others only give stale events)
        self.tree_start: float | None = None  # time of the tree's first tick
        self.heat_models: dict[str, ProtectionModel] = {}  # I²t models by guard name (the state file)
        self.stop_frames: tuple[FrameSpec, ...] = tuple(stop_frames)

    def source(self, name: str, kinds: tuple[SourceKind, ...]) -> SourceConfig:
        """The configured source ``name`` of one of ``kinds``; KeyError/ValueError naming the choices."""
        cfg = self.sources.get(name)
        if cfg is None:
            known = ", ".join(sorted(self.sources)) or "(none configured)"
            raise KeyError(f"unknown source {quote(name)}; configured sources: {known}")
        if cfg.kind not in kinds:
            raise ValueError(f"source {name!r} is of kind {cfg.kind!r}, expected {' or '.join(kinds)}")
        self.read_sources.add(name)
        return cfg

    def unit(self, source: str, role: str) -> str:
        """The DBC unit of ``source``'s ``role`` signal (empty when unknown or unitless)."""
        cfg = self.sources.get(source)
        ref = cfg.signal(role) if cfg is not None else None
        return (ref.unit or "") if ref is not None else ""

    def subscribe(self, source: str, role: str, model: ProtectionModel) -> None:
        """Feed every valid sample of ``source``'s ``role`` signal to ``model`` from now on."""
        self._subscribers.setdefault((source, role), []).append(model)

    def subscribers(self, source: str, role: str) -> list[ProtectionModel]:
        """The models fed with ``source``'s ``role`` samples, in subscription order."""
        return list(self._subscribers.get((source, role), ()))

    def journals(self, source: str, role: str) -> bool:
        """True when the samples of ``source``'s ``role`` are journalled (:meth:`drive_event`) before its health
        takes them: a CANopen drive's ``nmt`` / ``emcy``."""
        health = self.health.get(source)
        return role in _DRIVE_EVENT_ROLES and health is not None and health.source.signal("emcy_code") is not None

    def drive_event(self, sample: Sample, health: SourceHealth) -> None:
        """Journal a CANopen drive's EMCY frames (code, error register, manufacturer bytes) and NMT state
        changes (from its first source only)."""
        fields: dict[str, Any] = {"t": sample.t, "source": sample.source, "value": sample.value}
        if sample.signal == "emcy":
            code, data = health.value("emcy_code"), health.value("emcy_data")
            if sample.reason:
                fields["reason"] = sample.reason
            else:
                fields.update(code=f"0x{int(code):04X}", error_register=int(sample.value),
                              manufacturer=int(data).to_bytes(5, "little").hex().upper(),
                              reset=int(code) == 0 and int(sample.value) == 0)
            self.record("emcy", **fields)
            return
        before = health.value("nmt")
        if sample.reason or sample.value == before:
            return
        fields["value"] = state = int(sample.value)
        self.record("nmt", **fields, state=NMT_STATES.get(state, f"0x{state:02X}"),
                    previous=None if before != before else NMT_STATES.get(int(before), f"0x{int(before):02X}"))

    def record(self, event: str, **fields: Any) -> None:
        """Report an event (``trip``, ``recover``, ...) with its fields to the journal, if any."""
        if self.on_event is not None:
            self.on_event({"t": self.clock.now(), "event": event, **fields})
