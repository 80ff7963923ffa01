"""The status page's API against a live daemon: the JSON shape, the streams, read-only, the token, stalled clients."""

from __future__ import annotations

import contextlib
import itertools
import json
import socket
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from canguard.service.monitor.web import DOCUMENT_S
from monitorkit import DEMO_GUARDS, ESTOP_IDS, WAIT_S, Watched, running, shared_daemon, wait_for, watched_daemon

GUARD_FIELDS = {"name", "source", "value", "unit", "threshold", "margin", "status"}


@pytest.fixture(autouse=True)
def _clean_blackboard() -> Iterator[None]:
    """Not cleared between this module's tests: the shared daemon's tree holds it (monitorkit.shared_daemon)."""
    yield


@pytest.fixture
def own(tmp_path: Path) -> Iterator[Watched]:
    """A daemon of the test's own with its status page, running its task (the test trips it)."""
    with watched_daemon(tmp_path) as w:
        wait_for("the task to run", lambda: running(w))
        yield w


def sse(url: str, headers: dict[str, str] | None = None, timeout_s: float = 10.0) -> Iterator[tuple[str, str]]:
    """(event name, data) of each server-sent event read from ``url``."""
    req = urllib.request.Request(url, headers={"Accept": "text/event-stream", **(headers or {})})
    with urllib.request.urlopen(req, timeout=timeout_s) as resp:
        assert resp.headers.get_content_type() == "text/event-stream"
        name, data = "message", []
        for raw in resp:
            line = raw.decode().rstrip("\n")
            if not line:
                if data:
                    yield name, "\n".join(data)
                name, data = "message", []
            elif line.startswith("event: "):
                name = line[7:]
            elif line.startswith("data: "):
                data.append(line[6:])


def first_status(w: Watched, pred: Any, timeout_s: float = 10.0) -> dict[str, Any]:
    """The first document of the status stream for which ``pred`` holds."""
    deadline = time.monotonic() + timeout_s
    for name, data in sse(w.http + "/api/status"):
        if name == "status":
            doc = json.loads(data)
            if doc.get("task") and pred(doc):
                return doc
        assert time.monotonic() < deadline, "the status stream never showed the expected state"
    raise AssertionError("the status stream ended")


@pytest.fixture(scope="class")
def shared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Watched]:
    """The demo's daemon with its status page, running its task, while the tests of one class run; its robot
    as busy as the demo's (the stream's bound is tested against it)."""
    with shared_daemon(tmp_path_factory, busy=True) as w:
        yield w


class TestWhileRunning:
    """Requests that only read a running daemon: one daemon for them all (the class's), its task running."""

    @pytest.fixture
    def watched(self, shared: Watched) -> Watched:
        """The shared daemon, its task running (again, after any stop a loaded machine's late frames caused)."""
        wait_for("the task to run", lambda: running(shared))
        return shared

    def test_shape_and_every_guard_of_the_demo_tree(self, watched: Watched) -> None:
        """The document has tree, task, guards and events; each guard the issue's fields; every demo guard is there."""
        doc = first_status(watched, lambda d: all(g["status"] == "ok" for g in d["guards"]))
        assert {"tree", "task", "guards", "events"} <= set(doc)
        assert {g["name"] for g in doc["guards"]} == set(DEMO_GUARDS)
        for guard in doc["guards"]:
            assert set(guard) >= GUARD_FIELDS
        pack = next(g for g in doc["guards"] if g["name"] == "PackCurrent")
        assert (pack["source"], pack["unit"], pack["threshold"], pack["status"]) == ("/battery_state", "A", 35.0, "ok")
        assert pack["margin"] == pytest.approx(35.0 - pack["value"])
        heat = next(g for g in doc["guards"] if g["name"] == "Axis0I2t")
        assert heat["unit"] == "A²s" and 0.0 <= heat["heat_pct"] < 100.0
        assert doc["task"]["state"] == "running"
        assert doc["tree"]["main"] == "RobotGuard" and doc["tree"]["root"]["name"] == "Guards"
        assert [e["event"] for e in doc["events"]][:1] == ["start"]

    def test_unknown_path_is_404(self, watched: Watched) -> None:
        """A path the monitor does not serve answers 404, naming the ones it does."""
        with pytest.raises(urllib.error.HTTPError) as err:
            watched.get("/api/nothing")
        assert err.value.code == 404

    def test_stream_sends_no_more_documents_than_the_page_draws(self, watched: Watched) -> None:
        """A busy robot's stream carries at most one document per ``DOCUMENT_S`` (125 ms), yet keeps moving."""
        docs = 0
        start = time.monotonic()
        for name, _ in sse(watched.http + "/api/status"):
            docs += name == "status"
            if time.monotonic() - start >= 3.0:
                break
        elapsed = time.monotonic() - start
        assert docs <= elapsed / DOCUMENT_S + 2  # the first at once, then one per DOCUMENT_S at most
        assert docs >= 5  # the guards' values move: the page is told

    @pytest.mark.parametrize("method", ["POST", "PUT", "DELETE", "PATCH"])
    def test_writes_are_refused(self, watched: Watched, method: str) -> None:
        """Every method but GET/HEAD is 405, and the task keeps running."""
        req = urllib.request.Request(watched.http + "/api/status", data=b"{}", method=method)
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(req, timeout=5)
        assert err.value.code == 405 and "GET" in err.value.headers["Allow"]
        assert watched.status()["task"]["state"] == "running"


