"""The status page under clients that misbehave, at full size, beside the same demo left alone.

Each pair runs ``canguard demo --http 127.0.0.1:0 --groot2 0`` twice, alternating: once with its page
left alone (the peer), once while, from a second after the page listens until ``--leave-s`` into the run:

- ``--streams`` event streams (half ``/api/status``, half ``/api/events``) asked for and never read,
  spread over ten loopback addresses (127.0.0.1-10), a small receive buffer each;
- ``--half`` half-requests (``GET / HTTP/1.1`` and no blank line), each one the server closes opened again;
- ``--resets`` streams asked for and reset (``SO_LINGER`` 0) at once, every two seconds;
- ``--groot2-clients`` ZeroMQ REQ clients asking once and never reading, and garbage on both Groot2 ports.

The monitor process's CPU over that time is measured in both runs. Meanwhile a prober asks for
``/`` and ``/api/status`` in turn every 100 ms (a new connection each): the
slowest answer and any that failed. When the clients leave, the time until every stream place is free
again (``--free-streams`` streams accepted from four other addresses). Then the demo's own
summary of both runs: its trips and how fast each stop went out, and the tracebacks on its stderr.

    python -m benchmarks.page_abuse                 # this checkout, one pair (from the checkout's root)
    python -m benchmarks.page_abuse --repeat 2 --src /path/to/other/checkout/src
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import selectors
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

from benchmarks.kit import REPO, clean_up_on_sigterm, compiled

STOP_MS = re.compile(r"stop frames out ([0-9.]+) ms")


def demo(src: Path, duration_s: float) -> tuple[subprocess.Popen[str], Path]:
    """``canguard demo`` of the checkout at ``src`` with its monitors on ephemeral loopback ports."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    err = Path(os.environ.get("TMPDIR", "/tmp")) / f"page_abuse_{os.getpid()}.err"
    proc = subprocess.Popen([sys.executable, "-m", "canguard", "demo", "--duration", str(duration_s),
                             "--http", "127.0.0.1:0", "--groot2", "0"], env=env, text=True,
                            stdout=subprocess.PIPE, stderr=err.open("w"))
    return proc, err


def addresses(err: Path, timeout_s: float = 60.0) -> tuple[int, int]:
    """(HTTP port, Groot2 port) from the demo's log."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        text = err.read_text()
        http = re.search(r"status page on http://127\.0\.0\.1:(\d+)", text)
        groot2 = re.search(r"Groot2 monitor on [^:]+:(\d+)", text)
        if http and groot2:
            return int(http.group(1)), int(groot2.group(1))
        time.sleep(0.05)
    raise RuntimeError(f"the demo never said where its monitors listen:\n{err.read_text()}")


def stream(port: int, source: str, path: str = "/api/events") -> socket.socket:
    """A stream asked for from ``source``, never read."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)
    s.bind((source, 0))
    s.settimeout(5)
    s.connect(("127.0.0.1", port))
    s.sendall(f"GET {path} HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n\r\n".encode())
    return s


def half_request(port: int) -> socket.socket:
    """A request whose head never ends."""
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    s.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n")
    return s


