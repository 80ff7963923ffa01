"""Encoders for the simulator: one per DBC message, built once."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


class MessageEncoder:
    """Encodes one DBC message's physical signal values into frame bytes."""

    def __init__(self, message: Any) -> None:
        self.message = message
        self.frame_id: int = message.frame_id
        self.is_extended_id: bool = bool(message.is_extended_frame)
        self._defaults: dict[str, float] = {s.name: 0 for s in message.signals}
        self.by_start: tuple[str, ...] = tuple(s.name for s in sorted(message.signals, key=lambda s: s.start))
        """The signal names in start-bit order: what :meth:`pack` takes, positionally."""

    def encode(self, values: Mapping[str, float]) -> bytes:
        """Encode physical values (scaled, as in the DBC); missing ones are 0, unknown names are ignored."""
        return bytes(self.message.encode({**self._defaults, **values}, scaling=True, strict=False))

    def pack(self, *values: float) -> bytes:
        """Encode a value for each signal, in :attr:`by_start` order (the telemetry's setpoint then measured value)."""
        return bytes(self.message.encode(dict(zip(self.by_start, values, strict=True)), scaling=True, strict=False))
