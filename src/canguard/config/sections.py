"""The config's sections besides ``dbc:``, ``canopen:`` and ``monitor:``: buses, sources, tree, task, stop, actions,
state, and the frames they send."""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any, NamedTuple, cast

from canguard.config.dbc import Messages
from canguard.config.node_ids import RESERVED_NODE_IDS
from canguard.config.schema import (
    NON_VALUE_ROLES,
    ActionConfig,
    BusConfig,
    FrameSpec,
    SignalRef,
    SourceConfig,
    SourceKind,
    StateConfig,
    StopConfig,
    StopConfirm,
    TaskConfig,
    TreeConfig,
)
from canguard.config.yamlsrc import _CONFIRM_OPS, _FD_LENGTHS, Checks, _closest, _found, _path, _shown

_BUILT_IN_INTERFACES = frozenset({
    "socketcan", "socketcand", "virtual", "udp_multicast", "slcan", "serial", "gs_usb", "pcan", "kvaser",
    "vector", "ixxat",
})
"""Built into every python-can canguard supports: accepted without importing it (a candump replay never does)."""


def buses(c: Checks, value: Any) -> dict[str, BusConfig]:
    result: dict[str, BusConfig] = {}
    if not isinstance(value, Mapping) or not value:
        c.problem("buses", _found(value), "a mapping of bus name -> python-can Bus arguments")
        return result
    for name, kwargs, key in c.named(value, "buses", "a bus name"):
        if not isinstance(kwargs, Mapping):
            c.problem(key, _found(kwargs), "a mapping of python-can Bus arguments (interface, channel, ...)")
            continue
        for k in kwargs:
            if not isinstance(k, str):
                c.problem(_path(key, k), _found(k), "a python-can Bus argument name")
        interface = kwargs.get("interface")
        if interface is None:
            c.problem(_path(key, "interface"), "nothing", "a python-can interface name (socketcan, virtual, ...)")
        elif not isinstance(interface, str) or interface not in _BUILT_IN_INTERFACES:
            import can.interfaces  # python-can's names, plugins included

            if not isinstance(interface, str) or interface not in can.interfaces.VALID_INTERFACES:
                c.problem(_path(key, "interface"), _found(interface),
                          "a python-can interface" + _closest(interface, can.interfaces.VALID_INTERFACES))
        only = kwargs.get("filter", True)
        if not isinstance(only, bool):
            c.problem(_path(key, "filter"), _found(only),
                      "true (receive only the frames the config reads) or false (every frame)")
        args = {k: v for k, v in kwargs.items() if k != "filter"}
        result[name] = BusConfig(name=name, kwargs=MappingProxyType(args), filter=only is not False)
    c.bus_names = tuple(result)
    return result


def _ref(role: str, bus: str, message: Any, signal: Any) -> SignalRef:
    return SignalRef(role, bus, message.name, message.frame_id, bool(message.is_extended_frame), signal.name,
                     unit=signal.unit or None, minimum=None if signal.minimum is None else float(signal.minimum),
                     maximum=None if signal.maximum is None else float(signal.maximum))


def _message_signals(m: Messages, key: str, value: Mapping[str, Any], keys: tuple[str, ...], bus: str
                     ) -> list[SignalRef]:
    """The signals a source of one message reads (``keys``: its kind's, in role order)."""
    msg = m.message(value, key)
    signals: list[SignalRef] = []
    for k in keys:
        if msg is None or k in ("message", "effort") or k not in value:
            continue
        sig = m.read_signal(msg, value[k], _path(key, k))
        if sig is not None:
            signals.append(_ref("current" if k == "signal" else k, bus, msg, sig))
    return signals


def _effort_signals(c: Checks, m: Messages, key: str, value: Mapping[str, Any], bus: str) -> list[SignalRef]:
    """The joints of a ``joints`` source (``effort:``), each a signal named by its joint."""
    effort = value.get("effort")
    if not isinstance(effort, list) or not effort:
        if "effort" in value:
            c.problem(_path(key, "effort"), _found(effort), "a non-empty list of {message, signal, name}")
        return []
    signals: list[SignalRef] = []
    seen: set[str] = set()
    for i, item in enumerate(effort):
        ikey = f"{key}.effort[{i}]"
        if not c.mapping(item, ikey, ("message", "signal", "name", "bus"), ("message", "signal", "name")):
            continue
        jname = item.get("name")
        if "name" in item:
            if not isinstance(jname, str) or not jname or jname in NON_VALUE_ROLES:
                c.problem(_path(ikey, "name"), _found(jname),
                          "a joint name (a string, not " + ", ".join(sorted(NON_VALUE_ROLES)) + ")")
                jname = None
            elif jname in seen:
                c.problem(_path(ikey, "name"), f"{jname!r} again", "a joint name unique in the source")
                jname = None
            else:
                seen.add(jname)
        ibus = c.bus(item, ikey) if "bus" in item else bus
        msg = m.message(item, ikey)
        if msg is None or "signal" not in item:
            continue
        sig = m.read_signal(msg, item["signal"], _path(ikey, "signal"))
        if sig is not None and jname is not None:
            signals.append(_ref(jname, ibus, msg, sig))
    return signals


