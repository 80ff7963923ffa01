"""The status page's server under clients that misbehave, over real sockets: it always answers, frees at once.

These run the server in this process around a hub with nothing published (no daemon: the page and
``/api/status`` answer from the hub's empty document), with limits small enough to reach in a few
connections; ``tests/test_monitor_web.py`` does the same at the default limits against a running daemon.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import struct
import urllib.error
import urllib.request
from collections.abc import Iterator

import pytest

from canguard.config.monitor import Address
from canguard.service.monitor.hub import Hub
from canguard.service.monitor.web import Limits, WebMonitor
from monitorkit import wait_for

LIMITS = Limits(max_streams=6, streams_per_address=4, request_timeout_s=1.0, max_connections=20)


@contextlib.contextmanager
def serving(limits: Limits) -> Iterator[WebMonitor]:
    """A status page server on an ephemeral loopback port with ``limits``, around a hub of its own."""
    web = WebMonitor(Address("127.0.0.1", 0), Hub(), None, limits)
    web.start()
    try:
        yield web
    finally:
        web.close()


@pytest.fixture
def server() -> Iterator[WebMonitor]:
    """A status page server with :data:`LIMITS`."""
    with serving(LIMITS) as web:
        yield web


def connect(web: WebMonitor, source: str = "127.0.0.1") -> socket.socket:
    """A TCP connection to ``web`` from the loopback address ``source`` (all of 127/8 is this machine)."""
    sock = socket.socket()
    sock.bind((source, 0))
    sock.connect((web.address.host, web.address.port))
    return sock


def open_stream(web: WebMonitor, source: str = "127.0.0.1", path: str = "/api/events") -> tuple[socket.socket, int]:
    """Ask for an event stream and read its status line only: (the connection, the status code)."""
    sock = connect(web, source)
    sock.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n\r\n".encode())
    sock.settimeout(5)
    line = b""
    while not line.endswith(b"\r\n"):
        byte = sock.recv(1)
        if not byte:
            break
        line += byte
    return sock, int(line.split()[1]) if line else 0


def reset(sock: socket.socket) -> None:
    """Close with a TCP reset (SO_LINGER 0), as a killed browser or a crashed client does."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    sock.close()


def page_answers(web: WebMonitor) -> bool:
    """``GET /`` and ``GET /api/status`` both answer 200 with their documents."""
    base = f"http://{web.address.host}:{web.address.port}"
    with urllib.request.urlopen(base + "/", timeout=5) as resp:
        page = resp.status == 200 and b"<html" in resp.read()
    with urllib.request.urlopen(base + "/api/status", timeout=5) as resp:
        status = resp.status == 200 and b'"tree"' in resp.read()
    return page and status


@contextlib.contextmanager
def closing(socks: list[socket.socket]) -> Iterator[list[socket.socket]]:
    """``socks``, each closed at exit."""
    try:
        yield socks
    finally:
        for sock in socks:
            sock.close()


class TestStreamPlaces:
    """Event streams have places of their own, capped in all and per address."""

    def test_streams_never_lock_out_the_page(self, server: WebMonitor) -> None:
        """Past the per-address and total caps a stream is refused (503); the page and the JSON still answer."""
        with closing([]) as held:
            for _ in range(LIMITS.streams_per_address):
                sock, code = open_stream(server)
                held.append(sock)
                assert code == 200
            sock, code = open_stream(server)
            held.append(sock)
            assert code == 503  # this address has all its places
            for source in ("127.0.0.2", "127.0.0.3"):  # another address still gets one, up to the total
                sock, code = open_stream(server, source, "/api/status")
                held.append(sock)
                assert code == 200
            sock, code = open_stream(server, "127.0.0.4")
            held.append(sock)
            assert code == 503  # every stream place is taken
            assert page_answers(server)

    def test_a_stream_whose_client_left_frees_its_place_at_once(self, server: WebMonitor) -> None:
        """Streams closed or reset by their clients are free again with nothing written to them (no news)."""
        streams = [open_stream(server) for _ in range(LIMITS.streams_per_address)]
        assert [code for _, code in streams] == [200] * LIMITS.streams_per_address
        for i, (sock, _) in enumerate(streams):
            if i % 2:
                reset(sock)
            else:
                sock.close()
        with closing([]) as reopened:

            def a_place_is_free() -> bool:
                sock, code = open_stream(server)
                (reopened if code == 200 else [sock]).append(sock)
                if code != 200:
                    sock.close()
                return len(reopened) == LIMITS.streams_per_address

            # nothing is written to an idle stream before its keep-alive comment (15 s): a server that notices a
            # client's end only when a write fails holds every place well past this wait
            wait_for("every place of the streams that left", a_place_is_free, timeout_s=5.0)


