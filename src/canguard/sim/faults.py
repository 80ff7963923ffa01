"""Fault injection on a python-can bus: bus-off, failing sends, error frames, drops, delays.

:class:`FaultyBus` wraps any python-can bus and misbehaves as a shared :class:`Faults` says, the way real
interfaces do; :func:`faulty_opener` plugs it into :class:`canguard.io.bus.BusReader` (``opener=``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can

from canguard.config.schema import BusConfig

CAN_ERR_CRTL = 0x20000004
"""The id of an error frame reporting a controller problem (``CAN_ERR_FLAG | CAN_ERR_CRTL``)."""


@dataclass
class Faults:
    """What the wrapped buses do wrong right now; tests flip these while the daemon runs."""

    bus_off: bool = False
    """Receive and send raise CanOperationError; opening the bus again fails too."""
    fail_sends: int = 0
    """Sends that raise (a full transmit queue); -1: every send until set back to 0."""
    drop_ids: set[int] = field(default_factory=set)
    """Frames with these ids are lost on receive."""
    delay_s: float = 0.0
    """Each received frame is handed over this late."""
    error_frames: int = 0
    """Error frames still to deliver on receive (before the next data frame)."""
    refused_sends: int = 0
    """Sends that were refused (counted here, for the tests)."""
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def take_send_failure(self) -> bool:
        """True when this send must fail."""
        with self.lock:
            if self.bus_off or self.fail_sends == -1:
                self.refused_sends += 1
                return True
            if self.fail_sends > 0:
                self.fail_sends -= 1
                self.refused_sends += 1
                return True
            return False

    def take_error_frame(self) -> bool:
        with self.lock:
            if self.error_frames > 0:
                self.error_frames -= 1
                return True
            return False


class FaultyBus(can.BusABC):
    """A python-can bus that passes everything to ``inner`` except what :class:`Faults` says."""

    def __init__(self, inner: can.BusABC, faults: Faults, **kwargs: Any) -> None:
        self.inner = inner
        self.faults = faults
        self.channel_info = f"faulty({inner.channel_info})"
        super().__init__(channel=str(getattr(inner, "channel", "faulty")), **kwargs)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        f = self.faults
        if f.bus_off:
            raise can.CanOperationError("bus-off (injected)")
        if f.take_error_frame():
            return can.Message(arbitration_id=CAN_ERR_CRTL, is_error_frame=True, is_extended_id=True,
                               data=bytes([0, 0x04, 0, 0, 0, 0, 0, 0]), timestamp=time.time()), False
        msg = self.inner.recv(timeout)
        if msg is None:
            return None, False
        if msg.arbitration_id in f.drop_ids:
            return None, False
        if f.delay_s > 0:
            time.sleep(f.delay_s)
        return msg, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.faults.take_send_failure():
            raise can.CanOperationError("transmit refused (injected: bus-off or full TX queue)")
        self.inner.send(msg, timeout)

    def shutdown(self) -> None:
        self.inner.shutdown()
        super().shutdown()


def faulty_opener(faults: Faults, open_inner: Callable[[BusConfig], can.BusABC] | None = None
                  ) -> Callable[[BusConfig], can.BusABC]:
    """An ``opener`` for :class:`~canguard.io.bus.BusReader`: each bus wrapped; no reopen while bus-off."""

    def opener(cfg: BusConfig) -> can.BusABC:
        if faults.bus_off:
            raise can.CanOperationError(f"bus {cfg.name}: interface down (injected bus-off)")
        inner = open_inner(cfg) if open_inner is not None else can.Bus(**dict(cfg.kwargs))
        return FaultyBus(inner, faults)

    return opener