def source(c: Checks, m: Messages, name: str, value: Any) -> SourceConfig | None:
    """The source ``sources.NAME``; None after a problem."""
    key = _path("sources", name)
    if not isinstance(value, Mapping):
        c.problem(key, _found(value), "a mapping with kind: battery | joints | current")
        return None
    kind = value.get("kind")
    if "canopen" in value:  # an object of a canopen: drive
        c.mapping(value, key, ("kind", "canopen", "object", "scale", "max_age"), ("kind", "canopen", "object"))
        if kind != "current":
            c.problem(_path(key, "kind"), _found(kind), "current (a source of a canopen: drive)")
        elif m.canopen is None:
            c.problem(_path(key, "canopen"), _found(value.get("canopen")), "a drive of canopen: (none configured)")
        else:
            return m.canopen.source(name, value, key)
        return None
    keys = _KIND_KEYS.get(kind) if isinstance(kind, str) else None
    known = keys is not None
    if keys is None:
        c.problem(_path(key, "kind"), _found(kind), "one of battery, joints, current" + _closest(kind, SOURCE_KINDS))
        # Still check what can be checked without the kind (the source itself is not built).
        keys = ("message", "current", "signal", "present", "counter", "effort")
    c.mapping(value, key, ("kind", "bus", "max_age", *keys), keys[:2] if known else ())
    bus = c.bus(value, key)
    max_age = c.seconds(value, "max_age", key, 0.5)
    signals: list[SignalRef] = []
    if "message" in keys and (known or "message" in value):
        signals.extend(_message_signals(m, key, value, keys, bus))
    if "effort" in keys and (known or "effort" in value):
        signals.extend(_effort_signals(c, m, key, value, bus))
    if not known:
        return None
    return SourceConfig(name=name, kind=cast(SourceKind, kind), bus=bus, signals=tuple(signals), max_age_s=max_age)


class ReadSources(NamedTuple):
    """``sources:`` as read: the sound sources, the names of those with a problem, whether it was a mapping."""

    sources: dict[str, SourceConfig]
    broken: set[str]
    ok: bool


def read_sources(c: Checks, m: Messages, value: Any) -> ReadSources:
    """Every source of ``sources:`` (``value``; None: none), each problem recorded."""
    value = value or {}
    read = ReadSources({}, set(), isinstance(value, Mapping))
    if not read.ok:
        c.problem("sources", _found(value), "a mapping of source name -> source")
    for name, body, _ in c.named(value if read.ok else {}, "sources", "a source name"):
        before = len(c.problems)
        src = source(c, m, name, body)
        if src is not None:
            read.sources[name] = src
        if len(c.problems) > before:  # reported: references to this source add no follow-on errors
            read.broken.add(name)
    return read


SOURCE_KINDS: tuple[SourceKind, ...] = ("battery", "joints", "current")
_KIND_KEYS: dict[str, tuple[str, ...]] = {
    "battery": ("message", "current", "present", "counter"), "joints": ("effort",),
    "current": ("message", "signal", "present", "counter")}
"""The keys of each source kind besides kind, bus and max_age (the first two, or the one, required), in role order."""


def tree(c: Checks, value: Any) -> TreeConfig | None:
    value = c.section(value, "tree", ("file", "main", "tick_hz"), ("file",))
    if value is None:
        return None
    file = c.file_path(value["file"], "tree.file") if "file" in value else None
    main = value.get("main")
    main = None if main is None else c.string(main, "tree.main", "the ID of a BehaviorTree in the file")
    tick_hz = c.seconds(value, "tick_hz", "tree", 100.0)
    if file is None:
        return None
    if not file.is_file():
        what = "a directory" if file.is_dir() else "no such file"
        c.problem("tree.file", f"{str(file)!r} ({what})", "a BehaviorTree.CPP XML file")
    return TreeConfig(file=file, main=main, tick_hz=tick_hz)


