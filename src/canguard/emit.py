"""Frames out: the task gate (enable / heartbeat vs stop) and the frame sinks.

The :class:`TaskGate` turns the tree's decisions into frames:

- ``run()`` (ExecuteTask ticked): the task runs; task frames go out at once on
  the first run (or on resume after a stop) and then every ``task.period``.
- ``halt()`` (ExecuteTask halted) or ``stop()`` (the root returned FAILURE):
  stop frames go out at once, then every ``stop.repeat`` while the tree keeps
  failing; task frames resume only when ExecuteTask runs again.
- Optional confirmation: after a stop, ``stop.confirm`` (a source signal and a
  condition) must hold within its deadline, or ``stop.escalate`` frames go out
  and an ``escalate`` event is recorded.

Sinks never block the loop: :class:`BusSink` hands frames to python-can with
``timeout=0`` and counts failures, :class:`LogSink` keeps them as candump-ready
:class:`~canguard.data.Frame` objects for ``replay --emit``.
"""

from __future__ import annotations

import logging
import math
import operator
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TextIO

from .config import BusConfig, FrameSpec, StopConfig, TaskConfig
from .context import FrameSink
from .data import Frame
from .protect.staleness import SourceHealth

log = logging.getLogger("canguard.emit")

_OPS: dict[str, Callable[[float, float], bool]] = {
    "<": operator.lt,
    "<=": operator.le,
    ">": operator.gt,
    ">=": operator.ge,
    "==": operator.eq,
    "!=": operator.ne,
}

EventFn = Callable[..., None]