class TestStatus:
    """``GET /api/status``."""

    def test_trip_shows_stop_guard_reason_and_confirmation(self, own: Watched) -> None:
        """After an overcurrent the stream shows the task stopped by PackCurrent, why, and the confirmation."""
        own.trip()
        doc = first_status(own, lambda d: d["task"]["state"] == "stopped")
        task = doc["task"]
        assert task["guards"] == ["PackCurrent"]
        assert "PackCurrent" in task["reason"] and "overcurrent" in task["reason"]
        assert task["since"] is not None and task["confirmation"] in ("pending", "confirmed", "escalated")
        doc = first_status(own, lambda d: d["task"]["confirmation"] != "pending")
        # the simulated drives obey the Estop, mostly before the deadline: the page says what the journal says
        verdict = next(e["event"] for e in map(json.loads, own.events.read_text().splitlines())
                       if e["event"] in ("confirmed", "escalate"))
        assert doc["task"]["confirmation"] == {"confirmed": "confirmed", "escalate": "escalated"}[verdict]

    def test_stream_sends_a_document_only_when_more_than_its_time_changed(self, tmp_path: Path) -> None:
        """A silent robot: snapshots go on (GET sees them), the stream sends none that only moved in time."""
        with watched_daemon(tmp_path, robot=False) as w:
            docs: list[dict[str, Any]] = []

            def read() -> None:
                with contextlib.suppress(OSError):  # the stream ends with the daemon
                    docs.extend(json.loads(data) for name, data in sse(w.http + "/api/status") if name == "status")

            threading.Thread(target=read, daemon=True).start()
            first = wait_for("the stream's first document", lambda: next((d for d in docs if d.get("task")), None))
            wait_for("20 more snapshots", lambda: w.status()["seq"] >= first["seq"] + 20)
            sent = [d for d in list(docs) if d.get("task")]
            timeless = [{**d, "t": None, "seq": None, "task": {**d["task"], "for_s": None}} for d in sent]
            assert all(a != b for a, b in itertools.pairwise(timeless))
            assert len(sent) < 10


class TestEvents:
    """``GET /api/events``."""

    def test_streams_the_journal_trip_and_stop(self, own: Watched) -> None:
        """The stream replays the kept events, then the trip and the stop as the journal writes them."""
        seen: list[dict[str, Any]] = []
        tripped = False
        for name, data in sse(own.http + "/api/events"):
            assert name == "message"
            seen.append(json.loads(data))
            if not tripped and seen[-1]["event"] == "start":
                own.trip()
                tripped = True
            if seen[-1]["event"] == "stop" and any(e["event"] == "trip" for e in seen):
                break  # a stop before the task first ran (a source not yet fresh) is not the trip's
        trip = next(e for e in seen if e["event"] == "trip")
        assert (trip["node"], trip["reason"]) == ("PackCurrent", "overcurrent")
        journal = [json.loads(line)["event"] for line in own.events.read_text().splitlines()]
        assert [e["event"] for e in seen] == journal[:len(seen)]


class TestReadOnlyAndToken:
    """Nothing changes what canguard does; a token guards every request."""

    def test_token_is_required_when_set(self, tmp_path: Path) -> None:
        """With monitor.token, a request without it is 401; the bearer header or ?token= opens every path."""
        with watched_daemon(tmp_path, token="s3cret", robot=False) as w:
            for path in ("/", "/api/status"):
                with pytest.raises(urllib.error.HTTPError) as err:
                    w.get(path)
                assert err.value.code == 401
                with pytest.raises(urllib.error.HTTPError):
                    w.get(path, headers={"Authorization": "Bearer wrong"})
                assert "tree" in w.get(path, headers={"Authorization": "Bearer s3cret"})
                assert "tree" in w.get(path + "?token=s3cret")


