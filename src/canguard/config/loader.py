"""YAML config -> frozen dataclasses, validated once.

The dataclasses below are the typed, immutable view every other module reads.
``load_config(path)`` builds them; every problem it finds names the file, the key
path (``sources./battery_state.current``), what was found and what was expected,
and all problems of one file are reported together in one :class:`ConfigError`.
"""

from __future__ import annotations

import difflib
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal, cast

import can
import cantools
import yaml

from canguard.config.node_ids import RESERVED_NODE_IDS
from canguard.errors import ConfigError

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
    min_stop_s: float = 0.0
    """``stop.min_stop``: a stop lasts at least this long (s), whatever the tree says (0: no minimum)."""
    release: Literal["auto", "manual"] = "auto"
    """``stop.release``: ``manual`` also needs a ResetStop node ticked in the releasing tick."""


@dataclass(frozen=True)
class ActionConfig:
    """One ``actions:`` entry: an action node ID and the frames it sends when ticked."""

    name: str
    frames: tuple[FrameSpec, ...] = ()
    role: Literal["auto", "task", "recovery"] = "auto"
    """``task``: part of the task (withheld while stopped); ``recovery``: sends during a stop too;
    ``auto``: task when the tree has no ExecuteTask node, recovery when it has one."""


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
    simulation: bool = False
    """``simulation: true``: the config may guard only ``virtual`` buses under systemd (a bench, not a robot)."""
    database: Any = field(default=None, compare=False, repr=False)
    """The merged ``cantools.database.Database`` of every DBC file."""


@dataclass(frozen=True)
class PartialConfig:
    """The sound parts of a config that has problems (``ConfigError.partial``).

    ``canguard check`` checks the tree against them, so the tree's mistakes are
    listed in the same run as the config's.
    """

    tree: TreeConfig | None
    """``tree:`` when it names an existing file."""
    sources: Mapping[str, SourceConfig]
    """The sources that were built (some may miss signals the config got wrong)."""
    declared_sources: frozenset[str]
    """Every source name declared: a tree naming one that was not built is a follow-on error."""
    sources_ok: bool
    """False when ``sources:`` itself is unusable: the tree's source names are not checked then."""
    actions: Mapping[str, ActionConfig]
    """Every well-formed action node ID declared (with its frames when they loaded)."""


# ---------------------------------------------------------------------------
# The loader. Everything below turns YAML into the dataclasses above.
# ---------------------------------------------------------------------------

_SECONDS_KEYS = ("period", "repeat", "max_age", "deadline", "save_period")
_CONFIRM_OPS: dict[str, Literal["<", ">", "=="]] = {"below": "<", "above": ">", "equals": "=="}
_FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


