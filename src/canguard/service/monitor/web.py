"""The status page and its API: one asyncio event loop, in a thread of its own, serves every connection.

Read-only, with an optional bearer token (docs/monitor.md)."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import email.utils
import hmac
import json
import logging
import math
import re
import resource
import socket
import threading
from collections import Counter
from collections.abc import Awaitable
from dataclasses import dataclass
from http import HTTPStatus
from typing import Any, TypeVar
from urllib.parse import parse_qs, urlsplit

from canguard.config.monitor import Address
from canguard.data import data_path
from canguard.service.monitor.hub import ClientNotes, Hub

log = logging.getLogger(__name__)
T = TypeVar("T")

HEAD_BYTES = 16 * 1024
"""Largest request head (request line and headers); a longer one is answered 431."""
_HEAD_END = re.compile(rb"\r?\n\r?\n")
_LINE = re.compile(r"\r?\n")
_TEXT = "text/plain; charset=utf-8"
DOCUMENT_S = 0.125
"""Shortest time between two status documents: a change still reaches a page within 200 ms."""
_PAGE_HEADERS = {"Content-Security-Policy": "default-src 'none'; script-src 'unsafe-inline'; "
                                            "style-src 'unsafe-inline'; connect-src 'self'; img-src data:"}


@dataclass(frozen=True)
class Limits:
    """What the status page's server grants its clients (docs/monitor.md, "Clients that misbehave")."""

    max_connections: int = 2048
    max_streams: int = 64
    streams_per_address: int = 16
    request_timeout_s: float = 5.0
    send_timeout_s: float = 5.0
    keepalive_s: float = 15.0
    backlog: int = 1024


