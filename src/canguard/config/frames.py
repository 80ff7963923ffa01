"""Frames canguard sends (``actions:``, ``task:``, ``stop:``): encoded once, checked against the DBC."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from canguard.config.schema import FrameSpec
from canguard.config.sources import _Sources
from canguard.config.yamlsrc import _FD_LENGTHS, _closest, _found, _path, _shown


class _Frames(_Sources):
    """Frame specs: by message and signals, or raw id and data (classic or FD)."""

    def frame_value(self, message: Any, sig_name: Any, value: Any, key: str) -> Any:
        """One ``signals:`` value: a number, or a choice name of a signal with VAL_ choices."""
        sig = self.signal(message, sig_name, key)
        if sig is None:
            return None
        if isinstance(value, str):
            return self.choice_value(sig, value, key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            self.problem(key, _found(value), f"a number for {sig.name}")
            return None
        lo, hi = sig.minimum, sig.maximum
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            rng = f"[{'-inf' if lo is None else f'{lo:g}'}, {'inf' if hi is None else f'{hi:g}'}]"
            self.problem(key, _shown(value), f"a value of {sig.name} within its DBC range {rng}")
            return None
        return value if self.exact(sig, value, key) else None

    def choice_value(self, sig: Any, name: str, key: str) -> int | float | None:
        """The value of the VAL_ choice ``name`` of ``sig``; None after a problem naming the choices."""
        choices = _choices(sig)
        if name in choices:
            return choices[name]
        expected = f"a number or a choice of {sig.name}" if choices else f"a number for {sig.name}"
        self.problem(key, _shown(name), expected + (_closest(name, choices) if choices else ""))
        return None

    def exact(self, sig: Any, value: float, key: str) -> bool:
        """Whether ``value`` encodes exactly (a VAL_ choice, or a whole raw value): cantools rounds silently."""
        raw = _whole_raw(sig, value)
        if sig.choices:
            if raw is not None and raw in sig.choices:
                return True
            listed = ", ".join(f"{name} ({number})" for name, number in _choices(sig).items())
            self.problem(key, _shown(value), f"one of the choices of {sig.name}: {listed}")
            return False
        if sig.is_float or raw is not None:
            return True
        steps = f"steps of {sig.scale:g}" + (f" from {sig.offset:g}" if sig.offset else "")
        self.problem(key, _shown(value), f"a whole raw value: {steps}")
        return False

    def frame(self, value: Any, key: str) -> FrameSpec | None:
        if not isinstance(value, Mapping):
            self.problem(key, _found(value), "a frame: {message, signals, bus} or {id, data, bus, extended}")
            return None
        if "canopen" in value:
            if self.canopen is None:
                self.problem(_path(key, "canopen"), _found(value["canopen"]), "a drive of canopen: (none configured)")
                return None
            return self.canopen.frame(value, key)
        if "message" in value:
            return self._dbc_frame(value, key)
        if "id" in value:
            return self._raw_frame(value, key)
        self.problem(key, "a mapping without 'message' or 'id'", "a frame: {message, signals} or {id, data}")
        return None

    def _dbc_frame(self, value: Mapping[str, Any], key: str) -> FrameSpec | None:
        """A frame of a DBC message: ``{message, signals, bus}`` (unset signals at their initial values)."""
        self.mapping(value, key, ("message", "signals", "bus"), ("message",))
        bus = self.bus(value.get("bus"), _path(key, "bus"))
        msg = self.message(value["message"], _path(key, "message"))
        signals = value.get("signals")
        signals = {} if signals is None else signals
        if not isinstance(signals, Mapping):
            self.problem(_path(key, "signals"), _found(signals), "a mapping of signal name -> value")
            return None
        if msg is None:
            return None
        data: dict[str, Any] = {s.name: _initial(s) for s in msg.signals}
        ok = self.unsound_left_out(msg, signals, key)
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
            self.problem(_path(key, "signals"), f"{given}, which does not encode ({exc})",
                         f"values within the ranges of {msg.name}'s signals")
            return None
        return FrameSpec(bus, msg.frame_id, bytes(payload), is_extended_id=bool(msg.is_extended_frame),
                         is_fd=bool(msg.is_fd), label=msg.name)

    def unsound_left_out(self, msg: Any, given: Mapping[str, Any], key: str) -> bool:
        """Whether the signals the DBC gets wrong that a frame leaves out (sent as 0) are 0 at their initial values;
        a problem naming each that is not."""
        ok = True
        for s in self.dbc_checks.dropped(msg.name):
            if s.name in given:
                continue  # named in signals: frame_value reports it
            initial = _initial(s)
            if _whole_raw(s, initial) == 0:
                continue
            why = "; ".join(p.text for p in self.dbc_checks.involved(msg.name, s.name))
            self.problem(_path(key, "message"), f"{msg.name}, whose signal {s.name} the frame would send at its "
                         f"initial value {initial:g} but the DBC gets it wrong ({why})",
                         "a message whose signals the DBC gets wrong are 0 when left out, or a raw frame {id, data}")
            ok = False
        return ok

    def _raw_frame(self, value: Mapping[str, Any], key: str) -> FrameSpec | None:
        """A raw frame: ``{id, data, bus, extended, fd}``."""
        self.mapping(value, key, ("id", "data", "bus", "extended", "fd"), ("id",))
        bus = self.bus(value.get("bus"), _path(key, "bus"))
        raw_id = value["id"]
        if isinstance(raw_id, str):
            try:
                raw_id = int(raw_id, 0)
            except ValueError:
                self.problem(_path(key, "id"), _shown(raw_id), "a frame id (an int or '0x...')")
                return None
        if isinstance(raw_id, bool) or not isinstance(raw_id, int) or not 0 <= raw_id <= 0x1FFFFFFF:
            self.problem(_path(key, "id"), _found(raw_id), "a frame id 0..0x1FFFFFFF")
            return None
        extended = value.get("extended", raw_id > 0x7FF)
        if not isinstance(extended, bool):
            self.problem(_path(key, "extended"), _found(extended), "true or false")
            return None
        if not extended and raw_id > 0x7FF:
            self.problem(_path(key, "id"), f"0x{raw_id:X}", "a standard frame id 0..0x7FF (or extended: true)")
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

    def raw_data(self, value: Any, key: str, fd: bool) -> bytes | None:
        value = "" if value is None else value
        try:
            if isinstance(value, str):
                data = bytes.fromhex(value.replace(" ", "").replace(":", ""))
            elif isinstance(value, list) and all(isinstance(b, int) and not isinstance(b, bool) for b in value):
                data = bytes(value)
            else:
                raise ValueError
        except ValueError:
            self.problem(key, _found(value), "hex bytes ('00 ff') or a list of byte values 0..255")
            return None
        if (fd and len(data) not in _FD_LENGTHS) or (not fd and len(data) > 8):
            what = "a CAN FD length (0..8, 12, 16, 20, 24, 32, 48, 64)" if fd else "at most 8 bytes (fd: true for more)"
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