class TestRequests:
    """Half-sent, idle, oversized and garbage requests."""

    def test_half_requests_make_room_for_new_connections(self) -> None:
        """Thrice the connection places in half-requests: the oldest are closed for the newest; the page answers."""
        limits = Limits(max_connections=20, request_timeout_s=60.0)
        with serving(limits) as web, closing([]) as half:
            for _ in range(3 * limits.max_connections):
                sock = connect(web)
                sock.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n")  # and never the blank line
                half.append(sock)
            assert page_answers(web)
            half[0].settimeout(5)
            with contextlib.suppress(ConnectionResetError):  # closed with its request unread: a reset
                assert half[0].recv(1) == b""  # the oldest: closed long before its request timeout
            half[-1].setblocking(False)
            with pytest.raises(BlockingIOError):
                half[-1].recv(1)  # the newest: still open, waiting for the rest of its request

    def test_a_half_request_is_closed_after_the_request_timeout(self, server: WebMonitor) -> None:
        """A request head that never ends is closed, unanswered, once ``request_timeout_s`` is over."""
        with contextlib.closing(connect(server)) as sock:
            sock.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n")
            sock.settimeout(LIMITS.request_timeout_s + 5)
            assert sock.recv(1) == b""

    @pytest.mark.parametrize(("request_bytes", "code"), [
        (b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03\r\n\r\n", 400),  # a TLS hello, on the plain port
        (b"GET / HTTP/1.1\r\nno colon here\r\n\r\n", 400),
        (b"GET / HTTP/1.1\r\nX-Long: " + b"a" * 20000 + b"\r\n\r\n", 431),
        (b"POST /api/status HTTP/1.1\r\nContent-Length: 2\r\n\r\n{}", 405),
    ])
    def test_bad_requests_are_answered_and_closed(self, server: WebMonitor, request_bytes: bytes, code: int) -> None:
        """A request that is not HTTP, has a bad header, is too large or writes gets its error, then the end."""
        with contextlib.closing(connect(server)) as sock:
            sock.sendall(request_bytes)
            sock.settimeout(5)
            answer = b""
            while chunk := sock.recv(65536):
                answer += chunk
            assert answer.split(b"\r\n", 1)[0].split()[1] == str(code).encode()
        assert page_answers(server)

    def test_keep_alive_serves_several_requests_on_one_connection(self, server: WebMonitor) -> None:
        """Two requests on one HTTP/1.1 connection, sent together, get two answers in order."""
        with contextlib.closing(connect(server)) as sock:
            sock.sendall(b"GET /api/status HTTP/1.1\r\nHost: x\r\n\r\nGET /nothing HTTP/1.1\r\nHost: x\r\n\r\n")
            sock.settimeout(5)
            answer = b""
            while answer.count(b"HTTP/1.1 ") < 2 or not answer.endswith(b"/api/events\n"):
                answer += sock.recv(65536)
            assert [part.split(b"\r\n", 1)[0] for part in answer.split(b"HTTP/1.1 ")[1:]] == [b"200 OK",
                                                                                           b"404 Not Found"]


def test_misbehaving_clients_are_logged_one_line_per_cause(server: WebMonitor,
                                                           caplog: pytest.LogCaptureFixture) -> None:
    """Ten resets and ten garbage requests make one line each, and no traceback."""
    caplog.set_level(logging.WARNING, logger="canguard.service.monitor")
    for _ in range(10):
        sock, _ = open_stream(server, "127.0.0.5")
        reset(sock)
        with contextlib.closing(connect(server)) as sock:
            sock.sendall(b"\x00\x01garbage\r\n\r\n")
            sock.settimeout(5)
            while sock.recv(4096):
                pass
    wait_for("both causes logged", lambda: len({r.getMessage()[:40] for r in caplog.records}) >= 2, timeout_s=5)
    assert page_answers(server)
    messages = [r.getMessage() for r in caplog.records]
    assert sum("malformed request line" in m for m in messages) == 1
    assert sum("reset" in m for m in messages) == 1
    assert not any(r.exc_info for r in caplog.records)