class _Refused(Exception):
    """A request answered with an error status, then the connection closed."""

    def __init__(self, code: int, body: str, cause: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(cause)
        self.code, self.body, self.cause, self.headers = code, body.encode(), cause, headers or {}


@dataclass(frozen=True)
class _Request:
    method: str
    path: str
    query: str
    headers: dict[str, str]
    keep_alive: bool


def _parse(head: bytes) -> _Request:
    """The request line and headers; :class:`_Refused` (400) when they are not HTTP/1."""
    lines = _LINE.split(head.decode("latin-1"))
    parts = lines[0].split(" ") if lines else []
    if len(parts) != 3 or not parts[2].startswith("HTTP/1."):
        raise _Refused(400, "not an HTTP/1 request\n", "a malformed request line (answered 400)")
    headers: dict[str, str] = {}
    for line in lines[1:]:
        name, colon, value = line.partition(":")
        if not colon or not name.strip():
            raise _Refused(400, "malformed header\n", "a malformed header (answered 400)")
        headers[name.strip().lower()] = value.strip()
    method, target, version = parts
    url = urlsplit(target)
    has_body = headers.get("content-length", "0") not in ("", "0") or "transfer-encoding" in headers
    keep = version == "HTTP/1.1" and headers.get("connection", "").lower() != "close" and not has_body
    return _Request(method, url.path, url.query, headers, keep)


def _head(code: int, headers: dict[str, str]) -> bytes:
    lines = [f"HTTP/1.1 {code} {HTTPStatus(code).phrase}", "Server: canguard-monitor",
             f"Date: {email.utils.formatdate(usegmt=True)}", "Cache-Control: no-store"]
    lines += [f"{k}: {v}" for k, v in headers.items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")


async def _first(*steps: Awaitable[T], timeout_s: float | None = None) -> T:
    """Run ``steps`` until the first ends (its result or exception), the others cancelled; asyncio.TimeoutError after
    ``timeout_s``. Not ``asyncio.wait_for``: cancelled as its step fails, it leaves that exception unread (logged)."""
    tasks = [asyncio.ensure_future(step) for step in steps]
    for task in tasks:
        task.add_done_callback(lambda t: t.cancelled() or t.exception())
    try:
        done, _ = await asyncio.wait(tasks, timeout=timeout_s, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
    if not done:
        raise asyncio.TimeoutError
    errors = [error for task in done if (error := task.exception())]
    if errors:
        raise errors[0]
    return done.pop().result()


async def _until_closed(reader: asyncio.StreamReader) -> None:
    """Return when the client closed its end; ConnectionResetError when it reset it. What it sends is ignored."""
    while await reader.read(4096):
        pass


class WebMonitor:
    """The HTTP server of the status page, its event loop in a thread of its own."""

    def __init__(self, address: Address, hub: Hub, token: str | None, limits: Limits | None = None) -> None:
        limits = limits or Limits()
        soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)  # half the descriptors: the rest Groot2's, the system's
        if soft != resource.RLIM_INFINITY:
            limits = dataclasses.replace(limits, max_connections=max(16, min(limits.max_connections, soft // 2)))
        self.limits = limits
        """What clients are granted (``max_connections`` as this process's descriptors allow)."""
        self.hub = hub
        self.token = token
        self.page = data_path("monitor", "index.html").read_bytes()
        self.notes = ClientNotes(log, "status page")
        self.changed = asyncio.Event()
        """Set and replaced on each new status document: every waiting stream wakes."""
        self.document = (0, json.dumps(hub.status()).encode())
        """(version, ``/api/status`` JSON): the latest, its version bumped when more than its time changed."""
        self._shown: dict[str, Any] | None = None
        self._due = -math.inf
        self._rendering = False
        self.open = 0
        self.waiting: dict[asyncio.StreamWriter, None] = {}
        """Connections reading a request head or lingering after their answer, oldest first: the first to go."""
        self.streams: Counter[str] = Counter()
        family = socket.AF_INET6 if ":" in address.host else socket.AF_INET
        self._sock = socket.create_server((address.host, address.port), family=family, backlog=limits.backlog)
        host, port = self._sock.getsockname()[:2]
        self.address = Address(str(host), int(port))
        """Where it listens (the port the system gave for port 0)."""
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Event | None = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=asyncio.run, args=(self._main(),), name="canguard-monitor-http",
                                        daemon=True)
        hub.on_news = self._news

    def start(self) -> None:
        """Serve in a thread of its own (listening already: connections wait in the backlog meanwhile)."""
        self._thread.start()
        self._ready.wait(5)

    def close(self) -> None:
        """Stop serving: every connection closed."""
        loop, stopping = self._loop, self._stopping
        if loop is not None and stopping is not None:
            with contextlib.suppress(RuntimeError):  # the loop ended already
                loop.call_soon_threadsafe(stopping.set)
            self._thread.join(2)
        self._sock.close()

    def _news(self) -> None:
        """The hub's receiving thread: news for the next status document (made in the loop's thread)."""
        loop = self._loop
        if loop is not None:
            with contextlib.suppress(RuntimeError):  # the loop is closing
                loop.call_soon_threadsafe(self._schedule)

    def _schedule(self) -> None:
        """Make the next document at once, or :data:`DOCUMENT_S` after the last: what comes meanwhile goes in it."""
        if not self._rendering and self._loop is not None:
            self._rendering = True
            self._loop.call_at(max(self._loop.time(), self._due), self._render)

    def _render(self) -> None:
        """One status document for every client; the streams wake when what a page shows changed."""
        self._rendering = False
        self._due = asyncio.get_running_loop().time() + DOCUMENT_S
        status = self.hub.status()
        doc = json.dumps(status, allow_nan=False, separators=(",", ":")).encode()
        task = status.get("task")
        shown = {**status, "t": None, "seq": None, "task": {**task, "for_s": None} if task else task}
        changed = shown != self._shown
        self._shown = shown
        self.document = (self.document[0] + changed, doc)
        if changed:  # every waiting stream wakes
            self.changed.set()
            self.changed = asyncio.Event()

    async def _main(self) -> None:
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(self.on_loop_error)
        self._stopping = asyncio.Event()
        server = await asyncio.start_server(self.connection, sock=self._sock, backlog=self.limits.backlog,
                                            limit=HEAD_BYTES + 4)
        self._loop = loop
        self._schedule()
        self._ready.set()
        try:
            await self._stopping.wait()
        finally:
            server.close()  # then asyncio.run cancels each connection's task: each aborts its transport

    async def connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """Serve one connection until it ends; nothing it does escapes as an exception."""
        self.open += 1
        peer = writer.get_extra_info("peername")
        address = str(peer[0]) if peer else "?"
        buffered = bytearray()  # what came of the next request's head
        first = True
        try:
            if not self._admit():
                return
            while True:
                self.waiting[writer] = None  # reading a request head: the first to go when every place is taken
                try:
                    head = await self._read_head(reader, buffered, first)
                finally:
                    self.waiting.pop(writer, None)
                if head is None:
                    return
                first = False
                if not await self._respond(_parse(head), reader, writer, address):
                    await self._close(reader, writer)
                    return
        except _Refused as refused:
            self.notes.note(refused.cause)
            with contextlib.suppress(OSError, asyncio.TimeoutError):
                await self._answer(writer, refused.code, refused.body, _TEXT, refused.headers, False)
                await self._close(reader, writer)
        except asyncio.TimeoutError:
            self.notes.note(f"a client took nothing sent to it for {self.limits.send_timeout_s:g} s (dropped)")
        except (ConnectionResetError, BrokenPipeError):
            self.notes.note("a client reset its connection")
        except OSError as exc:
            self.notes.note(f"a connection failed: {exc.strerror or exc}")
        finally:
            self.waiting.pop(writer, None)
            self.open -= 1
            writer.transport.abort()  # after a graceful close: nothing; else the place is free now

    def _admit(self) -> bool:
        """Room for one more connection: the oldest one still sending its request (or lingering) goes, or this one."""
        if self.open <= self.limits.max_connections:
            return True
        if not self.waiting:
            self.notes.note(f"{self.limits.max_connections} connections open, all served: a new one closed")
            return False
        oldest = next(iter(self.waiting))
        self.waiting.pop(oldest)
        oldest.transport.abort()
        self.notes.note(f"{self.limits.max_connections} connections open: the oldest unfinished request closed "
                        "for a new one")
        return True

    async def _read_head(self, reader: asyncio.StreamReader, buffered: bytearray, first: bool) -> bytes | None:
        """The next request's head; None when the client closed, or did not send it whole in time."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.limits.request_timeout_s
        while (end := _HEAD_END.search(buffered)) is None:
            if len(buffered) > HEAD_BYTES:
                raise _Refused(431, "request head too large\n", f"a request head over {HEAD_BYTES} bytes "
                               "(answered 431)")
            try:
                chunk = await _first(reader.read(HEAD_BYTES + 4), timeout_s=max(0.0, deadline - loop.time()))
            except asyncio.TimeoutError:
                if buffered or first:
                    self.notes.note(f"a request not sent whole within {self.limits.request_timeout_s:g} s "
                                    "(connection closed)")
                return None  # else an idle keep-alive connection: closed quietly
            if not chunk:
                return None  # the client closed (or was closed for a newer one: _admit): nothing to answer
            buffered += chunk
        head = bytes(buffered[:end.start()])
        del buffered[:end.end()]
        return head

    async def _close(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """End our side, then wait for the client's close (closing with a request body unread resets the answer)."""
        self.waiting[writer] = None  # lingering: the first to go when every place is taken
        with contextlib.suppress(OSError, asyncio.TimeoutError):  # it lingers or resets: it is closed all the same
            writer.write_eof()
            await _first(_until_closed(reader), timeout_s=self.limits.send_timeout_s)

    async def _respond(self, req: _Request, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                       address: str) -> bool:
        """Answer ``req``; True when the connection stays open for another request."""
        keep, code, ctype, extra = req.keep_alive, 200, _TEXT, {}
        if req.method not in ("GET", "HEAD"):
            keep, code, body = False, 405, b"read-only: canguard's monitor answers GET only\n"
            extra = {"Allow": "GET, HEAD"}
        elif not self._authorized(req):
            code, body = 401, b"a bearer token is required (Authorization: Bearer TOKEN, or ?token=TOKEN)\n"
            extra = {"WWW-Authenticate": 'Bearer realm="canguard"'}
        elif req.path in ("/", "/index.html"):
            body, ctype, extra = self.page, "text/html; charset=utf-8", _PAGE_HEADERS
        elif req.path == "/api/status" and "text/event-stream" not in req.headers.get("accept", ""):
            body, ctype = self.document[1], "application/json"
        elif req.path in ("/api/status", "/api/events"):
            await self._stream(req, reader, writer, address)
            return False
        else:
            code, body = 404, b"not found: try /, /api/status or /api/events\n"
        await self._answer(writer, code, body, ctype, extra, keep, req.method)
        return keep

    def _authorized(self, req: _Request) -> bool:
        token = (self.token or "").encode()
        bearer = req.headers.get("authorization", "")
        given = [bearer[7:].strip()] if bearer.startswith("Bearer ") else []
        given += parse_qs(req.query).get("token", [])[:1]
        return not token or any(g and hmac.compare_digest(g.encode(), token) for g in given)

    async def _answer(self, writer: asyncio.StreamWriter, code: int, body: bytes, ctype: str,
                      headers: dict[str, str], keep: bool, method: str = "GET") -> None:
        head = _head(code, {"Content-Type": ctype, "Content-Length": str(len(body)),
                            **({} if keep else {"Connection": "close"}), **headers})
        await self._send(writer, head if method == "HEAD" else head + body)

    async def _send(self, writer: asyncio.StreamWriter, data: bytes) -> None:
        """Write; asyncio.TimeoutError when the client takes none of it for ``send_timeout_s``."""
        writer.write(data)
        await _first(writer.drain(), timeout_s=self.limits.send_timeout_s)

    async def _stream(self, req: _Request, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                      address: str) -> None:
        """A stream in a place of its own, until its client leaves (read as it happens) or stalls."""
        limits = self.limits
        if self.streams[address] >= limits.streams_per_address:
            raise _Refused(503, "too many event streams from this address\n", f"more than "
                           f"{limits.streams_per_address} event streams from one address (answered 503)",
                           {"Retry-After": "5"})
        if self.streams.total() >= limits.max_streams:
            raise _Refused(503, "too many event streams\n", f"more than {limits.max_streams} event streams "
                           "(answered 503)", {"Retry-After": "5"})
        self.streams[address] += 1
        try:
            await self._send(writer, _head(200, {"Content-Type": "text/event-stream", "X-Accel-Buffering": "no",
                                                 "Connection": "close"}))
            if req.method == "HEAD":
                return
            await _first(self._stream_data(writer, req.path == "/api/status"), _until_closed(reader))
        finally:
            self.streams[address] -= 1
            if not self.streams[address]:
                del self.streams[address]

    async def _stream_data(self, writer: asyncio.StreamWriter, status: bool) -> None:
        """Each new status document (``status``), else each journal event; a keep-alive after ``keepalive_s``."""
        sent, cursor = -1, 0
        while True:
            changed = self.changed  # set by a change from now on, while this stream writes too
            out = []
            if status and self.document[0] != sent:
                sent, doc = self.document
                out.append(b"event: status\ndata: " + doc + b"\n\n")
            elif not status:
                events, lost = self.hub.events_after(cursor)
                out += [b"event: lost\ndata: " + json.dumps({"events": lost}).encode() + b"\n\n"] if lost else []
                for cursor, line in events:
                    out.append(b"id: %d\ndata: " % cursor + line.rstrip(b"\n") + b"\n\n")
            if out:
                await self._send(writer, b"".join(out))
            try:
                await _first(changed.wait(), timeout_s=self.limits.keepalive_s)
            except asyncio.TimeoutError:
                await self._send(writer, b": keep-alive\n\n")

    def on_loop_error(self, _loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        """What the loop itself could not do (an accept out of descriptors): one line per cause, no traceback."""
        exc = context.get("exception")
        if isinstance(exc, asyncio.CancelledError):  # a connection ended at shutdown
            return
        if exc is not None and not isinstance(exc, OSError):  # canguard's fault, not a client's: say where
            log.error("status page: %s", context.get("message"), exc_info=exc)
            return
        self.notes.note(f"{context.get('message', 'event loop error')}"
                        f"{f' ({type(exc).__name__}: {exc})' if exc else ''}")