def task(c: Checks, m: Messages, value: Any) -> TaskConfig:
    value = c.section(value, "task", ("period", "frames"))
    if value is None:
        return TaskConfig()
    return TaskConfig(period_s=c.seconds(value, "period", "task", 0.02), frames=frames(c, m, value, "frames", "task"))


def _confirm(c: Checks, m: Messages, value: Any, read: ReadSources) -> StopConfirm | None:
    key = "stop.confirm"
    value = c.section(value, key, ("source", "signal", *_CONFIRM_OPS, "deadline"), ("source", "deadline"))
    if value is None:
        return None
    ops = [k for k in _CONFIRM_OPS if k in value]
    if len(ops) != 1:
        c.problem(key, f"{len(ops)} of below/above/equals", "exactly one of below, above, equals")
    deadline = c.seconds(value, "deadline", key, 0.0)
    role = value.get("signal", "current")
    source = value.get("source")
    src = read.sources.get(source) if isinstance(source, str) else None
    # A source already reported broken (or whose DBC did not load) adds no follow-on error here.
    follow_on = (isinstance(source, str) and source in read.broken) or not (m.ok and read.ok)
    if "source" in value and src is None and not follow_on:
        c.problem(_path(key, "source"), _found(source), "a configured source" + _closest(source, read.sources))
    ref = src.signal(role) if src is not None and isinstance(role, str) else None
    if src is not None and ref is None and not follow_on:
        roles = [s.role for s in src.signals]
        c.problem(_path(key, "signal"), _found(role), f"a signal role of {source}" + _closest(role, roles))
    if len(ops) != 1 or deadline <= 0:
        return None
    op_name = ops[0]
    raw = value[op_name]
    sig = m.by_name[ref.message].get_signal_by_name(ref.signal) if ref is not None else None
    if op_name == "equals" and isinstance(raw, str):
        choice = choice_value(c, sig, raw, _path(key, op_name)) if sig is not None else None
        number = None if choice is None else float(choice)  # no sig: a source or signal already reported
    else:
        number = c.number(raw, _path(key, op_name))
        if op_name == "equals" and number is not None and sig is not None:
            # equals compares decoded values, which only ever take what the signal encodes.
            number = number if exact(c, sig, number, _path(key, op_name)) else None
    if number is None or src is None or ref is None:
        return None
    return StopConfirm(source=src.name, signal=ref.role, op=_CONFIRM_OPS[op_name], value=number,
                       deadline_s=deadline)


def stop(c: Checks, m: Messages, value: Any, read: ReadSources) -> StopConfig:
    value = c.section(value, "stop", ("repeat", "frames", "confirm", "escalate", "min_stop", "release"))
    if value is None:
        return StopConfig()
    min_stop = value.get("min_stop", 0.0)
    if isinstance(min_stop, bool) or not isinstance(min_stop, (int, float)) or not 0 <= min_stop < math.inf:
        c.problem("stop.min_stop", _found(min_stop), "a number >= 0 in seconds")
        min_stop = 0.0
    release = c.choice(value, "release", "stop", ("auto", "manual"), "auto")
    return StopConfig(c.seconds(value, "repeat", "stop", 0.05), frames(c, m, value, "frames", "stop"),
                      _confirm(c, m, value.get("confirm"), read), frames(c, m, value, "escalate", "stop"),
                      float(min_stop), release)


def actions(c: Checks, m: Messages, value: Any) -> dict[str, ActionConfig]:
    result: dict[str, ActionConfig] = {}
    if value is None:
        return result
    if not isinstance(value, Mapping):
        c.problem("actions", _found(value), "a mapping of action node ID -> {frames: [...]}")
        return result
    for name, body in value.items():
        key = _path("actions", name)
        if not isinstance(name, str) or not (name.isascii() and name.isidentifier()):
            c.problem(key, _found(name), "an action node ID (letters, digits, underscores)")
            continue
        if name in RESERVED_NODE_IDS:  # its frames are still checked below
            c.problem(key, "the ID of a built-in node type", "a new action name")
        result[name] = ActionConfig(name=name)  # with a problem in its body, still a node ID the tree may use
        if body is not None and c.mapping(body, key, ("frames", "role")):
            role = c.choice(body, "role", key, ("task", "recovery", "auto"), "auto")
            result[name] = ActionConfig(name=name, frames=frames(c, m, body, "frames", key), role=role)
    return result


def state(c: Checks, value: Any) -> StateConfig:
    value = c.section(value, "state", ("file", "on_corrupt", "save_period"))
    if value is None:
        return StateConfig()
    file = c.file_path(value["file"], "state.file") if value.get("file") is not None else None
    return StateConfig(file=file, on_corrupt=c.choice(value, "on_corrupt", "state", ("hot", "cold"), "hot"),
                       save_period_s=c.seconds(value, "save_period", "state", 5.0))


