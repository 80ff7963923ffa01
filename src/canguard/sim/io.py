"""Where the simulated robot's frames go: a candump -L file, or a python-can bus.

:func:`run_on_bus` is the one place the simulator reads the wall clock (to pace and to map received frames).
"""

from __future__ import annotations

import gzip
import io
import logging
import threading
import time
from collections.abc import Callable
from os import PathLike
from typing import Any

import can

from canguard.io.block import frame_from_message
from canguard.io.candump import write_candump
from canguard.io.frame import Frame
from canguard.sim.robot import SimRobot

log = logging.getLogger(__name__)

_SLEEP_MIN_S = 0.001  # frames due closer than this are sent at once: batching beats oversleeping


def write_log(path: str | PathLike[str], duration_s: float, **robot_kwargs: Any) -> int:
    """Simulate ``duration_s`` seconds of ``SimRobot(**robot_kwargs)`` into a candump -L file (``.gz``: gzip'd with a
    zero mtime, so the bytes depend on content only); the frames written."""
    frames = SimRobot(**robot_kwargs).frames(duration_s)  # the replay reader's own writer: read_log gives them back
    if str(path).endswith(".gz"):
        with (open(path, "wb") as raw, gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0) as gz,
              io.TextIOWrapper(gz, encoding="ascii", newline="\n") as out):
            return write_candump(frames, out)
    with open(path, "w", encoding="ascii", newline="\n") as out:
        return write_candump(frames, out)


def to_message(frame: Frame) -> can.Message:
    """The python-can message of a frame (error frames keep their class bits, without CAN_ERR_FLAG)."""
    return can.Message(arbitration_id=frame.arbitration_id, is_extended_id=frame.is_extended_id,
                       is_error_frame=frame.is_error_frame, is_remote_frame=frame.is_remote_frame, is_fd=frame.is_fd,
                       bitrate_switch=frame.bitrate_switch, data=frame.data)


def _pace(bus: can.BusABC, due: float, answer: Callable[[can.Message | None], None],
          stop_event: threading.Event | None) -> None:
    """Wait until the monotonic clock reaches ``due``, answering the bus' frames meanwhile."""
    while True:
        wait = due - time.monotonic()
        if wait < _SLEEP_MIN_S:
            answer(bus.recv(0))
            return
        answer(bus.recv(min(wait, 0.05)))
        if stop_event is not None and stop_event.is_set():
            return


def run_on_bus(bus: can.BusABC, duration_s: float, *, stop_event: threading.Event | None = None,
               robot: SimRobot | None = None, **robot_kwargs: Any) -> int:
    """Run ``robot`` (or ``SimRobot(**robot_kwargs)``) on ``bus`` for ``duration_s`` seconds, answering the bus'
    frames; the frames sent. Error frames go only on software buses; a refused send is logged and skipped."""
    if robot is None:
        robot = SimRobot(**robot_kwargs)
    elif robot_kwargs:
        raise TypeError("run_on_bus: pass either robot or SimRobot arguments, not both")
    send_errors = type(bus).__name__ in {"VirtualBus", "UdpMulticastBus"}  # controllers make error frames
    sim0 = robot.now
    wall0 = time.monotonic()
    sent = failed = 0

    def answer(msg: can.Message | None) -> None:
        while msg is not None:  # at the simulated time of its arrival
            channel = str(msg.channel) if msg.channel is not None else robot.channel
            robot.receive(frame_from_message(msg, channel)._replace(t=sim0 + (time.monotonic() - wall0)))
            msg = bus.recv(0)

    for frame in robot.frames(duration_s):
        if stop_event is not None and stop_event.is_set():
            break
        _pace(bus, wall0 + (frame.t - sim0), answer, stop_event)
        if frame.is_error_frame and not send_errors:
            continue
        try:
            bus.send(to_message(frame))
            sent += 1
        except can.CanError as exc:
            failed += 1
            if failed == 1 or failed % 1000 == 0:
                log.warning("simulator: %d frame(s) not sent: %s", failed, exc)
    return sent