class Abuse:
    """The misbehaving clients, in a thread, until :meth:`leave`."""

    def __init__(self, port: int, groot2: int, args: argparse.Namespace) -> None:
        self.port, self.groot2, self.args = port, groot2, args
        self.done = threading.Event()
        self.reopened = 0
        self.refused = 0
        """Connections the server did not accept (refused, or not within 5 s)."""
        import zmq

        self.ctx = zmq.Context()
        self.thread = threading.Thread(target=self.run, daemon=True)

    def run(self) -> None:
        args, port = self.args, self.port
        held = [s for i in range(args.streams)
                if (s := self.connect(stream, port, f"127.0.0.{1 + i % 10}", ("/api/status", "/api/events")[i % 2]))]
        sel = selectors.DefaultSelector()
        for _ in range(args.half):
            if half := self.connect(half_request, port):
                sel.register(half, selectors.EVENT_READ)
        held += self.groot2_clients()
        next_resets = 0.0
        try:
            while not self.done.is_set():
                if time.monotonic() >= next_resets:
                    next_resets = time.monotonic() + 2.0
                    for _ in range(args.resets):
                        s = self.connect(stream, port, "127.0.0.1")
                        if s is None:
                            continue
                        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                        s.close()
                for key, _ in sel.select(0.1):  # closed by the server (timeout or room made): open another
                    sel.unregister(key.fileobj)
                    key.fileobj.close()  # type: ignore[union-attr]
                    if half := self.connect(half_request, port):
                        sel.register(half, selectors.EVENT_READ)
                    self.reopened += 1
        finally:
            for key in list(sel.get_map().values()):
                key.fileobj.close()  # type: ignore[union-attr]
            for s in held:
                s.close()

    def connect(self, how: Any, *args: Any) -> socket.socket | None:
        """``how(*args)``, or None (counted) when the server does not accept the connection."""
        try:
            return how(*args)  # type: ignore[no-any-return]
        except OSError:
            self.refused += 1
            return None

    def groot2_clients(self) -> list[Any]:
        """REQ clients that ask once and never read; garbage on both ports (closed at the end, as sockets)."""
        import zmq

        out: list[Any] = []
        for p in (self.groot2, self.groot2 + 1):
            raw = self.connect(socket.create_connection, ("127.0.0.1", p), 5)
            if raw is not None:
                with contextlib.suppress(OSError):
                    raw.sendall(bytes(range(256)) * 16)
                out.append(raw)
        for i in range(self.args.groot2_clients):
            req = self.ctx.socket(zmq.REQ)
            req.setsockopt(zmq.LINGER, 0)
            req.connect(f"tcp://127.0.0.1:{self.groot2}")
            req.send_multipart([bytes([2, ord("TSB"[i % 3])]) + i.to_bytes(4, "little"), b"RobotGuard"])
        return out

    def leave(self) -> float:
        """Every client leaves; the time it happened."""
        self.done.set()
        self.thread.join(30)
        self.ctx.destroy(linger=0)
        return time.monotonic()