class TaskGate:
    """Decides which frames go out: the task's while it runs, the stop frames while it is stopped."""

    IDLE = "idle"
    RUNNING = "running"
    STOPPED = "stopped"

    def __init__(
        self,
        task: TaskConfig,
        stop: StopConfig,
        sink: FrameSink,
        health: Mapping[str, SourceHealth] | None = None,
        on_event: EventFn | None = None,
    ) -> None:
        self.task_cfg = task
        self.stop_cfg = stop
        self.sink = sink
        self.health = health or {}
        self.on_event = on_event
        self.state = self.IDLE
        self.stop_since: float | None = None
        self.stop_reason = ""
        self.stopped_s = 0.0
        """Total time spent stopped (closed intervals only; see :meth:`stopped_total`)."""
        self.stops = 0
        self._next_task = math.inf
        self._next_stop = math.inf
        self._confirm_pending = False
        self._ran_this_tick = False
        self.inhibits: dict[str, str] = {}
        """Reasons the task may not run whatever the tree says (a bus down, a stale source), by key."""
        self.explain: Callable[[], str] | None = None
        """Says why the tree halted the task (the failing guards); set by the engine."""

    # -- driven by ExecuteTask -------------------------------------------------------------
    def run(self, node: str, now: float) -> None:
        """ExecuteTask was ticked: start (or resume) the task."""
        self._ran_this_tick = True
        if self.state == self.RUNNING or self.inhibits:
            return  # running already, or held stopped until every inhibit is released
        if self.state == self.STOPPED:
            self._end_stop(now, node)
        self.state = self.RUNNING
        self._send_task(now)

    def halt(self, node: str, now: float) -> None:
        """ExecuteTask was halted: stop the task at once."""
        if self.state == self.RUNNING:
            why = self.explain() if self.explain is not None else ""
            self.stop(now, reason=f"{node} halted" + (f" ({why})" if why else ""), node=node)

    # -- driven by the engine --------------------------------------------------------------
    def stop(self, now: float, reason: str, node: str = "") -> None:
        """Stop the task (idempotent): stop frames at once, then every ``stop.repeat``."""
        if self.state == self.STOPPED:
            return
        self.state = self.STOPPED
        self.stop_since = now
        self.stop_reason = reason
        self.stops += 1
        self._next_task = math.inf
        self._confirm_pending = self.stop_cfg.confirm is not None
        self._event("stop", now, node=node, reason=reason)
        self._send_stop(now)

    def inhibit(self, key: str, reason: str, now: float, node: str = "") -> None:
        """Hold the task stopped for ``key`` (stopping it now if it runs) until :meth:`release`."""
        self.inhibits[key] = reason
        if self.state == self.RUNNING:
            self.stop(now, reason=reason, node=node)

    def release(self, key: str) -> None:
        """Drop one inhibit; the task resumes when ExecuteTask next runs and no other inhibit is left."""
        self.inhibits.pop(key, None)

    def adopt(self, old: TaskGate) -> None:
        """Continue where ``old`` is (a config reload): running, stopped or idle, with its deadlines and counts."""
        self.state = old.state
        self.stop_since = old.stop_since
        self.stop_reason = old.stop_reason
        self.stopped_s = old.stopped_s
        self.stops = old.stops
        self.inhibits = dict(old.inhibits)
        self._next_task = old._next_task
        self._next_stop = old._next_stop
        self._confirm_pending = old._confirm_pending and self.stop_cfg.confirm is not None

    def resend_stop(self, now: float) -> None:
        """Send the stop frames again now if the task is stopped (the daemon's exit)."""
        if self.state == self.STOPPED:
            self._send_stop(now)

    def begin_tick(self) -> None:
        """Called before each tick: tracks whether ExecuteTask ran in it."""
        self._ran_this_tick = False

    def service(self, now: float) -> None:
        """After each tick and between ticks: periodic task / stop frames, stop confirmation."""
        if self.state == self.RUNNING and now >= self._next_task:
            self._send_task(now)
        elif self.state == self.STOPPED:
            if now >= self._next_stop:
                self._send_stop(now)
            if self._confirm_pending:
                self._check_confirm(now)

    def next_deadline(self) -> float:
        """The earliest time :meth:`service` has something to do (inf when nothing)."""
        if self.state == self.RUNNING:
            return self._next_task
        if self.state == self.STOPPED:
            nxt = self._next_stop
            if self._confirm_pending and self.stop_cfg.confirm is not None and self.stop_since is not None:
                nxt = min(nxt, self.stop_since + self.stop_cfg.confirm.deadline_s)
            return nxt
        return math.inf

    def skip_to(self, t: float) -> None:
        """After a gap in time (a stall, a gap in a log): periodic frames due before ``t`` are due at ``t``.

        The stop confirmation deadline is not moved: it is one deadline, not a period.
        """
        self._next_task = max(self._next_task, t)
        self._next_stop = max(self._next_stop, t)

    def stopped_total(self, now: float) -> float:
        """Seconds spent stopped so far, the open interval included."""
        extra = now - self.stop_since if self.state == self.STOPPED and self.stop_since is not None else 0.0
        return self.stopped_s + max(0.0, extra)

    # -- internals -----------------------------------------------------------------------
    def _end_stop(self, now: float, node: str) -> None:
        since = self.stop_since if self.stop_since is not None else now
        self.stopped_s += max(0.0, now - since)
        self._event("resume", now, node=node, reason=f"stopped for {now - since:.3f} s")
        self.stop_since = None
        self._next_stop = math.inf
        self._confirm_pending = False

    def _send_task(self, now: float) -> None:
        if self.task_cfg.frames:
            self.sink.send(self.task_cfg.frames, "task")
        # Schedule from the previous deadline when on time, so the period does not drift;
        # after a late service, restart from now rather than bursting to catch up.
        nxt = self._next_task + self.task_cfg.period_s
        self._next_task = nxt if math.isfinite(nxt) and nxt > now else now + self.task_cfg.period_s

    def _send_stop(self, now: float) -> None:
        if self.stop_cfg.frames:
            self.sink.send(self.stop_cfg.frames, "stop")
        self._next_stop = now + self.stop_cfg.repeat_s

    def _check_confirm(self, now: float) -> None:
        confirm = self.stop_cfg.confirm
        if confirm is None or self.stop_since is None:
            self._confirm_pending = False
            return
        health = self.health.get(confirm.source)
        value = health.value(confirm.signal) if health is not None else math.nan
        fresh = health is not None and not health.reason(now, confirm.signal)
        # Only a sample taken after the stop went out can say the drive obeyed it.
        last_t = health.last_t(confirm.signal) if health is not None else None
        after_stop = last_t is not None and last_t > self.stop_since
        # Ordering conditions (below / above) are on the magnitude: a drive still pushing -20 A
        # is not "below 1 A". Equality (an axis state) compares the value itself.
        measured = value if confirm.op in ("==", "!=") else abs(value)
        if fresh and after_stop and _OPS[confirm.op](measured, confirm.value):
            self._confirm_pending = False
            self._event(
                "confirmed", now, source=confirm.source, value=value, threshold=confirm.value,
                reason=f"{confirm.signal} {confirm.op} {confirm.value} after {now - self.stop_since:.3f} s",
            )
        elif now >= self.stop_since + confirm.deadline_s:  # next_deadline()'s own sum: (a + d) - a < d in floats
            self._confirm_pending = False
            if self.stop_cfg.escalate:
                self.sink.send(self.stop_cfg.escalate, "escalate")
            self._event(
                "escalate", now, source=confirm.source, value=value, threshold=confirm.value,
                reason=f"not confirmed within {confirm.deadline_s} s: {confirm.signal} {confirm.op} "
                f"{confirm.value} does not hold",
            )

    def _event(self, event: str, now: float, **fields: Any) -> None:
        if self.on_event is not None:
            self.on_event(event, now, **fields)


