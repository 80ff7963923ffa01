"""Frames out: the task gate (enable / heartbeat vs stop) and the frame sinks.

A stop's frames go out at once (before its reason is worked out or recorded), then every ``stop.repeat``;
the stop latches until :meth:`TaskGate._release_rule` ends it, at a tick's end. While stopped, task frames
are withheld, so in no tick do both task and stop frames go out. Sinks never block the loop.
"""

from __future__ import annotations

import logging
import math
import operator
import os
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, TextIO

from canguard.bt.context import FrameSink
from canguard.config.schema import BusConfig, FrameSpec, StopConfig, TaskConfig
from canguard.engine.ratelimit import RateLimit, held_note
from canguard.io.frame import Frame
from canguard.protect.staleness import SourceHealth

log = logging.getLogger(__name__)

_OPS: dict[str, Callable[[float, float], bool]] = {"<": operator.lt, "<=": operator.le, ">": operator.gt,
                                                   ">=": operator.ge, "==": operator.eq, "!=": operator.ne}

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
        self.stopped_s = 0.0  # closed intervals only (:meth:`stopped_total`)
        self.stops = 0
        self.next_task_t = math.inf  # when the task's periodic frames are next due
        self._next_stop = math.inf
        self.confirm_pending = False  # a stop waits for ``stop.confirm``
        self._ran_this_tick = False
        self.inhibits: dict[str, str] = {}  # why the task may not run whatever the tree says, by key
        self.explain: Callable[[], str] = str  # why the tree halted the task (the failing guards): the engine's
        self.tree_has_task = True
        """False when the tree holds no ExecuteTask and no task action: a tick without FAILURE asks for the task."""
        self._asked_by = ""
        self._reset_this_tick = False
        self._queued: list[tuple[str, Sequence[FrameSpec], Callable[[str], None] | None]] = []
        self.cause: tuple[str, str] | None = None  # (node, reason) holding the stop; None right after a stop
        self.halts_next: Callable[[], bool] | None = None
        """Says at a model's edge that the coming tick surely halts the running task (set by the engine)."""
        self._ahead = False

    # -- driven by ExecuteTask -------------------------------------------------------------
    def run(self, node: str, now: float) -> None:
        """ExecuteTask was ticked: the tree asks for the task (started or resumed at the tick's end)."""
        self._ran_this_tick = True
        if not self._asked_by:
            self._asked_by = node

    def action(
        self, node: str, role: str, frames: Sequence[FrameSpec], now: float,
        note: Callable[[str], None] | None = None,
    ) -> None:
        """A config action was ticked: recovery frames go out now; task frames at the tick's end unless stopped
        (``note`` is told what became of them: the node's feedback)."""
        if role != "task":
            if frames:
                self.sink.send(frames, node)
            if note is not None:
                note(f"{len(frames)} frame(s) sent (recovery)")
            return
        if not self._asked_by:
            self._asked_by = node
        self._queued.append((node, frames, note))

    def reset(self, node: str, now: float) -> str:
        """ResetStop was ticked: with ``stop.release: manual`` the stop may end in this tick. Says what it did."""
        self._reset_this_tick = True
        if self.state != self.STOPPED:
            return "no stop to reset"
        if self.stop_cfg.release != "manual":
            return "stop.release is auto: no reset needed"
        return "reset requested"

    def halt(self, node: str, now: float) -> None:
        """ExecuteTask was halted: stop the task at once (why is worked out once the stop frames left)."""
        if self.state == self.RUNNING:
            self.stop(now, reason=lambda: f"{node} halted" + (f" ({why})" if (why := self.explain()) else ""),
                      node=node)

    # -- driven by the engine --------------------------------------------------------------
    def stop(self, now: float, reason: str | Callable[[], str], node: str = "") -> None:
        """Stop the task (idempotent): stop frames at once, then ``reason`` (a callable: asked after the send)."""
        if self.state == self.STOPPED:
            return
        self.state = self.STOPPED
        if not self._ahead:
            self._send_stop(now)
        self._ahead = False
        self.stop_since = now
        self.stop_reason = reason if isinstance(reason, str) else reason()
        self.stops += 1
        self.next_task_t = math.inf
        self.confirm_pending = self.stop_cfg.confirm is not None
        self.cause = None
        self._event("stop", now, node=node, reason=self.stop_reason)

    def ahead(self, now: float) -> None:
        """At a model's edge, before its tick: when that tick surely halts the running task (:attr:`halts_next`),
        the stop frames leave now, and the stop (its reason, its event) follows in the tick, or at its end."""
        if self.state == self.RUNNING and self.halts_next is not None and self.halts_next():
            self._send_stop(now)
            self._ahead = True

    def inhibit(self, key: str, reason: str, now: float, node: str = "") -> None:
        """Hold the task stopped for ``key`` (stopping it now if it runs) until :meth:`release`."""
        self.inhibits[key] = reason
        if self.state == self.RUNNING:
            self.stop(now, reason=reason, node=node)

    def release(self, key: str) -> None:
        """Drop one inhibit; the task resumes when :meth:`_release_rule` next allows it."""
        self.inhibits.pop(key, None)

    def adopt(self, old: TaskGate) -> None:
        """Continue where ``old`` is (a config reload): running, stopped or idle, with its deadlines and counts."""
        self.state = old.state
        self.stop_since = old.stop_since
        self.stop_reason = old.stop_reason
        self.stopped_s = old.stopped_s
        self.stops = old.stops
        self.inhibits = dict(old.inhibits)
        self.next_task_t = old.next_task_t
        self._next_stop = old._next_stop
        self.confirm_pending = old.confirm_pending and self.stop_cfg.confirm is not None
        self.cause = old.cause

    def resend_stop(self, now: float) -> None:
        """Send the stop frames again now if the task is stopped (the daemon's exit)."""
        if self.state == self.STOPPED:
            self._send_stop(now)

    def begin_tick(self) -> None:
        """Called before each tick: tracks whether the task was asked for and a reset given in it."""
        self._ran_this_tick = False
        self._asked_by = ""
        self._reset_this_tick = False
        self._queued = []

    def end_tick(self, now: float, failed: bool, cause: tuple[str, str] = ("", "")) -> None:
        """After each tick: start, resume or hold (``failed``: the root returned FAILURE; ``cause``: (node, reason) of
        that failure); task action frames queued in the tick go out only if the task runs at its end."""
        queued, self._queued = self._queued, []
        if self._ahead:  # stop frames sent ahead of a halt that did not come: they stand, the task stops
            self.stop(now, reason="stop frames sent at a guard's trip; the tree did not halt the task")
        if self.state != self.RUNNING:
            hold = self._release_rule(now, failed)
            if not hold:
                was_stopped = self.state == self.STOPPED
                if was_stopped:
                    self._end_stop(now, self._asked_by)
                self.state = self.RUNNING
                if self._ran_this_tick:
                    self._send_task(now)
            elif self.state == self.STOPPED:
                self._note_cause(now, cause if failed and cause[1] else ("", hold))
        running = self.state == self.RUNNING
        for node, frames, note in queued:
            if running and frames:
                self.sink.send(frames, node)
            if note is not None:
                note(f"{len(frames)} frame(s) " + ("sent" if running else f"withheld: task {self.state}"))

    def _release_rule(self, now: float, failed: bool) -> str:
        """THE stop/resume rule: "" when the task may start or resume at the end of this tick, else what holds it:
        a failed root, an inhibit, a tree that did not ask for the task in this tick (a tree without ExecuteTask or
        task action asks by not failing); for a stop also ``stop.min_stop`` and a ResetStop if release is manual."""
        if failed:
            return "tree failed"
        if self.inhibits:
            return "; ".join(self.inhibits[k] for k in sorted(self.inhibits))
        if self.tree_has_task and not self._asked_by:
            return "task not reached in the tree"
        if self.state == self.STOPPED:
            since = self.stop_since if self.stop_since is not None else now
            if now - since < self.stop_cfg.min_stop_s:
                return f"stop.min_stop {self.stop_cfg.min_stop_s:g} s not elapsed"
            if self.stop_cfg.release == "manual" and not self._reset_this_tick:
                return "stop.release manual: waiting for ResetStop"
        return ""

    def _note_cause(self, now: float, cause: tuple[str, str]) -> None:
        """Journal a ``reason`` event when what holds the stop changes (the stop event said the first)."""
        if self.cause is None:
            self.cause = cause
            return
        if cause != self.cause:
            previous = self.cause[1]
            self.cause = cause
            self._event("reason", now, node=cause[0], reason=cause[1], previous=previous)

    def service(self, now: float) -> None:
        """After each tick and between ticks: periodic task / stop frames, stop confirmation."""
        if self.state == self.RUNNING and now >= self.next_task_t:
            self._send_task(now)
        elif self.state == self.STOPPED:
            if now >= self._next_stop:
                self._send_stop(now)
            if self.confirm_pending:
                self._check_confirm(now)

    def next_deadline(self) -> float:
        """The earliest time :meth:`service` has something to do (inf when nothing)."""
        if self.state == self.RUNNING:
            return self.next_task_t
        if self.state == self.STOPPED:
            nxt = self._next_stop
            if self.confirm_pending and self.stop_cfg.confirm is not None and self.stop_since is not None:
                nxt = min(nxt, self.stop_since + self.stop_cfg.confirm.deadline_s)
            return nxt
        return math.inf

    @property
    def counts_only(self) -> bool:
        """Its frames are only counted (a replay without ``--emit``): nobody reads them as they go."""
        sink = self.sink
        return isinstance(sink, LogSink) and sink.out is None and not sink.keep

    def count_task_through(self, last: float) -> None:
        """The task's periodic sends due up to ``last`` counted at once (quiet ticks while :attr:`counts_only`)."""
        task, period, sends = self.next_task_t, self.task_cfg.period_s, 0
        while task <= last:  # as service at each deadline (a tick at the same time goes first)
            sends += 1
            task += period
        if sends:
            self.next_task_t = task
            sink = self.sink
            assert isinstance(sink, LogSink)
            sink.sent += sends * len(self.task_cfg.frames)

    def skip_to(self, t: float) -> None:
        """After a gap in time: periodic frames due before ``t`` are due at ``t`` (the confirmation deadline stays)."""
        self.next_task_t = max(self.next_task_t, t)
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
        self.confirm_pending = False
        self.cause = None

    def _send_task(self, now: float) -> None:
        if self.task_cfg.frames:
            self.sink.send(self.task_cfg.frames, "task")
        # Schedule from the previous deadline when on time, so the period does not drift;
        # after a late service, restart from now rather than bursting to catch up.
        nxt = self.next_task_t + self.task_cfg.period_s
        self.next_task_t = nxt if math.isfinite(nxt) and nxt > now else now + self.task_cfg.period_s

    def _send_stop(self, now: float) -> None:
        if self.stop_cfg.frames:
            self.sink.send(self.stop_cfg.frames, "stop")
        self._next_stop = now + self.stop_cfg.repeat_s

    def _check_confirm(self, now: float) -> None:
        confirm = self.stop_cfg.confirm
        if confirm is None or self.stop_since is None:
            self.confirm_pending = False
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
            self.confirm_pending = False
            self._event(
                "confirmed", now, source=confirm.source, value=value, threshold=confirm.value,
                reason=f"{confirm.signal} {confirm.op} {confirm.value} after {now - self.stop_since:.3f} s",
            )
        elif now >= self.stop_since + confirm.deadline_s:  # next_deadline()'s own sum: (a + d) - a < d in floats
            self.confirm_pending = False
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
    """Records sent frames: streamed to ``out`` as candump -L lines at once (``replay --emit``: memory stays
    flat in the log's length), kept in :attr:`frames` (``keep``: tests), and counted in :attr:`sent`."""

    def __init__(
        self, clock_now: Callable[[], float], buses: Mapping[str, BusConfig], *,
        out: TextIO | None = None, keep: bool = True,
    ) -> None:
        self._now = clock_now
        self._channel = {name: (b.channel or name) for name, b in buses.items()}
        self.out = out
        self.keep = keep
        self.sent = 0
        self.frames: list[Frame] = []
        self.origins: list[str] = []

    def send(self, frames: Sequence[FrameSpec], origin: str) -> None:
        """Count every frame; write it to ``out`` and / or keep it, at the current time."""
        self.sent += len(frames)
        out, keep = self.out, self.keep
        if out is None and not keep:
            return
        from canguard.io.candump import format_candump_line

        t = self._now()
        for f in frames:
            frame = Frame(t, self._channel.get(f.bus, f.bus), f.arbitration_id, f.data, f.is_extended_id, f.is_fd)
            if out is not None:
                out.write(format_candump_line(frame) + "\n")
            if keep:
                self.frames.append(frame)
                self.origins.append(origin)