def frame_value(c: Checks, m: Messages, message: Any, sig_name: Any, value: Any, key: str) -> Any:
    """One ``signals:`` value: a number, or a choice name of a signal with VAL_ choices."""
    sig = m.signal(message, sig_name, key)
    if sig is None:
        return None
    if isinstance(value, str):
        return choice_value(c, sig, value, key)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        c.problem(key, _found(value), f"a number for {sig.name}")
        return None
    lo, hi = sig.minimum, sig.maximum
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        rng = f"[{'-inf' if lo is None else f'{lo:g}'}, {'inf' if hi is None else f'{hi:g}'}]"
        c.problem(key, _shown(value), f"a value of {sig.name} within its DBC range {rng}")
        return None
    return value if exact(c, sig, value, key) else None


def choice_value(c: Checks, sig: Any, name: str, key: str) -> int | float | None:
    """The value of the VAL_ choice ``name`` of ``sig``; None after a problem naming the choices."""
    choices = _choices(sig)
    if name in choices:
        return choices[name]
    expected = f"a number or a choice of {sig.name}" if choices else f"a number for {sig.name}"
    c.problem(key, _shown(name), expected + (_closest(name, choices) if choices else ""))
    return None


def exact(c: Checks, sig: Any, value: float, key: str) -> bool:
    """Whether ``value`` encodes exactly (a VAL_ choice, or a whole raw value): cantools rounds silently."""
    raw = _whole_raw(sig, value)
    if sig.choices:
        if raw is not None and raw in sig.choices:
            return True
        listed = ", ".join(f"{name} ({number})" for name, number in _choices(sig).items())
        c.problem(key, _shown(value), f"one of the choices of {sig.name}: {listed}")
        return False
    if sig.is_float or raw is not None:
        return True
    steps = f"steps of {sig.scale:g}" + (f" from {sig.offset:g}" if sig.offset else "")
    c.problem(key, _shown(value), f"a whole raw value: {steps}")
    return False


def frame(c: Checks, m: Messages, value: Any, key: str) -> FrameSpec | None:
    if not isinstance(value, Mapping):
        c.problem(key, _found(value), "a frame: {message, signals, bus} or {id, data, bus, extended}")
        return None
    if "canopen" in value:
        if m.canopen is None:
            c.problem(_path(key, "canopen"), _found(value["canopen"]), "a drive of canopen: (none configured)")
            return None
        return m.canopen.frame(value, key)
    if "message" in value:
        return _dbc_frame(c, m, value, key)
    if "id" in value:
        return _raw_frame(c, value, key)
    c.problem(key, "a mapping without 'message' or 'id'", "a frame: {message, signals} or {id, data}")
    return None


def _dbc_frame(c: Checks, m: Messages, value: Mapping[str, Any], key: str) -> FrameSpec | None:
    """A frame of a DBC message: ``{message, signals, bus}`` (unset signals at their initial values)."""
    c.mapping(value, key, ("message", "signals", "bus"), ("message",))
    bus = c.bus(value, key)
    msg = m.message(value, key)
    signals = value.get("signals")
    signals = {} if signals is None else signals
    if not isinstance(signals, Mapping):
        c.problem(_path(key, "signals"), _found(signals), "a mapping of signal name -> value")
        return None
    if msg is None:
        return None
    ok = _unsound_left_out(c, m, msg, signals, key)
    values = {name: frame_value(c, m, msg, name, v, f"{key}.signals.{name}") for name, v in signals.items()}
    if not ok or None in values.values():
        return None
    data: dict[str, Any] = {**{s.name: _initial(s) for s in msg.signals}, **values}
    try:
        payload = msg.encode(data, scaling=True, padding=False, strict=True)
    except Exception as exc:  # cantools EncodeError / ValueError / KeyError
        given = ", ".join(f"{k}={v!r}" for k, v in signals.items()) or "no signals"
        c.problem(_path(key, "signals"), f"{given}, which does not encode ({exc})",
                  f"values within the ranges of {msg.name}'s signals")
        return None
    return FrameSpec(bus, msg.frame_id, bytes(payload), is_extended_id=bool(msg.is_extended_frame),
                     is_fd=bool(msg.is_fd), label=msg.name)