class _UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses duplicate mapping keys (a typo must not pass silently)."""


def _construct_unique_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode) -> dict[Any, Any]:
    loader.flatten_mapping(node)
    mapping: dict[Any, Any] = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in mapping:
            raise yaml.constructor.ConstructorError(
                "while constructing a mapping",
                node.start_mark,
                f"found duplicate key {key!r}",
                key_node.start_mark,
            )
        mapping[key] = loader.construct_object(value_node, deep=True)
    return mapping


_UniqueKeyLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG,
    _construct_unique_mapping,
)


def _found(value: Any) -> str:
    """How a found value reads in an error message."""
    if value is None:
        return "nothing"
    if isinstance(value, bool):
        return f"{value!r} (a boolean)"
    if isinstance(value, (str, int, float)):
        return repr(value)
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return f"a {type(value).__name__}"


def _closest(word: Any, choices: Any) -> str:
    """``"; closest: a, b"`` for the nearest names, or the known names when none is near."""
    names = sorted({str(c) for c in choices})
    if not names:
        return ""
    scored = sorted(
        ((difflib.SequenceMatcher(None, str(word), n).ratio(), n) for n in names), key=lambda x: -x[0]
    )
    best = scored[0][0]
    # Only names nearly as close as the best one: a clear typo gets one suggestion, not a list.
    near = [n for r, n in scored[:3] if r >= 0.5 and r >= best - 0.15]
    if near:
        return "; closest: " + ", ".join(near)
    shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
    return f"; known: {shown}"


def _path(parent: str, key: Any) -> str:
    return f"{parent}.{key}" if parent else str(key)


def _key_lines(text: str) -> dict[str, int]:
    """The line (1-based) of every key path of a YAML document, in the loader's spelling.

    ``sources.axis0.signal`` is the line of the ``signal:`` key, ``task.frames[1]`` the line
    of the list item; problems name key paths, and this gives them their line in the file.
    """
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return {}
    lines: dict[str, int] = {}
    constructor = yaml.SafeLoader("")

    def walk(node: yaml.Node, key: str) -> None:
        if isinstance(node, yaml.MappingNode):
            for key_node, value_node in node.value:
                if not isinstance(key_node, yaml.ScalarNode):
                    continue
                try:  # the key as the loader sees it (``1:`` is the int 1, as in the problem's path)
                    name = constructor.construct_object(key_node)
                except yaml.YAMLError:
                    name = key_node.value
                sub = _path(key, name)
                lines.setdefault(sub, key_node.start_mark.line + 1)
                walk(value_node, sub)
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                sub = f"{key}[{i}]"
                lines.setdefault(sub, item.start_mark.line + 1)
                walk(item, sub)

    if root is not None:
        walk(root, "")
    return lines


def _line_of(lines: Mapping[str, int], key: str) -> int | None:
    """The line of ``key``, else of its nearest enclosing key that is in the file (a missing key)."""
    k = key
    while k:
        if k in lines:
            return lines[k]
        cut = max(k.rfind("."), k.rfind("["))
        if cut <= 0:
            return None
        k = k[:cut]
    return None


class _Loader:
    """One pass over one config file, collecting every problem instead of stopping at the first."""

    def __init__(self, path: Path, display: str, lines: Mapping[str, int] | None = None) -> None:
        self.path = path
        self.base = path.parent
        self.display = display
        self.problems: list[str] = []
        self.located: list[str] = []
        """``problems`` with the line of their key: ``file:line: key: found X, expected Y``."""
        self.lines: Mapping[str, int] = lines or {}
        self.database: Any = None
        self.messages_ok = False
        self._by_name: dict[str, Any] = {}
        self._by_id: dict[int, list[Any]] = {}
        self.bus_names: tuple[str, ...] = ()
        self.sources: dict[str, SourceConfig] = {}
        self._broken_sources: set[str] = set()
        self._sources_ok = True

    # -- problems ----------------------------------------------------------
    def problem(self, key: str, found: str, expected: str) -> None:
        """Record ``file: key: found X, expected Y`` (and its located form ``file:line: key: ...``)."""
        self.problems.append(f"{self.display}: {key}: found {found}, expected {expected}")
        line = _line_of(self.lines, key)
        where = self.display if line is None else f"{self.display}:{line}"
        self.located.append(f"{where}: {key}: found {found}, expected {expected}")

    def fail(self) -> ConfigError:
        """The ConfigError listing every problem recorded so far."""
        return ConfigError(self.problems, self.located)

    # -- generic checks ----------------------------------------------------
    def mapping(self, value: Any, key: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> bool:
        """Check ``value`` is a mapping with only ``allowed`` keys and every ``required`` one."""
        if not isinstance(value, Mapping):
            self.problem(key or "(top level)", _found(value), f"a mapping with keys {', '.join(allowed)}")
            return False
        for k in value:
            if k not in allowed:
                self.problem(
                    _path(key, k), f"unknown key {k!r}", f"one of {', '.join(allowed)}" + _closest(k, allowed)
                )
        for k in required:
            if k not in value:
                self.problem(_path(key, k), "nothing", "a value (required key)")
        return True

    def string(self, value: Any, key: str, expected: str = "a string") -> str | None:
        if isinstance(value, str) and value:
            return value
        self.problem(key, _found(value), expected)
        return None

    def number(self, value: Any, key: str, *, positive: bool = False) -> float | None:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        if ok and (not positive or value > 0):
            return float(value)
        if positive:
            unit = " in seconds" if key.rsplit(".", 1)[-1] in _SECONDS_KEYS else ""
            self.problem(key, _found(value), f"a number > 0{unit}")
        else:
            self.problem(key, _found(value), "a finite number")
        return None

    def seconds(self, mapping: Mapping[str, Any], name: str, key: str, default: float) -> float:
        if name not in mapping:
            return default
        value = self.number(mapping[name], _path(key, name), positive=True)
        return default if value is None else value

    def file_path(self, value: Any, key: str) -> Path | None:
        text = self.string(value, key, "a file path (relative to the config file or absolute)")
        if text is None:
            return None
        p = Path(text).expanduser()
        return Path(os.path.normpath(p if p.is_absolute() else self.base / p))

    def bus(self, value: Any, key: str) -> str:
        """Resolve a ``bus:`` key (``value`` None = left out)."""
        if value is None:
            if len(self.bus_names) == 1:
                return self.bus_names[0]
            if self.bus_names:
                self.problem(
                    key,
                    "nothing",
                    f"one of the buses {', '.join(self.bus_names)} (several buses are configured)",
                )
            return ""
        if not isinstance(value, str) or value not in self.bus_names:
            if self.bus_names:
                self.problem(key, _found(value), "a configured bus" + _closest(value, self.bus_names))
            return ""
        return value

    # -- DBC ---------------------------------------------------------------
    def load_dbc(self, value: Any) -> tuple[Path, ...]:
        if isinstance(value, str):
            value = [value]
        if not isinstance(value, list) or not value:
            self.problem("dbc", _found(value), "a DBC file path or a non-empty list of them")
            return ()
        files: list[Path] = []
        databases: list[tuple[Path, Any]] = []
        for i, item in enumerate(value):
            p = self.file_path(item, f"dbc[{i}]")
            if p is None:
                continue
            files.append(p)
            try:
                databases.append((p, cantools.database.load_file(str(p))))
            except FileNotFoundError:
                self.problem(f"dbc[{i}]", repr(item), f"an existing DBC file (no such file: {p})")
            except Exception as exc:  # cantools raises many kinds of parse errors
                self.problem(f"dbc[{i}]", f"{p} which does not load ({exc})", "a valid DBC file")
        if len(databases) != len(value):
            return tuple(files)
        messages: list[Any] = []
        where: dict[str, Path] = {}
        ids: dict[tuple[int, bool], tuple[str, Path]] = {}
        clash = False
        for p, db in databases:
            for m in db.messages:
                if m.name in where:
                    self.problem(
                        "dbc", f"message {m.name!r} in both {where[m.name]} and {p}", "unique message names"
                    )
                    clash = True
                    continue
                key = (m.frame_id, bool(m.is_extended_frame))
                if key in ids:
                    other, op = ids[key]
                    self.problem(
                        "dbc",
                        f"frame id 0x{m.frame_id:X} as {other!r} in {op} and as {m.name!r} in {p}",
                        "unique frame ids",
                    )
                    clash = True
                    continue
                where[m.name] = p
                ids[key] = (m.name, p)
                messages.append(m)
        if clash:
            return tuple(files)
        if len(databases) == 1:
            self.database = databases[0][1]
        else:
            nodes = [n for _, db in databases for n in db.nodes]
            self.database = cantools.database.can.Database(messages=messages, nodes=nodes)
        for m in self.database.messages:
            self._by_name[m.name] = m
            self._by_id.setdefault(m.frame_id, []).append(m)
        self.messages_ok = True
        return tuple(files)

    def message(self, value: Any, key: str) -> Any:
        """The cantools message named (or numbered) by ``value``; None after recording a problem."""
        if not self.messages_ok:
            return None
        if isinstance(value, str):
            if value in self._by_name:
                return self._by_name[value]
            text = value.strip().lower()
            try:
                number = int(text, 16) if text.startswith("0x") else int(text, 10)
            except ValueError:
                self.problem(
                    key, repr(value), "a DBC message name or frame id" + _closest(value, self._by_name)
                )
                return None
            value = number
        if isinstance(value, int) and not isinstance(value, bool):
            found = self._by_id.get(value & 0x1FFFFFFF, [])
            if len(found) == 1:
                return found[0]
            if len(found) > 1:
                names = ", ".join(m.name for m in found)
                self.problem(key, f"frame id 0x{value:X} of several messages ({names})", "a message name")
                return None
            self.problem(key, f"0x{value:X}", "the frame id of a DBC message")
            return None
        self.problem(key, _found(value), "a DBC message name or frame id")
        return None

    def signal(self, message: Any, value: Any, key: str) -> Any:
        """The signal ``value`` of ``message``; None after recording a problem."""
        names = [s.name for s in message.signals]
        if isinstance(value, str) and value in names:
            return message.get_signal_by_name(value)
        self.problem(key, _found(value), f"a signal of {message.name}" + _closest(value, names))
        return None

    # -- sections ----------------------------------------------------------
    def buses(self, value: Any) -> dict[str, BusConfig]:
        result: dict[str, BusConfig] = {}
        if not isinstance(value, Mapping) or not value:
            self.problem("buses", _found(value), "a mapping of bus name -> python-can Bus arguments")
            return result
        for name, kwargs in value.items():
            key = _path("buses", name)
            if not isinstance(name, str) or not name:
                self.problem(key, _found(name), "a bus name (a string)")
                continue
            if not isinstance(kwargs, Mapping):
                self.problem(
                    key, _found(kwargs), "a mapping of python-can Bus arguments (interface, channel, ...)"
                )
                continue
            bad = [k for k in kwargs if not isinstance(k, str)]
            for k in bad:
                self.problem(_path(key, k), _found(k), "a python-can Bus argument name")
            interface = kwargs.get("interface")
            if interface is None:
                self.problem(
                    _path(key, "interface"),
                    "nothing",
                    "a python-can interface name (socketcan, virtual, ...)",
                )
            elif not isinstance(interface, str) or interface not in can.interfaces.VALID_INTERFACES:
                self.problem(
                    _path(key, "interface"),
                    _found(interface),
                    "a python-can interface" + _closest(interface, can.interfaces.VALID_INTERFACES),
                )
            result[name] = BusConfig(name=name, kwargs=MappingProxyType(dict(kwargs)))
        self.bus_names = tuple(result)
        return result

    def signal_ref(self, role: str, bus: str, message: Any, signal: Any) -> SignalRef:
        return SignalRef(
            role=role,
            bus=bus,
            message=message.name,
            frame_id=message.frame_id,
            is_extended_id=bool(message.is_extended_frame),
            signal=signal.name,
            unit=signal.unit or None,
            minimum=None if signal.minimum is None else float(signal.minimum),
            maximum=None if signal.maximum is None else float(signal.maximum),
        )

    def source(self, name: str, value: Any) -> SourceConfig | None:
        key = _path("sources", name)
        if not isinstance(value, Mapping):
            self.problem(key, _found(value), "a mapping with kind: battery | joints | current")
            return None
        kind = value.get("kind")
        common = ("kind", "bus", "max_age")
        allowed: tuple[str, ...]
        required: tuple[str, ...]
        if kind == "battery":
            allowed, required = (*common, "message", "current", "present"), ("message", "current")
        elif kind == "current":
            allowed, required = (*common, "message", "signal", "present"), ("message", "signal")
        elif kind == "joints":
            allowed, required = (*common, "effort"), ("effort",)
        else:
            self.problem(
                _path(key, "kind"),
                _found(kind),
                "one of battery, joints, current" + _closest(kind, SOURCE_KINDS),
            )
            # Still check what can be checked without the kind: keys of any kind, the bus,
            # max_age, messages and signal names (the source itself is not built).
            allowed, required = (*common, "message", "current", "signal", "present", "effort"), ()
        self.mapping(value, key, allowed, required)
        bus = self.bus(value.get("bus"), _path(key, "bus"))
        max_age = self.seconds(value, "max_age", key, 0.5)
        signals: list[SignalRef] = []
        known = kind in SOURCE_KINDS
        if kind in ("battery", "current") or (not known and "message" in value):
            msg = self.message(value["message"], _path(key, "message")) if "message" in value else None
            roles: tuple[tuple[str, str], ...]
            if kind == "battery":
                roles = (("current", "current"), ("present", "present"))
            elif kind == "current":
                roles = (("current", "signal"), ("present", "present"))
            else:
                roles = (("current", "current"), ("current", "signal"), ("present", "present"))
            for role, k in roles:
                if msg is None or k not in value:
                    continue
                sig = self.signal(msg, value[k], _path(key, k))
                if sig is not None:
                    signals.append(self.signal_ref(role, bus, msg, sig))
        if kind == "joints" or (not known and "effort" in value):
            effort = value.get("effort")
            if not isinstance(effort, list) or not effort:
                if "effort" in value:
                    self.problem(
                        _path(key, "effort"), _found(effort), "a non-empty list of {message, signal, name}"
                    )
            else:
                seen: set[str] = set()
                for i, item in enumerate(effort):
                    ikey = f"{key}.effort[{i}]"
                    if not self.mapping(
                        item, ikey, ("message", "signal", "name", "bus"), ("message", "signal", "name")
                    ):
                        continue
                    jname = item.get("name")
                    if "name" in item:
                        if not isinstance(jname, str) or not jname or jname == "present":
                            self.problem(
                                _path(ikey, "name"), _found(jname), "a joint name (a string, not 'present')"
                            )
                            jname = None
                        elif jname in seen:
                            self.problem(
                                _path(ikey, "name"), f"{jname!r} again", "a joint name unique in the source"
                            )
                            jname = None
                        else:
                            seen.add(jname)
                    ibus = bus if "bus" not in item else self.bus(item["bus"], _path(ikey, "bus"))
                    msg = self.message(item["message"], _path(ikey, "message")) if "message" in item else None
                    if msg is None or "signal" not in item:
                        continue
                    sig = self.signal(msg, item["signal"], _path(ikey, "signal"))
                    if sig is not None and jname is not None:
                        signals.append(self.signal_ref(jname, ibus, msg, sig))
        if not known:
            return None
        return SourceConfig(
            name=name, kind=cast(SourceKind, kind), bus=bus, signals=tuple(signals), max_age_s=max_age
        )

    def frame_value(self, message: Any, sig_name: Any, value: Any, key: str) -> Any:
        """One ``signals:`` value: a number, or a choice name of a signal with VAL_ choices."""
        sig = self.signal(message, sig_name, key)
        if sig is None:
            return None
        if isinstance(value, str):
            choices = _choices(sig)
            if value in choices:
                return choices[value]
            expected = f"a number or a choice of {sig.name}" if choices else f"a number for {sig.name}"
            self.problem(key, repr(value), expected + (_closest(value, choices) if choices else ""))
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.problem(key, _found(value), f"a number for {sig.name}")
            return None
        lo, hi = sig.minimum, sig.maximum
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            rng = f"[{'-inf' if lo is None else f'{lo:g}'}, {'inf' if hi is None else f'{hi:g}'}]"
            self.problem(key, repr(value), f"a value of {sig.name} within its DBC range {rng}")
            return None
        return value if self.exact(sig, value, key) else None

    def exact(self, sig: Any, value: float, key: str) -> bool:
        """Whether the number ``value`` encodes exactly: one of the VAL_ choices, or a whole raw value.

        cantools rounds a raw value silently (1.5 would be sent as 2), so a number a signal
        cannot carry exactly is a problem, not a guess.
        """
        raw = _whole_raw(sig, value)
        if sig.choices:
            if raw is not None and raw in sig.choices:
                return True
            listed = ", ".join(f"{name} ({number})" for name, number in _choices(sig).items())
            self.problem(key, repr(value), f"one of the choices of {sig.name}: {listed}")
            return False
        if sig.is_float or raw is not None:
            return True
        steps = f"steps of {sig.scale:g}" + (f" from {sig.offset:g}" if sig.offset else "")
        self.problem(key, repr(value), f"a whole raw value: {steps}")
        return False

    def frame(self, value: Any, key: str) -> FrameSpec | None:
        if not isinstance(value, Mapping):
            self.problem(key, _found(value), "a frame: {message, signals, bus} or {id, data, bus, extended}")
            return None
        if "message" in value:
            self.mapping(value, key, ("message", "signals", "bus"), ("message",))
            bus = self.bus(value.get("bus"), _path(key, "bus"))
            msg = self.message(value["message"], _path(key, "message"))
            signals = value.get("signals", {})
            if signals is None:
                signals = {}
            if not isinstance(signals, Mapping):
                self.problem(_path(key, "signals"), _found(signals), "a mapping of signal name -> value")
                return None
            if msg is None:
                return None
            data: dict[str, Any] = {s.name: _initial(s) for s in msg.signals}
            ok = True
            for sname, sval in signals.items():
                v = self.frame_value(msg, sname, sval, _path(_path(key, "signals"), sname))
                if v is None:
                    ok = False
                else:
                    data[sname] = v
            if not ok:
                return None
            try:
                payload = msg.encode(data, scaling=True, padding=False, strict=True)
            except Exception as exc:  # cantools EncodeError / ValueError / KeyError
                given = ", ".join(f"{k}={v!r}" for k, v in signals.items()) or "no signals"
                self.problem(
                    _path(key, "signals"),
                    f"{given}, which does not encode ({exc})",
                    f"values within the ranges of {msg.name}'s signals",
                )
                return None
            return FrameSpec(
                bus=bus,
                arbitration_id=msg.frame_id,
                data=bytes(payload),
                is_extended_id=bool(msg.is_extended_frame),
                is_fd=bool(msg.is_fd),
                label=msg.name,
            )
        if "id" in value:
            self.mapping(value, key, ("id", "data", "bus", "extended", "fd"), ("id",))
            bus = self.bus(value.get("bus"), _path(key, "bus"))
            raw_id = value["id"]
            if isinstance(raw_id, str):
                try:
                    raw_id = int(raw_id, 0)
                except ValueError:
                    self.problem(_path(key, "id"), repr(raw_id), "a frame id (an int or '0x...')")
                    return None
            if isinstance(raw_id, bool) or not isinstance(raw_id, int) or not 0 <= raw_id <= 0x1FFFFFFF:
                self.problem(_path(key, "id"), _found(raw_id), "a frame id 0..0x1FFFFFFF")
                return None
            extended = value.get("extended", raw_id > 0x7FF)
            if not isinstance(extended, bool):
                self.problem(_path(key, "extended"), _found(extended), "true or false")
                return None
            if not extended and raw_id > 0x7FF:
                self.problem(
                    _path(key, "id"), f"0x{raw_id:X}", "a standard frame id 0..0x7FF (or extended: true)"
                )
                return None
            fd = value.get("fd", False)
            if not isinstance(fd, bool):
                self.problem(_path(key, "fd"), _found(fd), "true or false")
                return None
            payload_b = self.raw_data(value.get("data", ""), _path(key, "data"), fd)
            if payload_b is None:
                return None
            label = f"0x{raw_id:08X}" if extended else f"0x{raw_id:03X}"
            return FrameSpec(bus, raw_id, payload_b, is_extended_id=extended, is_fd=fd, label=label)
        self.problem(key, "a mapping without 'message' or 'id'", "a frame: {message, signals} or {id, data}")
        return None

    def raw_data(self, value: Any, key: str, fd: bool) -> bytes | None:
        if value is None:
            value = ""
        try:
            if isinstance(value, str):
                data = bytes.fromhex(value.replace(" ", "").replace(":", ""))
            elif isinstance(value, list) and all(
                isinstance(b, int) and not isinstance(b, bool) for b in value
            ):
                data = bytes(value)
            else:
                raise ValueError
        except ValueError:
            self.problem(key, _found(value), "hex bytes ('00 ff') or a list of byte values 0..255")
            return None
        if (fd and len(data) not in _FD_LENGTHS) or (not fd and len(data) > 8):
            what = (
                "a CAN FD length (0..8, 12, 16, 20, 24, 32, 48, 64)"
                if fd
                else "at most 8 bytes (fd: true for more)"
            )
            self.problem(key, f"{len(data)} bytes", what)
            return None
        return data

    def frames(self, value: Any, key: str) -> tuple[FrameSpec, ...]:
        if value is None:
            return ()
        if not isinstance(value, list):
            self.problem(key, _found(value), "a list of frames")
            return ()
        out = [self.frame(item, f"{key}[{i}]") for i, item in enumerate(value)]
        return tuple(f for f in out if f is not None)

    def tree(self, value: Any) -> TreeConfig | None:
        if value is None:
            return None
        if not self.mapping(value, "tree", ("file", "main", "tick_hz"), ("file",)):
            return None
        file = self.file_path(value["file"], "tree.file") if "file" in value else None
        main = value.get("main")
        if main is not None and not (isinstance(main, str) and main):
            self.problem("tree.main", _found(main), "the ID of a BehaviorTree in the file")
            main = None
        tick_hz = 100.0
        if "tick_hz" in value:
            tick_hz = self.number(value["tick_hz"], "tree.tick_hz", positive=True) or tick_hz
        if file is None:
            return None
        if not file.is_file():
            what = "a directory" if file.is_dir() else "no such file"
            self.problem("tree.file", f"{str(file)!r} ({what})", "a BehaviorTree.CPP XML file")
        return TreeConfig(file=file, main=main, tick_hz=tick_hz)

    def task(self, value: Any) -> TaskConfig:
        if value is None:
            return TaskConfig()
        if not self.mapping(value, "task", ("period", "frames")):
            return TaskConfig()
        return TaskConfig(
            period_s=self.seconds(value, "period", "task", 0.02),
            frames=self.frames(value.get("frames"), "task.frames"),
        )

    def confirm(self, value: Any) -> StopConfirm | None:
        key = "stop.confirm"
        if value is None:
            return None
        if not self.mapping(
            value, key, ("source", "signal", *_CONFIRM_OPS, "deadline"), ("source", "deadline")
        ):
            return None
        ops = [k for k in _CONFIRM_OPS if k in value]
        if len(ops) != 1:
            self.problem(key, f"{len(ops)} of below/above/equals", "exactly one of below, above, equals")
        deadline = self.seconds(value, "deadline", key, 0.0)
        role = value.get("signal", "current")
        source = value.get("source")
        src = self.sources.get(source) if isinstance(source, str) else None
        # A source that is already reported broken (or lost its signals to a DBC that did not
        # load) must not add a follow-on error here: the root cause is reported once.
        follow_on = (
            (isinstance(source, str) and source in self._broken_sources)
            or not self.messages_ok
            or not self._sources_ok
        )
        if "source" in value and src is None and not follow_on:
            self.problem(
                _path(key, "source"), _found(source), "a configured source" + _closest(source, self.sources)
            )
        ref: SignalRef | None = None
        if src is not None:
            ref = src.signal(role) if isinstance(role, str) else None
            if ref is None and not follow_on:
                roles = [s.role for s in src.signals]
                self.problem(
                    _path(key, "signal"), _found(role), f"a signal role of {source}" + _closest(role, roles)
                )
        if len(ops) != 1 or deadline <= 0:
            return None
        op_name = ops[0]
        raw = value[op_name]
        number: float | None = None
        sig = self._by_name[ref.message].get_signal_by_name(ref.signal) if ref is not None else None
        if op_name == "equals" and isinstance(raw, str) and sig is None:
            return None  # a choice name of a source or signal already reported
        if op_name == "equals" and isinstance(raw, str) and sig is not None:
            choices = _choices(sig)
            if raw in choices:
                number = float(choices[raw])
            else:
                self.problem(
                    _path(key, op_name),
                    repr(raw),
                    f"a number or a choice of {sig.name}" + _closest(raw, choices),
                )
                return None
        else:
            number = self.number(raw, _path(key, op_name))
            if op_name == "equals" and number is not None and sig is not None:
                # equals compares decoded values, which only ever take what the signal encodes.
                number = number if self.exact(sig, number, _path(key, op_name)) else None
        if number is None or src is None or ref is None:
            return None
        return StopConfirm(
            source=src.name, signal=ref.role, op=_CONFIRM_OPS[op_name], value=number, deadline_s=deadline
        )

    def stop(self, value: Any) -> StopConfig:
        if value is None:
            return StopConfig()
        if not self.mapping(value, "stop", ("repeat", "frames", "confirm", "escalate", "min_stop", "release")):
            return StopConfig()
        min_stop = 0.0
        if "min_stop" in value:
            raw = value["min_stop"]
            if isinstance(raw, (int, float)) and not isinstance(raw, bool) and math.isfinite(raw) and raw >= 0:
                min_stop = float(raw)
            else:
                self.problem("stop.min_stop", _found(raw), "a number >= 0 in seconds")
        release = value.get("release", "auto")
        if release not in ("auto", "manual"):
            self.problem("stop.release", _found(release), "auto or manual")
            release = "auto"
        return StopConfig(
            repeat_s=self.seconds(value, "repeat", "stop", 0.05),
            frames=self.frames(value.get("frames"), "stop.frames"),
            confirm=self.confirm(value.get("confirm")),
            escalate=self.frames(value.get("escalate"), "stop.escalate"),
            min_stop_s=min_stop,
            release=release,
        )

    def actions(self, value: Any) -> dict[str, ActionConfig]:
        result: dict[str, ActionConfig] = {}
        if value is None:
            return result
        if not isinstance(value, Mapping):
            self.problem("actions", _found(value), "a mapping of action node ID -> {frames: [...]}")
            return result
        builtin = RESERVED_NODE_IDS if value else frozenset()
        for name, body in value.items():
            key = _path("actions", name)
            if not isinstance(name, str) or not _IDENT.fullmatch(name):
                self.problem(key, _found(name), "an action node ID (letters, digits, underscores)")
                continue
            if name in builtin:  # its frames are still checked below
                self.problem(key, "the ID of a built-in node type", "a new action name")
            if body is None:
                result[name] = ActionConfig(name=name)
                continue
            if not self.mapping(body, key, ("frames", "role")):
                continue
            role = body.get("role", "auto")
            if role not in ("auto", "task", "recovery"):
                self.problem(_path(key, "role"), _found(role), "task, recovery or auto")
                role = "auto"
            result[name] = ActionConfig(
                name=name, frames=self.frames(body.get("frames"), _path(key, "frames")), role=role
            )
        return result

    def state(self, value: Any) -> StateConfig:
        if value is None:
            return StateConfig()
        if not self.mapping(value, "state", ("file", "on_corrupt", "save_period")):
            return StateConfig()
        file = self.file_path(value["file"], "state.file") if value.get("file") is not None else None
        on_corrupt = value.get("on_corrupt", "hot")
        if on_corrupt not in ("hot", "cold"):
            self.problem("state.on_corrupt", _found(on_corrupt), "hot or cold")
            on_corrupt = "hot"
        return StateConfig(
            file=file, on_corrupt=on_corrupt, save_period_s=self.seconds(value, "save_period", "state", 5.0)
        )

    def partial(
        self, doc: Mapping[str, Any], tree: TreeConfig | None, actions: Mapping[str, ActionConfig]
    ) -> PartialConfig:
        """What of a config with problems is sound enough to check its tree against."""
        raw_actions = doc.get("actions")
        names = [n for n in raw_actions if isinstance(n, str)] if isinstance(raw_actions, Mapping) else []
        builtin = RESERVED_NODE_IDS if names else frozenset()
        # An action whose frames are wrong is still an action node ID the tree may use.
        all_actions = {
            n: actions.get(n, ActionConfig(name=n)) for n in names if _IDENT.fullmatch(n) and n not in builtin
        }
        raw_sources = doc.get("sources")
        declared = frozenset(str(n) for n in raw_sources) if isinstance(raw_sources, Mapping) else frozenset()
        return PartialConfig(
            tree=tree if tree is not None and tree.file.is_file() else None,
            sources=MappingProxyType(dict(self.sources)),
            declared_sources=declared,
            sources_ok=self._sources_ok,
            actions=MappingProxyType(all_actions),
        )

    def config(self, doc: Any) -> Config:
        top = ("dbc", "buses", "sources", "tree", "task", "stop", "actions", "events", "state", "simulation")
        if not self.mapping(doc, "", top, ("dbc", "buses")):
            raise self.fail()
        dbc_files = self.load_dbc(doc["dbc"]) if "dbc" in doc else ()
        buses = self.buses(doc["buses"]) if "buses" in doc else {}
        raw_sources = doc.get("sources") or {}
        if not isinstance(raw_sources, Mapping):
            self.problem("sources", _found(raw_sources), "a mapping of source name -> source")
            self._sources_ok = False
            raw_sources = {}
        for name, body in raw_sources.items():
            if not isinstance(name, str) or not name:
                self.problem(_path("sources", name), _found(name), "a source name (a string)")
                continue
            before = len(self.problems)
            src = self.source(name, body)
            if src is not None:
                self.sources[name] = src
            if len(self.problems) > before:
                # Already reported: references to this source must not add follow-on errors.
                self._broken_sources.add(name)
        tree = self.tree(doc.get("tree"))
        task = self.task(doc.get("task"))
        stop = self.stop(doc.get("stop"))
        actions = self.actions(doc.get("actions"))
        events = self.file_path(doc["events"], "events") if doc.get("events") is not None else None
        state = self.state(doc.get("state"))
        simulation = doc.get("simulation", False)
        if not isinstance(simulation, bool):
            self.problem("simulation", _found(simulation), "true or false")
            simulation = False
        if self.problems:
            err = self.fail()
            err.partial = self.partial(doc, tree, actions)
            raise err
        return Config(
            path=self.path,
            dbc_files=dbc_files,
            buses=MappingProxyType(buses),
            sources=MappingProxyType(dict(self.sources)),
            tree=tree,
            task=task,
            stop=stop,
            actions=MappingProxyType(actions),
            events=events,
            state=state,
            simulation=simulation,
            database=self.database,
        )


SOURCE_KINDS: tuple[SourceKind, ...] = ("battery", "joints", "current")
_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _initial(signal: Any) -> Any:
    """The value a signal left out of ``signals:`` takes: its DBC initial value, else 0 (or its minimum)."""
    initial = getattr(signal, "initial", None)
    if initial is not None:
        return initial
    if signal.minimum is not None and signal.minimum > 0:
        return signal.minimum
    return 0


def _physical(signal: Any, raw: int) -> int | float:
    """The physical value of ``raw`` (``raw * scale + offset``), an int when it is whole."""
    value = raw * signal.scale + signal.offset
    return int(value) if float(value).is_integer() else value


def _whole_raw(signal: Any, value: float) -> int | None:
    """The raw value ``(value - offset) / scale`` when it is a whole number (within rounding), else None."""
    if not signal.scale:
        return None
    raw = (value - signal.offset) / signal.scale
    nearest = round(raw)
    return nearest if abs(raw - nearest) <= 1e-9 * max(1.0, abs(raw)) else None


def _choices(signal: Any) -> dict[str, int | float]:
    """A signal's VAL_ choices as ``name -> physical value``."""
    return {str(name): _physical(signal, int(raw)) for raw, name in (signal.choices or {}).items()}


