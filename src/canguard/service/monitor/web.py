"""The status page and its API, on the standard library's threading HTTP server.

``GET /`` the page (one self-contained document: no external script, style or font);
``GET /api/status`` the JSON document (or, asked with ``Accept: text/event-stream``, a stream of it:
one ``status`` event per change); ``GET /api/events`` the journal events as server-sent events
(the kept ones first). Read-only: every other method is refused with 405. With a token, every
request must carry ``Authorization: Bearer TOKEN`` (or ``?token=TOKEN``: a browser's EventSource
cannot set headers). Each connection has its own thread with a send timeout: a client that stops
reading is dropped, and nothing it does reaches the engine (see :mod:`.hub`).
"""

from __future__ import annotations

import hmac
import json
import logging
import socket
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import parse_qs, urlsplit

from canguard.config.monitor import Address
from canguard.data import data_path
from canguard.service.monitor.hub import Hub

log = logging.getLogger(__name__)

SEND_TIMEOUT_S = 5.0
"""A client that takes longer to accept a write is dropped."""
KEEPALIVE_S = 15.0
"""A stream with nothing new sends a comment this often (proxies and browsers keep it open)."""
MAX_CLIENTS = 32
"""Connections served at once; more get 503 (a monitor must not eat the daemon's memory)."""


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    block_on_close = False

    def __init__(self, address: tuple[str, int], hub: Hub, token: str | None, page: bytes) -> None:
        self.address_family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self.hub = hub
        self.token = token
        self.page = page
        self.slots = threading.BoundedSemaphore(MAX_CLIENTS)
        super().__init__(address, _Handler)


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    protocol_version = "HTTP/1.1"
    server_version = "canguard-monitor"

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("%s " + format, self.address_string(), *args)

    def setup(self) -> None:
        super().setup()
        self.connection.settimeout(SEND_TIMEOUT_S)

    # -- read-only ---------------------------------------------------------------------------
    def _refuse(self) -> None:
        self._send(405, b"read-only: canguard's monitor answers GET only\n", "text/plain; charset=utf-8",
                   {"Allow": "GET, HEAD"})

    do_POST = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = _refuse

    def do_HEAD(self) -> None:
        self.do_GET()

    def do_GET(self) -> None:
        url = urlsplit(self.path)
        if not self._authorized(url.query):
            self._send(401, b"a bearer token is required (Authorization: Bearer TOKEN, or ?token=TOKEN)\n",
                       "text/plain; charset=utf-8", {"WWW-Authenticate": 'Bearer realm="canguard"'})
            return
        if not self.server.slots.acquire(blocking=False):
            self._send(503, b"too many monitor clients\n", "text/plain; charset=utf-8", {"Retry-After": "5"})
            return
        try:
            self._route(url.path)
        except (OSError, ValueError):  # the client went away or stalled past SEND_TIMEOUT_S
            self.close_connection = True
        finally:
            self.server.slots.release()

    def _route(self, path: str) -> None:
        if path in ("/", "/index.html"):
            self._send(200, self.server.page, "text/html; charset=utf-8", {
                "Content-Security-Policy": "default-src 'none'; script-src 'unsafe-inline'; "
                                           "style-src 'unsafe-inline'; connect-src 'self'; img-src data:",
            })
        elif path == "/api/status":
            if "text/event-stream" in self.headers.get("Accept", ""):
                self._stream_status()
            else:
                _, doc = self.server.hub.status_document()
                self._send(200, doc, "application/json")
        elif path == "/api/events":
            self._stream_events()
        else:
            self._send(404, b"not found: try /, /api/status or /api/events\n", "text/plain; charset=utf-8")

    def _authorized(self, query: str) -> bool:
        token = self.server.token
        if not token:
            return True
        given = self.headers.get("Authorization", "")
        if given.startswith("Bearer ") and hmac.compare_digest(given[7:].strip().encode(), token.encode()):
            return True
        asked = parse_qs(query).get("token", [""])[0]
        return bool(asked) and hmac.compare_digest(asked.encode(), token.encode())

    def _send(self, code: int, body: bytes, ctype: str, headers: dict[str, str] | None = None) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        for k, v in (headers or {}).items():
            self.send_header(k, v)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    # -- streams -----------------------------------------------------------------------------
    def _open_stream(self) -> bool:
        """Send a stream's headers; False for HEAD (no body follows)."""
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Accel-Buffering", "no")
        self.end_headers()
        self.close_connection = True  # a stream ends with its connection
        return self.command != "HEAD"

    def _stream_status(self) -> None:
        hub = self.server.hub
        if not self._open_stream():
            return
        sent = -1
        while not hub.closed:
            version, doc = hub.status_document()
            if version != sent:
                self.wfile.write(b"event: status\ndata: " + doc + b"\n\n")
                self.wfile.flush()
                sent = version
            elif hub.wait(version, KEEPALIVE_S) == version and not hub.closed:
                self.wfile.write(b": keep-alive\n\n")
                self.wfile.flush()

    def _stream_events(self) -> None:
        hub = self.server.hub
        if not self._open_stream():
            return
        cursor = 0
        version = -1
        while not hub.closed:
            events, lost = hub.events_after(cursor)
            if lost:
                self.wfile.write(b"event: lost\ndata: " + json.dumps({"events": lost}).encode() + b"\n\n")
            for seq, line in events:
                self.wfile.write(b"id: %d\ndata: " % seq + line.rstrip(b"\n") + b"\n\n")
                cursor = seq
            self.wfile.flush()
            new = hub.wait(version, KEEPALIVE_S)
            if new == version and not hub.closed:
                self.wfile.write(b": keep-alive\n\n")
            version = new


class WebMonitor:
    """The HTTP server of the status page, in its own thread."""

    def __init__(self, address: Address, hub: Hub, token: str | None) -> None:
        page = data_path("monitor", "index.html").read_bytes()
        self._server = _Server((address.host, address.port), hub, token, page)
        host, port = self._server.server_address[:2]
        self.address = Address(str(host), int(port))
        """Where it listens (the port the system gave for port 0)."""
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.2},
                                        name="canguard-monitor-http", daemon=True)

    def start(self) -> None:
        """Serve in a thread of its own."""
        self._thread.start()

    def close(self) -> None:
        """Stop serving; streams end as the hub closes."""
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(2)