class BusSink:
    """Sends frames on live buses with timeout 0; each refusal counted, reported once a second per bus and origin.
    Once the stop frames are out the loop yields the CPU: a local process waiting for them runs first."""

    def __init__(self, send: Callable[[str, Any], bool], on_error: EventFn | None = None,
                 on_refused: Callable[[str, str, str, int], None] | None = None,
                 now: Callable[[], float] = time.monotonic) -> None:
        import can  # only the live path needs python-can's Message

        self._message = can.Message
        self._messages: dict[FrameSpec, Any] = {}  # each frame's python-can Message, built at its first send
        self._send = send
        self.on_error = on_error
        self.on_refused = on_refused
        """Called with (bus, frame label, origin, refusals held back before it) per reported refusal."""
        self._now = now
        self.reports = RateLimit()
        self.sent = 0

    def send(self, frames: Sequence[FrameSpec], origin: str) -> None:
        """Hand each frame to its bus with timeout 0; a full queue or an error is counted, never raised."""
        messages = self._messages
        for f in frames:
            msg = messages.get(f)
            if msg is None:
                msg = messages[f] = self._message(arbitration_id=f.arbitration_id, data=f.data,
                                                  is_extended_id=f.is_extended_id, is_fd=f.is_fd)
            if self._send(f.bus, msg):
                self.sent += 1
                continue
            if self.on_error is not None:
                self.on_error(f.bus)
            held = self.reports.allow((f.bus, origin), self._now())
            if held is None:
                continue
            log.warning("could not send %s (%s) on bus %s%s", f.label, origin, f.bus, held_note(held))
            if self.on_refused is not None:
                self.on_refused(f.bus, f.label, origin, held)
        if origin == "stop":
            os.sched_yield()