class LogSink:
    """Records sent frames: streamed to ``out`` as candump -L lines (``replay --emit``), kept, or counted.

    ``out`` given: each frame is written as one candump -L line at once
    (:func:`canguard.replay.format_candump_line`), so memory stays flat in the
    log's length. ``keep`` True: frames are also kept in :attr:`frames` (tests).
    Either way :attr:`sent` counts every frame.
    """

    def __init__(
        self, clock_now: Callable[[], float], buses: Mapping[str, BusConfig], *,
        out: TextIO | None = None, keep: bool = True,
    ) -> None:
        self._now = clock_now
        self._channel = {name: (b.channel or name) for name, b in buses.items()}
        self.out = out
        """Where each frame is written as a candump -L line as it is sent (None: not written)."""
        self.keep = keep
        """False: do not keep frames in memory (a replay stays flat in memory on long logs)."""
        self.sent = 0
        self.frames: list[Frame] = []
        self.origins: list[str] = []

    def send(self, frames: Sequence[FrameSpec], origin: str) -> None:
        """Count every frame; write it to ``out`` and / or keep it, at the current time."""
        self.sent += len(frames)
        out, keep = self.out, self.keep
        if out is None and not keep:
            return
        from .replay import format_candump_line

        t = self._now()
        for f in frames:
            frame = Frame(t, self._channel.get(f.bus, f.bus), f.arbitration_id, f.data, f.is_extended_id, f.is_fd)
            if out is not None:
                out.write(format_candump_line(frame) + "\n")
            if keep:
                self.frames.append(frame)
                self.origins.append(origin)


class BusSink:
    """Sends frames on live buses without ever blocking the loop; failures are logged and counted."""

    def __init__(self, send: Callable[[str, Any], bool], on_error: EventFn | None = None) -> None:
        import can  # only the live path needs python-can's Message

        self._message = can.Message
        self._send = send
        self.on_error = on_error
        self.sent = 0
        self.failed = 0

    def send(self, frames: Sequence[FrameSpec], origin: str) -> None:
        """Hand each frame to its bus with timeout 0; a full queue or an error is counted, never raised."""
        for f in frames:
            msg = self._message(
                arbitration_id=f.arbitration_id, data=f.data, is_extended_id=f.is_extended_id, is_fd=f.is_fd
            )
            if self._send(f.bus, msg):
                self.sent += 1
            else:
                self.failed += 1
                log.warning("could not send %s (%s) on bus %s", f.label, origin, f.bus)
                if self.on_error is not None:
                    self.on_error(f.bus)