def _unsound_left_out(c: Checks, m: Messages, msg: Any, given: Mapping[str, Any], key: str) -> bool:
    """Whether each signal the DBC gets wrong that a frame leaves out (so sends as 0) is 0 at its initial value."""
    ok = True
    for s in m.dropped(msg.name):
        if s.name in given:
            continue  # named in signals: frame_value reports it
        initial = _initial(s)
        if _whole_raw(s, initial) == 0:
            continue
        why = "; ".join(p.text for p in m.involved(msg.name, s.name))
        c.problem(_path(key, "message"), f"{msg.name}, whose signal {s.name} the frame would send at its "
                  f"initial value {initial:g} but the DBC gets it wrong ({why})",
                  "a message whose signals the DBC gets wrong are 0 when left out, or a raw frame {id, data}")
        ok = False
    return ok


def _raw_frame(c: Checks, value: Mapping[str, Any], key: str) -> FrameSpec | None:
    """A raw frame: ``{id, data, bus, extended, fd}``."""
    c.mapping(value, key, ("id", "data", "bus", "extended", "fd"), ("id",))
    bus = c.bus(value, key)
    raw_id = value["id"]
    if isinstance(raw_id, str):
        try:
            raw_id = int(raw_id, 0)
        except ValueError:
            c.problem(_path(key, "id"), _shown(raw_id), "a frame id (an int or '0x...')")
            return None
    if isinstance(raw_id, bool) or not isinstance(raw_id, int) or not 0 <= raw_id <= 0x1FFFFFFF:
        c.problem(_path(key, "id"), _found(raw_id), "a frame id 0..0x1FFFFFFF")
        return None
    extended = c.choice(value, "extended", key, (True, False), raw_id > 0x7FF)
    if not extended and raw_id > 0x7FF:
        c.problem(_path(key, "id"), f"0x{raw_id:X}", "a standard frame id 0..0x7FF (or extended: true)")
        return None
    fd = c.choice(value, "fd", key, (True, False), False)
    payload_b = _raw_data(c, value.get("data", ""), _path(key, "data"), fd)
    if payload_b is None:
        return None
    label = f"0x{raw_id:08X}" if extended else f"0x{raw_id:03X}"
    return FrameSpec(bus, raw_id, payload_b, is_extended_id=extended, is_fd=fd, label=label)


def _raw_data(c: Checks, value: Any, key: str, fd: bool) -> bytes | None:
    value = "" if value is None else value
    try:
        if isinstance(value, str):
            data = bytes.fromhex(value.replace(" ", "").replace(":", ""))
        elif isinstance(value, list) and all(isinstance(b, int) and not isinstance(b, bool) for b in value):
            data = bytes(value)
        else:
            raise ValueError
    except ValueError:
        c.problem(key, _found(value), "hex bytes ('00 ff') or a list of byte values 0..255")
        return None
    if (fd and len(data) not in _FD_LENGTHS) or (not fd and len(data) > 8):
        what = "a CAN FD length (0..8, 12, 16, 20, 24, 32, 48, 64)" if fd else "at most 8 bytes (fd: true for more)"
        c.problem(key, f"{len(data)} bytes", what)
        return None
    return data


def frames(c: Checks, m: Messages, mapping: Mapping[str, Any], name: str, key: str) -> tuple[FrameSpec, ...]:
    """The frames of ``mapping[name]`` (a list; left out or null: none), each problem recorded."""
    value = mapping.get(name)
    key = _path(key, name)
    if value is None:
        return ()
    if not isinstance(value, list):
        c.problem(key, _found(value), "a list of frames")
        return ()
    out = [frame(c, m, item, f"{key}[{i}]") for i, item in enumerate(value)]
    return tuple(f for f in out if f is not None)


def _initial(signal: Any) -> Any:
    """The value a signal left out of ``signals:`` takes: its DBC initial value, else 0 (or its minimum)."""
    initial = getattr(signal, "initial", None)
    if initial is not None:
        return initial
    if signal.minimum is not None and signal.minimum > 0:
        return signal.minimum
    return 0


def _whole_raw(signal: Any, value: float) -> int | None:
    """The raw value ``(value - offset) / scale`` when it is a whole number (within rounding), else None."""
    if not signal.scale:
        return None
    raw = (value - signal.offset) / signal.scale
    nearest = round(raw)
    return nearest if abs(raw - nearest) <= 1e-9 * max(1.0, abs(raw)) else None


def _choices(signal: Any) -> dict[str, int | float]:
    """A signal's VAL_ choices as ``name -> physical value`` (an int when it is whole)."""
    values = {str(name): int(raw) * signal.scale + signal.offset for raw, name in (signal.choices or {}).items()}
    return {name: int(v) if float(v).is_integer() else v for name, v in values.items()}