def load_config_text(text: str, path: str | Path) -> Config:
    """Validate config ``text`` as if read from ``path`` (relative paths resolve against its folder).

    Raises :class:`ConfigError` listing every problem, each as
    ``"{file}: {key.path}: found ..., expected ..."``; YAML syntax errors as ``"{file}:{line}: ..."``.
    """
    display = str(path)
    p = Path(path).expanduser().absolute()
    try:
        doc = yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{display}:{mark.line + 1}:{mark.column + 1}" if mark is not None else display
        problem = getattr(exc, "problem", None) or str(exc)
        context = getattr(exc, "context", None)
        detail = f"{context}, {problem}" if context else str(problem)
        raise ConfigError(f"{where}: YAML syntax error: {detail}") from exc
    if doc is None:
        raise ConfigError(
            f"{display}: (top level): found an empty file, expected a mapping with dbc, buses, sources"
        )
    return _Loader(p, display, _key_lines(text)).config(doc)


def load_config(path: str | Path) -> Config:
    """Read and validate the YAML config at ``path`` (and every DBC file it names).

    Returns the frozen :class:`Config`; raises :class:`ConfigError` listing every
    problem found in the file (an unreadable file is one problem naming it).
    """
    try:
        text = Path(path).expanduser().read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(
            f"{path}: found a file that cannot be read ({exc.strerror or exc}), expected a YAML config"
        ) from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{path}: found bytes that are not UTF-8 ({exc.reason}), expected a YAML text file"
        ) from exc
    return load_config_text(text, path)
