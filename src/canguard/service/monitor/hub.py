"""In the monitor process: the latest snapshot, the last journal events, and who to wake.

Receiving only assigns a reference or appends to a bounded deque; a dispatcher thread renders the status document
at most every :data:`DOCUMENT_S` (shared by every client) and wakes its subscribers.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any

from canguard.engine.event_codec import encode_event
from canguard.service.monitor.snapshot import TickSnapshot, status_name

DOCUMENT_S = 0.125
"""Shortest time between two status documents (a browser spends ~5 ms drawing each): a change still reaches a
page within 200 ms."""
KEEP_EVENTS = 500
"""Journal events kept for clients; a client further behind loses the oldest."""
STATUS_EVENTS = 30
"""Journal events ``/api/status`` carries."""


class Hub:
    """The latest :class:`TickSnapshot` and journal events, for any number of monitor threads."""

    def __init__(self, ask_blackboard: Callable[[], None] = lambda: None) -> None:
        self.want_blackboard = ask_blackboard
        """Ask the engine to put the root blackboard into its snapshots for the next second."""
        self._latest: TickSnapshot | None = None
        self._events: deque[tuple[int, bytes, dict[str, Any]]] = deque(maxlen=KEEP_EVENTS)
        """(seq, journal line, the line as JSON): each event is encoded once, as it arrives."""
        self._event_seq = 0
        self._subscribers: list[Callable[[], None]] = []
        self._version = 0
        self._doc: tuple[int, bytes] = (0, json.dumps(self.status()).encode())
        self._closed = threading.Event()
        self._news = threading.Event()
        """Set by the receiving side on a new snapshot or event: the dispatcher sleeps until then."""
        self._thread: threading.Thread | None = None

    # -- the receiving side: never blocks ----------------------------------------------------------
    def put(self, snapshot: TickSnapshot) -> None:
        """Publish the latest snapshot."""
        self._latest = snapshot
        self._news.set()

    def event(self, event: Mapping[str, Any], seq: int) -> None:
        """Keep one journal event, numbered ``seq`` by the daemon (a gap: events it dropped); the oldest go."""
        line = encode_event(event)  # as the journal writes it (JSON-safe, rounded)
        self._event_seq = seq
        self._events.append((seq, line, json.loads(line)))
        self._news.set()

    # -- the monitors' side ----------------------------------------------------------------------
    def latest(self) -> TickSnapshot | None:
        """The latest published snapshot (None before the first tick)."""
        return self._latest

    def events_after(self, seq: int) -> tuple[list[tuple[int, bytes]], int]:
        """Events newer than ``seq`` as (seq, journal line), and how many of them were already dropped."""
        kept = list(self._events)  # one C-level copy: atomic against the engine's appends
        newer = [(n, line) for n, line, _ in kept if n > seq]
        first = newer[0][0] if newer else self._event_seq + 1
        return newer, max(0, first - seq - 1)

    def status_document(self) -> tuple[int, bytes]:
        """(version, ``/api/status`` JSON): the latest document, its version bumped when more than its time changed."""
        return self._doc

    def subscribe(self, changed: Callable[[], None]) -> None:
        """Call ``changed()`` (from the dispatcher's thread: it must not wait) at each new status document."""
        self._subscribers.append(changed)

    # -- the dispatcher ----------------------------------------------------------------------------
    def start(self) -> None:
        """Start the dispatcher thread."""
        self._thread = threading.Thread(target=self._dispatch, name="canguard-monitor-hub", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the dispatcher."""
        self._closed.set()
        self._news.set()
        if self._thread is not None:
            self._thread.join(2)

    def _dispatch(self) -> None:
        shown: dict[str, Any] | None = None
        due = -math.inf
        while True:
            self._news.wait()  # a snapshot or an event came (or close)
            wait_s = due - time.monotonic()
            if self._closed.is_set() or (wait_s > 0 and self._closed.wait(wait_s)):
                return  # else: what came until the next document is due goes into it
            self._news.clear()  # before reading: news after this wakes the next round
            due = time.monotonic() + DOCUMENT_S
            status = self.status()
            doc = json.dumps(status, allow_nan=False, separators=(",", ":")).encode()
            news = _shown(status)
            changed = news != shown  # streams get a document when what a page shows changed, not its clock alone
            self._version += changed
            self._doc = (self._version, doc)  # one tuple assigned: a plain GET always gets the latest
            shown = news
            if changed:
                for tell in self._subscribers:
                    tell()

    def status(self) -> dict[str, Any]:
        """The ``/api/status`` document: tree, task, guards, events."""
        snap = self._latest
        events = [form for _, _, form in list(self._events)[-STATUS_EVENTS:]]
        if snap is None:
            return {"tree": None, "task": None, "guards": [], "events": events}
        return {"t": snap.t, "seq": snap.seq, "tree": tree_document(snap), "task": task_document(snap, events),
                "guards": [guard_document(g) for g in snap.guards], "events": events}


def _shown(status: dict[str, Any]) -> dict[str, Any]:
    """``status`` without what changes with the clock alone (the page counts a stop's duration itself)."""
    task = status.get("task")
    return {**status, "t": None, "seq": None, "task": {**task, "for_s": None} if task else task}


def _number(x: float | None) -> float | None:
    return x if isinstance(x, (int, float)) and math.isfinite(x) else None


def tree_document(snap: TickSnapshot) -> dict[str, Any]:
    """The tree with each node's status: ``{"main", "status", "root": {uid, type, name, status, children}}``."""
    root = _with_status(snap.layout.tree, snap.codes)
    return {"main": snap.layout.main_id, "status": root["status"], "root": root}


def _with_status(node: dict[str, Any], codes: tuple[int, ...]) -> dict[str, Any]:
    """A copy of the static ``node`` and its children, each with its status (the static tree stays as it is)."""
    out = {**node, "status": status_name(codes[node["uid"] - 1])}
    out["children"] = [_with_status(child, codes) for child in node["children"]]
    return out


def task_document(snap: TickSnapshot, events: list[dict[str, Any]]) -> dict[str, Any]:
    """State, since when, stopped by which guard and why, what holds it, confirmation / escalation."""
    task = snap.task
    stopped = task.state == "stopped"
    since = task.since if stopped else None
    confirmation = None
    if since is not None:
        confirmation = "pending" if snap.confirm else None
        for ev in events:
            if ev.get("event") in ("confirmed", "escalate") and (ev.get("t") or 0) >= since - 1e-6:
                confirmation = "confirmed" if ev["event"] == "confirmed" else "escalated"
    return {"state": task.state, "since": _number(since), "for_s": None if since is None else _number(snap.t - since),
            "reason": task.reason if stopped else "", "guards": list(task.stopped_by) if stopped else [],
            "failing": list(task.failing), "holding": [{"key": k, "reason": r} for k, r in task.holding],
            "stops": task.stops, "confirmation": confirmation}


def guard_document(g: Any) -> dict[str, Any]:
    """One guard: name, source, value, unit, threshold, margin, status, role, kind, heat and reason."""
    return {
        "name": g.name, "source": g.source, "value": _number(g.value), "unit": g.unit,
        "threshold": _number(g.threshold), "margin": _number(g.threshold - g.value), "status": g.status,
        "role": g.role, "kind": g.kind, "heat_pct": _number(g.heat_pct), "reason": g.reason,
    }