def unread_stream(port: int, path: str) -> socket.socket:
    """A stream asked for and never read (a small receive buffer: the server's writes back up soon)."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)
    s.connect(("127.0.0.1", port))
    s.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n\r\n".encode())
    return s


def test_misbehaving_clients_leave_the_page_and_the_stop_as_they_are(tmp_path: Path,
                                                                     capfd: pytest.CaptureFixture[str]) -> None:
    """Unread streams, half-requests, resets, Groot2 clients that never read or send garbage, all at once.

    The page and ``/api/status`` answer throughout, a trip puts the Estop on the bus on time (a loop held up by
    a stalled write would wait out the server's 5 s send timeout: 2 s leaves a loaded machine its slack;
    bench_latency measures the real tail), Groot2 still answers a new client, every stream place is free as
    soon as its client left, and nothing of it prints a traceback, nor does the daemon's end with them open.
    """
    import zmq

    with contextlib.ExitStack() as held, watched_daemon(tmp_path, groot2=True) as w:  # held: open as it stops
        wait_for("the task to run", lambda: running(w))
        port = int(w.http.rsplit(":", 1)[1])
        streams = [unread_stream(port, path) for path in ("/api/status", "/api/events") * 10]
        for _ in range(60):
            half = socket.create_connection(("127.0.0.1", port))
            half.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n")  # and never the blank line
            held.callback(half.close)
        for _ in range(10):
            s = unread_stream(port, "/api/events")
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\1\0\0\0\0\0\0\0")  # on, 0 s: a reset
            s.close()
        for p in (w.groot2, w.groot2 + 1):  # not ZeroMQ at all
            raw = socket.create_connection(("127.0.0.1", p))
            raw.sendall(bytes(range(256)) * 8)
            held.callback(raw.close)
        ctx = zmq.Context()
        held.callback(ctx.destroy, linger=0)
        for i in range(20):  # many REQ clients, each asking once and never reading the reply
            req = ctx.socket(zmq.REQ)
            req.connect(f"tcp://127.0.0.1:{w.groot2}")
            req.send_multipart([bytes([2, ord("TSB"[i % 3])]) + i.to_bytes(4, "little"), b"RobotGuard"])
        greedy = ctx.socket(zmq.DEALER)  # garbage requests, and never a reply read
        greedy.connect(f"tcp://127.0.0.1:{w.groot2}")
        for i in range(200):
            greedy.send_multipart([b"", bytes([2, ord("T")]) + i.to_bytes(4, "little")] if i % 2 else
                                  [b"", b"\xff" * (i % 9), b"junk"], zmq.NOBLOCK)
        sub = ctx.socket(zmq.SUB)  # subscribed to everything, never read
        sub.setsockopt(zmq.SUBSCRIBE, b"")
        sub.connect(f"tcp://127.0.0.1:{w.groot2 + 1}")
        seq = w.status()["seq"]  # let ~20 status documents pile up behind the unread streams
        wait_for("the status stream to move on", lambda: w.status()["seq"] >= seq + 20)
        assert "<html" in w.get("/")
        msg = w.trip_until_estop(2.0)
        assert msg is not None and msg.arbitration_id in ESTOP_IDS, "no Estop within 2 s while clients misbehaved"
        wait_for("the page to show the stop", lambda: w.status()["task"]["state"] == "stopped")
        asker = ctx.socket(zmq.REQ)
        asker.setsockopt(zmq.RCVTIMEO, 5000)
        asker.connect(f"tcp://127.0.0.1:{w.groot2}")
        asker.send_multipart([bytes([2, ord("S"), 1, 0, 0, 0])])
        assert len(asker.recv_multipart()[0]) == 22  # a STATUS reply: protocol header + the tree's UUID
        for s in streams:
            s.close()

        def streams_free() -> bool:
            with contextlib.ExitStack() as fresh:
                for _ in range(16):  # every place of this address (web.Limits.streams_per_address)
                    s = unread_stream(port, "/api/events")
                    fresh.callback(s.close)
                    if not s.recv(12).startswith(b"HTTP/1.1 200"):
                        return False
            return True

        wait_for("the places of the streams that left", streams_free, timeout_s=5.0)
        held.enter_context(contextlib.closing(unread_stream(port, "/api/status")))
    assert "Traceback" not in capfd.readouterr().err


def test_a_failing_monitor_never_stops_the_guard(tmp_path: Path, caplog: pytest.LogCaptureFixture,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """When publishing a snapshot raises, the tick goes on: the trip still sends the Estop, and the log says why."""
    with watched_daemon(tmp_path) as w:
        wait_for("the task to run", lambda: running(w))

        def broken(*_record: object) -> None:
            raise RuntimeError("monitor broke")

        monkeypatch.setattr(w.daemon.monitor, "offer", broken)
        msg = w.trip_until_estop(WAIT_S)
        assert msg is not None and msg.arbitration_id in ESTOP_IDS
        # the stop's snapshot is taken in a tick after the Estop went out: wait for it, not for the daemon's end
        wait_for("the log to say why", lambda: any("monitor snapshot failed" in r.getMessage() for r in caplog.records))
