"""In the monitor process: the latest tick and the last journal events, which the servers read."""

from __future__ import annotations

import contextlib
import json
import logging
import math
import socket
import time
from collections import deque
from collections.abc import Callable
from typing import Any, NamedTuple

from canguard.engine.event_codec import encode_event
from canguard.service.monitor import STATUS_NAMES, WANT_BLACKBOARD
from canguard.service.monitor.layout import LayoutRecord

KEEP_EVENTS = 500
"""Journal events kept for clients; a client further behind loses the oldest."""
STATUS_EVENTS = 30
"""Journal events ``/api/status`` carries."""
NOTE_EVERY_S = 60.0
"""Shortest time between two log lines of the same client misbehaviour; the ones between are counted."""


class Tick(NamedTuple):
    """One tick of the daemon as the monitors show it."""

    seq: int
    t: float
    layout: LayoutRecord
    codes: bytes
    """Per UID (``codes[uid - 1]``), BT.CPP's status code."""
    task: tuple[Any, ...]
    """As :func:`task_document` reads it."""
    guards: tuple[tuple[Any, ...], ...]
    """Each as :func:`guard_document` reads it."""
    confirm: bool
    """``stop.confirm`` is configured (a stop then waits for its confirmation)."""
    blackboard: dict[str, Any] | None
    """The root blackboard's entries, when a monitor asked for them lately."""


class ClientNotes:
    """What clients did wrong, per cause: logged at once, then at most every :data:`NOTE_EVERY_S` with the count."""

    def __init__(self, log: logging.Logger, server: str) -> None:
        self._log = log
        self._server = server
        self._causes: dict[str, tuple[float, int]] = {}
        """cause -> (when its next line may be written, occurrences not yet logged)."""

    def note(self, cause: str) -> None:
        """One more occurrence of ``cause`` (a sentence of what the client did and what was done about it)."""
        now = time.monotonic()
        next_s, held = self._causes.get(cause, (-1.0, 0))
        if now < next_s:
            self._causes[cause] = (next_s, held + 1)
            return
        self._causes[cause] = (now + NOTE_EVERY_S, 0)
        more = f" ({held} more times since the last such line)" if held else ""
        self._log.warning("%s: %s%s", self._server, cause, more)


class Hub:
    """The latest :class:`Tick` and journal events from the daemon's socket, for server threads (no lock needed)."""

    def __init__(self, sock: socket.socket | None = None) -> None:
        self.sock = sock
        self.layout: LayoutRecord | None = None
        self._guards: tuple[tuple[Any, ...], ...] = ()
        self.latest: Tick | None = None
        """The latest tick (None before the first)."""
        self._events: deque[tuple[int, bytes, dict[str, Any]]] = deque(maxlen=KEEP_EVENTS)
        """(seq, journal line, the line as JSON): each event is encoded once, as it arrives."""
        self._event_seq = 0
        self.on_news: Callable[[], None] = lambda: None
        """Called after each message of the daemon, in the receiving thread (it must not wait)."""

    def receive(self, message: tuple[Any, ...]) -> None:
        """One message of the daemon: a tree's layout, or a tick's journal events and record."""
        if message[0] == "layout":
            self.layout = message[1]
            self._guards = ()
            return
        _, events, record = message
        for seq, event in events:  # numbered by the daemon (a gap: events it dropped)
            line = encode_event(event)  # as the journal writes it (JSON-safe, rounded)
            self._event_seq = seq
            self._events.append((seq, line, json.loads(line)))
        if record is not None and self.layout is not None:
            seq, t, codes, task, confirm, blackboard, guards = record
            if guards is not None:
                self._guards = guards
            self.latest = Tick(seq, t, self.layout, codes, task, self._guards, confirm, blackboard)
        self.on_news()

    def want_blackboard(self) -> None:
        """Ask the daemon to put the root blackboard into its records for the next second."""
        if self.sock is not None:
            with contextlib.suppress(OSError):  # the daemon is busy or gone: no blackboard this time
                self.sock.send(WANT_BLACKBOARD, socket.MSG_DONTWAIT)

    def events_after(self, seq: int) -> tuple[list[tuple[int, bytes]], int]:
        """Events newer than ``seq`` as (seq, journal line), and how many of them were already dropped."""
        kept = list(self._events)  # one C-level copy: atomic against the receiving side's appends
        newer = [(n, line) for n, line, _ in kept if n > seq]
        first = newer[0][0] if newer else self._event_seq + 1
        return newer, max(0, first - seq - 1)

    def status(self) -> dict[str, Any]:
        """The ``/api/status`` document: tree, task, guards, events."""
        tick = self.latest
        events = [form for _, _, form in list(self._events)[-STATUS_EVENTS:]]
        if tick is None:
            return {"tree": None, "task": None, "guards": [], "events": events}
        root = _with_status(tick.layout.tree, tick.codes)
        return {"t": tick.t, "seq": tick.seq, "tree": {"main": tick.layout.main_id, "status": root["status"],
                                                       "root": root},
                "task": task_document(tick, events), "guards": [guard_document(g) for g in tick.guards],
                "events": events}


def _number(x: float | None) -> float | None:
    return x if isinstance(x, (int, float)) and math.isfinite(x) else None


def _with_status(node: dict[str, Any], codes: bytes) -> dict[str, Any]:
    """A copy of the static ``node`` and its children, each with its status (``IDLE`` for an idle-after code)."""
    code = codes[node["uid"] - 1]
    out = {**node, "status": STATUS_NAMES[code] if code < len(STATUS_NAMES) else "IDLE"}
    out["children"] = [_with_status(child, codes) for child in node["children"]]
    return out


def task_document(tick: Tick, events: list[dict[str, Any]]) -> dict[str, Any]:
    """The task: state, since when, stopped by which guards and why, what holds it, confirmation / escalation."""
    state, since, reason, stops, holding, failing, stopped_by = tick.task  # as the daemon's Monitor takes it
    stopped = state == "stopped"
    since = since if stopped else None
    confirmation = None
    if since is not None:
        confirmation = "pending" if tick.confirm else None
        for ev in events:
            if ev.get("event") in ("confirmed", "escalate") and (ev.get("t") or 0) >= since - 1e-6:
                confirmation = "confirmed" if ev["event"] == "confirmed" else "escalated"
    return {"state": state, "since": _number(since), "for_s": None if since is None else _number(tick.t - since),
            "reason": reason if stopped else "", "guards": list(stopped_by) if stopped else [],
            "failing": list(failing), "holding": [{"key": k, "reason": r} for k, r in holding],
            "stops": stops, "confirmation": confirmation}


def guard_document(guard: tuple[Any, ...]) -> dict[str, Any]:
    """One guard: name, source, value, unit, threshold, margin, status, role, kind, heat and reason."""
    name, role, kind, source, value, unit, threshold, heat_pct, status, reason = guard  # as the Monitor reads it
    return {"name": name, "source": source, "value": _number(value), "unit": unit, "threshold": _number(threshold),
            "margin": _number(threshold - value), "status": status, "role": role, "kind": kind,
            "heat_pct": _number(heat_pct), "reason": reason}
