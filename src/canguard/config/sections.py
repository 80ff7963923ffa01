"""The sections around the sources: buses, tree, task, stop, actions, state."""

from __future__ import annotations

import math
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from canguard.config.frames import _Frames
from canguard.config.monitor import needs_token, parse_address
from canguard.config.node_ids import RESERVED_NODE_IDS
from canguard.config.schema import (
    ActionConfig,
    BusConfig,
    MonitorConfig,
    SignalRef,
    StateConfig,
    StopConfig,
    StopConfirm,
    TaskConfig,
    TreeConfig,
)
from canguard.config.sources import _IDENT
from canguard.config.yamlsrc import _CONFIRM_OPS, _closest, _found, _path

_BUILT_IN_INTERFACES = frozenset({
    "socketcan", "socketcand", "virtual", "udp_multicast", "slcan", "serial", "gs_usb", "pcan", "kvaser",
    "vector", "ixxat",
})
"""Interfaces every python-can canguard supports (>= 4.3) has built in (``tests/test_config.py`` holds
them to the installed python-can's): a config naming one of them is accepted without importing python-can,
which ``canguard replay`` of a candump log otherwise never does (~35 ms of its start, ~0.35 s with ``asammdf``)."""


def _valid_interfaces() -> frozenset[str]:
    """python-can's interface names (plugins included), imported when a config names another (not at import)."""
    import can.interfaces

    names: frozenset[str] = can.interfaces.VALID_INTERFACES
    return names


class _Sections(_Frames):
    """``buses:``, ``tree:``, ``task:``, ``stop:``, ``actions:``, ``state:``, ``monitor:``."""

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
            elif not isinstance(interface, str) or (
                    interface not in _BUILT_IN_INTERFACES and interface not in _valid_interfaces()):
                self.problem(
                    _path(key, "interface"),
                    _found(interface),
                    "a python-can interface" + _closest(interface, _valid_interfaces()),
                )
            only = kwargs.get("filter", True)
            if not isinstance(only, bool):
                self.problem(_path(key, "filter"), _found(only),
                             "true (receive only the frames the config reads) or false (every frame)")
            args = {k: v for k, v in kwargs.items() if k != "filter"}
            result[name] = BusConfig(name=name, kwargs=MappingProxyType(args), filter=only is not False)
        self.bus_names = tuple(result)
        return result

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
            choice = self.choice(sig, raw, _path(key, op_name))
            if choice is None:
                return None
            number = float(choice)
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

    def monitor(self, value: Any) -> MonitorConfig:
        if value is None:
            return MonitorConfig()
        if not self.mapping(value, "monitor", ("http", "token", "groot2")):
            return MonitorConfig()
        found: dict[str, str | None] = {"http": None, "groot2": None}
        for key, span in (("http", 1), ("groot2", 2)):
            if value.get(key) is None:
                continue
            address = parse_address(value[key], port_span=span)
            if isinstance(address, str):
                self.problem(f"monitor.{key}", _found(value[key]), address)
            else:
                found[key] = str(address)
        token = value.get("token")
        if token is not None and not (isinstance(token, str) and token.strip()):
            self.problem("monitor.token", _found(token), "a bearer token (a non-empty string)")
            token = None
        http = parse_address(found["http"]) if found["http"] else None
        if http is not None and not isinstance(http, str) and needs_token(http, token) and "token" not in value:
            self.problem("monitor.token", "nothing",
                         f"a bearer token: monitor.http {http} is not loopback, so the page would be open to the "
                         "network (or bind monitor.http to 127.0.0.1)")
        return MonitorConfig(http=found["http"], token=token, groot2=found["groot2"])