def monitor_cpu_s(demo_pid: int) -> float:
    """CPU seconds (user + system) the demo's monitor process (its child) used so far; 0 when not found."""
    tick = os.sysconf("SC_CLK_TCK")
    for task in Path(f"/proc/{demo_pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            with contextlib.suppress(OSError):
                fields = Path(f"/proc/{child}/stat").read_text().rsplit(")", 1)[1].split()
                return (int(fields[11]) + int(fields[12])) / tick
    return 0.0


def probe(port: int, until: threading.Event, out: list[tuple[float, float, int]]) -> None:
    """``/`` and ``/api/status`` in turn every 100 ms: (when, seconds to the whole answer, status or 0)."""
    paths = ("/", "/api/status")
    i = 0
    while not until.wait(0.1):
        start = time.monotonic()
        code = 0
        with contextlib.suppress(OSError, urllib.error.HTTPError), \
                urllib.request.urlopen(f"http://127.0.0.1:{port}{paths[i % 2]}", timeout=10) as resp:
            resp.read()
            code = resp.status
        out.append((start, time.monotonic() - start, code))
        i += 1


def places_free(port: int, streams: int) -> bool:
    """True when ``streams`` streams from four fresh addresses are all accepted."""
    socks: list[socket.socket] = []
    try:
        return all_accepted(port, streams, socks)
    except OSError:
        return False
    finally:
        for s in socks:
            s.close()


def all_accepted(port: int, streams: int, socks: list[socket.socket]) -> bool:
    """Ask for ``streams`` streams (into ``socks``); True when every one is answered 200."""
    for i in range(streams):
        s = stream(port, f"127.0.1.{1 + i % 4}")
        socks.append(s)
        if not s.recv(12).startswith(b"HTTP/1.1 200"):
            return False
    return True


def one_run(src: Path, args: argparse.Namespace, abuse: bool) -> dict[str, Any]:
    proc, err = demo(src, args.duration)
    try:
        port, groot2 = addresses(err)
        t0 = time.monotonic()
        result: dict[str, Any] = {}
        if not abuse:
            time.sleep(1.0)
            cpu0, wall0 = monitor_cpu_s(proc.pid), time.monotonic()
            time.sleep(max(0.0, args.leave_s - (time.monotonic() - t0)))
            result["monitor_cpu_pct"] = 100 * (monitor_cpu_s(proc.pid) - cpu0) / (time.monotonic() - wall0)
        else:
            probes: list[tuple[float, float, int]] = []
            stop_probing = threading.Event()
            prober = threading.Thread(target=probe, args=(port, stop_probing, probes), daemon=True)
            prober.start()
            time.sleep(1.0)
            clients = Abuse(port, groot2, args)
            cpu0, wall0 = monitor_cpu_s(proc.pid), time.monotonic()
            clients.thread.start()
            time.sleep(max(0.0, args.leave_s - (time.monotonic() - t0)))
            result["monitor_cpu_pct"] = 100 * (monitor_cpu_s(proc.pid) - cpu0) / (time.monotonic() - wall0)
            left = clients.leave()
            while not places_free(port, args.free_streams):
                if time.monotonic() - left > 30:
                    break
                time.sleep(0.05)
            result["free_after_leave_s"] = time.monotonic() - left
            stop_probing.set()
            prober.join(15)
            during = [(lat, code) for t, lat, code in probes]
            result["probes"] = len(during)
            result["probe_max_s"] = max(lat for lat, _ in during)
            result["probe_p99_s"] = sorted(lat for lat, _ in during)[int(0.99 * (len(during) - 1))]
            result["probes_failed"] = sum(code != 200 for _, code in during)
            result["half_reopened"] = clients.reopened
            result["refused"] = clients.refused
        out, _ = proc.communicate(timeout=args.duration + 60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = err.read_text()
    err.unlink()
    stops = [float(x) for x in STOP_MS.findall(out)]
    for line in out.splitlines():
        if line.startswith("  t="):
            print("   ", line.strip()[:150], file=sys.stderr)
    trips = re.search(r"trips: (\d+); stops: (\d+)", out)
    for line in [line for line in text.splitlines() if "WARNING" in line or "ERROR" in line][:12]:
        print("   ", line[:200], file=sys.stderr)
    result.update(trips=trips.group(0) if trips else "?", stop_ms_median=statistics.median(stops) if stops else None,
                  stop_ms_max=max(stops, default=None), tracebacks=text.count("Traceback"),
                  log_lines=len([line for line in text.splitlines() if "WARNING" in line or "ERROR" in line]))
    return result


def main() -> int:
    clean_up_on_sigterm()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--src", type=Path, default=REPO / "src", help="the canguard source tree to run")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--duration", type=float, default=40.0, help="each demo's run (s)")
    parser.add_argument("--leave-s", type=float, default=30.0, help="when the misbehaving clients leave (s)")
    parser.add_argument("--streams", type=int, default=100)
    parser.add_argument("--half", type=int, default=600)
    parser.add_argument("--resets", type=int, default=50)
    parser.add_argument("--groot2-clients", type=int, default=50)
    parser.add_argument("--free-streams", type=int, default=64,
                        help="streams that must all be accepted to call every place free (web.Limits.max_streams)")
    args = parser.parse_args()
    src = compiled(args.src.resolve())
    for r in range(args.repeat):
        for abuse in (False, True):
            res = one_run(src, args, abuse)
            print(f"pair {r + 1} {'abused' if abuse else 'left alone'}: "
                  + ", ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in res.items()),
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
