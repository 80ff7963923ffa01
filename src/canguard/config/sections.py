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
"""Interfaces every python-can canguard supports has built in: accepted without importing python-can (which
``canguard replay`` of a candump log otherwise never does)."""


def _valid_interfaces() -> frozenset[str]:
    """python-can's interface names (plugins included), imported when a config names another."""
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
                self.problem(key, _found(kwargs), "a mapping of python-can Bus arguments (interface, channel, ...)")
                continue
            for k in kwargs:
                if not isinstance(k, str):
                    self.problem(_path(key, k), _found(k), "a python-can Bus argument name")
            interface = kwargs.get("interface")
            if interface is None:
                self.problem(_path(key, "interface"), "nothing",
                             "a python-can interface name (socketcan, virtual, ...)")
            elif not isinstance(interface, str) or (
                    interface not in _BUILT_IN_INTERFACES and interface not in _valid_interfaces()):
                self.problem(_path(key, "interface"), _found(interface),
                             "a python-can interface" + _closest(interface, _valid_interfaces()))
            only = kwargs.get("filter", True)
            if not isinstance(only, bool):
                self.problem(_path(key, "filter"), _found(only),
                             "true (receive only the frames the config reads) or false (every frame)")
            args = {k: v for k, v in kwargs.items() if k != "filter"}
            result[name] = BusConfig(name=name, kwargs=MappingProxyType(args), filter=only is not False)
        self.bus_names = tuple(result)
        return result

    def tree(self, value: Any) -> TreeConfig | None:
        value = self.section(value, "tree", ("file", "main", "tick_hz"), ("file",))
        if value is None:
            return None
        file = self.file_path(value["file"], "tree.file") if "file" in value else None
        main = value.get("main")
        if main is not None and not (isinstance(main, str) and main):
            self.problem("tree.main", _found(main), "the ID of a BehaviorTree in the file")
            main = None
        tick_hz = self.seconds(value, "tick_hz", "tree", 100.0)
        if file is None:
            return None
        if not file.is_file():
            what = "a directory" if file.is_dir() else "no such file"
            self.problem("tree.file", f"{str(file)!r} ({what})", "a BehaviorTree.CPP XML file")
        return TreeConfig(file=file, main=main, tick_hz=tick_hz)

    def task(self, value: Any) -> TaskConfig:
        value = self.section(value, "task", ("period", "frames"))
        if value is None:
            return TaskConfig()
        return TaskConfig(period_s=self.seconds(value, "period", "task", 0.02),
                          frames=self.frames(value.get("frames"), "task.frames"))

    def confirm(self, value: Any) -> StopConfirm | None:
        key = "stop.confirm"
        value = self.section(value, key, ("source", "signal", *_CONFIRM_OPS, "deadline"), ("source", "deadline"))
        if value is None:
            return None
        ops = [k for k in _CONFIRM_OPS if k in value]
        if len(ops) != 1:
            self.problem(key, f"{len(ops)} of below/above/equals", "exactly one of below, above, equals")
        deadline = self.seconds(value, "deadline", key, 0.0)
        role = value.get("signal", "current")
        source = value.get("source")
        src = self.sources.get(source) if isinstance(source, str) else None
        # A source already reported broken (or whose DBC did not load) adds no follow-on error here.
        follow_on = (isinstance(source, str) and source in self._broken_sources) or not (
            self.messages_ok and self._sources_ok)
        if "source" in value and src is None and not follow_on:
            self.problem(_path(key, "source"), _found(source), "a configured source" + _closest(source, self.sources))
        ref = src.signal(role) if src is not None and isinstance(role, str) else None
        if src is not None and ref is None and not follow_on:
            roles = [s.role for s in src.signals]
            self.problem(_path(key, "signal"), _found(role), f"a signal role of {source}" + _closest(role, roles))
        if len(ops) != 1 or deadline <= 0:
            return None
        op_name = ops[0]
        raw = value[op_name]
        sig = self._by_name[ref.message].get_signal_by_name(ref.signal) if ref is not None else None
        number: float | None = None
        if op_name == "equals" and isinstance(raw, str):
            choice = self.choice_value(sig, raw, _path(key, op_name)) if sig is not None else None
            number = None if choice is None else float(choice)  # no sig: a source or signal already reported
        else:
            number = self.number(raw, _path(key, op_name))
            if op_name == "equals" and number is not None and sig is not None:
                # equals compares decoded values, which only ever take what the signal encodes.
                number = number if self.exact(sig, number, _path(key, op_name)) else None
        if number is None or src is None or ref is None:
            return None
        return StopConfirm(source=src.name, signal=ref.role, op=_CONFIRM_OPS[op_name], value=number,
                           deadline_s=deadline)

    def stop(self, value: Any) -> StopConfig:
        value = self.section(value, "stop", ("repeat", "frames", "confirm", "escalate", "min_stop", "release"))
        if value is None:
            return StopConfig()
        min_stop = value.get("min_stop", 0.0)
        if isinstance(min_stop, bool) or not isinstance(min_stop, (int, float)) or not 0 <= min_stop < math.inf:
            self.problem("stop.min_stop", _found(min_stop), "a number >= 0 in seconds")
            min_stop = 0.0
        release = self.choice(value, "release", "stop", ("auto", "manual"), "auto")
        return StopConfig(self.seconds(value, "repeat", "stop", 0.05), self.frames(value.get("frames"), "stop.frames"),
                          self.confirm(value.get("confirm")), self.frames(value.get("escalate"), "stop.escalate"),
                          float(min_stop), release)

    def actions(self, value: Any) -> dict[str, ActionConfig]:
        result: dict[str, ActionConfig] = {}
        if value is None:
            return result
        if not isinstance(value, Mapping):
            self.problem("actions", _found(value), "a mapping of action node ID -> {frames: [...]}")
            return result
        for name, body in value.items():
            key = _path("actions", name)
            if not isinstance(name, str) or not _IDENT.fullmatch(name):
                self.problem(key, _found(name), "an action node ID (letters, digits, underscores)")
                continue
            if name in RESERVED_NODE_IDS:  # its frames are still checked below
                self.problem(key, "the ID of a built-in node type", "a new action name")
            if body is None:
                result[name] = ActionConfig(name=name)
            elif self.mapping(body, key, ("frames", "role")):
                role = self.choice(body, "role", key, ("task", "recovery", "auto"), "auto")
                result[name] = ActionConfig(name=name, frames=self.frames(body.get("frames"), _path(key, "frames")),
                                            role=role)
        return result

    def state(self, value: Any) -> StateConfig:
        value = self.section(value, "state", ("file", "on_corrupt", "save_period"))
        if value is None:
            return StateConfig()
        file = self.file_path(value["file"], "state.file") if value.get("file") is not None else None
        on_corrupt = self.choice(value, "on_corrupt", "state", ("hot", "cold"), "hot")
        save_period_s = self.seconds(value, "save_period", "state", 5.0)
        return StateConfig(file=file, on_corrupt=on_corrupt, save_period_s=save_period_s)

    def monitor(self, value: Any) -> MonitorConfig:
        value = self.section(value, "monitor", ("http", "token", "groot2"))
        if value is None:
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
