"""Suite ``monitor``: what being watched costs the deployed daemon, beside the same daemon unwatched.

The live suite's ``canguard run`` (bundled config, udp_multicast, background traffic at ``FPS``
frames/s from a process of its own) with ``monitor: {http, groot2}`` on ephemeral loopback ports.
Blocks of trip-to-stop trials (the live suite's) take turns:

* unwatched (the peer): nobody reads the monitors;
* watched remotely: a Groot2 stand-in asks for STATUS at 50 Hz and a process reads the status page's
  event stream (``/api/status``, what the page's EventSource reads): a browser on another machine;
* watched by a browser on the robot: the page open in headless chromium beside the daemon (where
  chromium, chromedriver and selenium are installed);
* misbehaving clients (a process of their own, :func:`misbehave`): event streams asked for and never
  read, spread over ten loopback addresses (a small receive buffer each); half-requests (``GET /
  HTTP/1.1`` and no blank line), each one the server closes opened again; streams reset (``SO_LINGER``
  0) at once, every two seconds; ZeroMQ REQ clients asking once and never reading, and garbage on both
  Groot2 ports. Meanwhile a prober asks for ``/`` and ``/api/status`` in turn every 100 ms (a new
  connection each). When the clients leave: the time until every stream place is free again (as many
  streams as the server grants, accepted from four other addresses).

Per block: trip-to-stop p50 / p99, and the CPU of the daemon and of its monitor process (``/proc``) in %
of one core over the block. The misbehaving clients' block adds the prober's answers, the places freed,
and the tracebacks on the daemon's stderr over the run (none: a check of the suite).
"""

from __future__ import annotations

import contextlib
import json
import re
import selectors
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from benchmarks import kit
from benchmarks.kit import Options, Table
from benchmarks.live import Child, Daemon, Peer

GROOT2_POLLER = """
import signal, threading, zmq
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *a: stop.set())
sock = zmq.Context().socket(zmq.REQ)
sock.setsockopt(zmq.LINGER, 0)
sock.connect("tcp://127.0.0.1:{port}")
polls = 0
while not stop.wait(1.0 / 50):
    sock.send_multipart([bytes([2, ord("S")]) + polls.to_bytes(4, "little")])
    while not stop.is_set() and not sock.poll(100):
        pass
    if stop.is_set():
        break
    sock.recv_multipart()
    polls += 1
    if polls == 1:
        print("ready", flush=True)
print(polls, flush=True)
"""
"""A Groot2 stand-in: STATUS requests at 50 Hz (Groot2's framing) until SIGTERM; prints the replies it got."""

PAGE_READER = """
import signal, socket, threading, urllib.parse
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *a: stop.set())
url = urllib.parse.urlsplit({url!r})
sock = socket.create_connection((url.hostname, url.port), timeout=10)
sock.sendall(b"GET /api/status HTTP/1.1\\r\\nHost: x\\r\\nAccept: text/event-stream\\r\\n\\r\\n")
sock.settimeout(0.1)
documents, tail = 0, b""
while not stop.is_set():
    try:
        chunk = sock.recv(1 << 16)
    except socket.timeout:
        continue
    if not chunk:
        break
    events = (tail + chunk).split(b"\\n\\n")
    tail = events.pop()
    if not documents and events:
        print("ready", flush=True)
    documents += len(events)
print(documents, flush=True)
"""
"""The page's reader on another machine: reads the status stream and counts its documents until SIGTERM."""

MONITOR_AT = (re.compile(r"status page on (http://[0-9.:]+/)"), re.compile(r"Groot2 monitor on [0-9.]+:(\d+)"))
"""What the daemon says at start where its status page and Groot2's monitor listen."""


class Watcher:
    """A watcher process: ready once it got its first answer; :meth:`close` gives how many it got."""

    def __init__(self, code: str, src: Path) -> None:
        self.proc = subprocess.Popen([sys.executable, "-c", code], env=kit.child_env(src), stdout=subprocess.PIPE,
                                     text=True)
        assert self.proc.stdout is not None
        if self.proc.stdout.readline().strip() != "ready":
            kit.stop_process(self.proc)
            raise RuntimeError("a watcher got no answer from the daemon's monitors")

    def close(self, timeout_s: float = 10.0) -> str:
        """Stop it: the last line it printed (what it counted)."""
        self.proc.send_signal(signal.SIGTERM)
        try:
            out, _ = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.communicate()
            return ""
        return out.strip().rsplit("\n", 1)[-1]


@dataclass
class Misbehaviour:
    """How many misbehaving clients of each kind (see the module's docstring)."""

    streams: int
    half: int
    resets: int
    groot2_clients: int
    free_streams: int
    """Streams that must all be accepted to call every place free: the server's ``max_streams``."""


def stream(port: int, source: str, path: str = "/api/events") -> socket.socket:
    """An event stream asked for from ``source``, never read."""
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

    def __init__(self, port: int, groot2: int, sizes: Misbehaviour) -> None:
        import zmq

        self.port, self.groot2, self.sizes = port, groot2, sizes
        self.done = threading.Event()
        self.reopened = 0
        self.refused = 0
        """Connections the server did not accept (refused, or not within 5 s)."""
        self.ctx = zmq.Context()
        self.thread = threading.Thread(target=self.run, daemon=True)

    def run(self) -> None:
        """Open the clients, keep the half-requests and resets coming until :meth:`leave`, close them."""
        port, n = self.port, self.sizes
        held = [s for i in range(n.streams)
                if (s := self.connect(stream, port, f"127.0.0.{1 + i % 10}", ("/api/status", "/api/events")[i % 2]))]
        sel = selectors.DefaultSelector()
        for _ in range(n.half):
            if half := self.connect(half_request, port):
                sel.register(half, selectors.EVENT_READ)
        held += self.groot2_clients()
        next_resets = 0.0
        try:
            while not self.done.is_set():
                if time.monotonic() >= next_resets:
                    next_resets = time.monotonic() + 2.0
                    self.resets()
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

    def resets(self) -> None:
        """Streams asked for and reset at once."""
        for _ in range(self.sizes.resets):
            s = self.connect(stream, self.port, "127.0.0.1")
            if s is not None:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
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
        for i in range(self.sizes.groot2_clients):
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


def probe(port: int, until: threading.Event, out: list[tuple[float, int]]) -> None:
    """``/`` and ``/api/status`` in turn every 100 ms, a new connection each: (seconds to the whole answer,
    status or 0)."""
    paths = ("/", "/api/status")
    i = 0
    while not until.wait(0.1):
        start = time.monotonic()
        code = 0
        with contextlib.suppress(OSError, urllib.error.HTTPError), \
                urllib.request.urlopen(f"http://127.0.0.1:{port}{paths[i % 2]}", timeout=10) as resp:
            resp.read()
            code = resp.status
        out.append((time.monotonic() - start, code))
        i += 1


def places_free(port: int, streams: int) -> bool:
    """True when ``streams`` streams from four fresh addresses are all answered 200."""
    socks: list[socket.socket] = []
    try:
        for i in range(streams):
            socks.append(stream(port, f"127.0.1.{1 + i % 4}"))
            if not socks[-1].recv(12).startswith(b"HTTP/1.1 200"):
                return False
        return True
    except OSError:
        return False
    finally:
        for s in socks:
            s.close()


def misbehave(port: int, groot2: int, sizes: dict[str, int]) -> None:
    """The misbehaving clients' process: the prober and the clients until SIGTERM ("ready" printed once they are
    connected); then they leave, and it prints what it saw as one JSON line."""
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_a: stop.set())
    n = Misbehaviour(**sizes)
    probes: list[tuple[float, int]] = []
    stop_probing = threading.Event()
    prober = threading.Thread(target=probe, args=(port, stop_probing, probes), daemon=True)
    prober.start()
    clients = Abuse(port, groot2, n)
    clients.thread.start()
    print("ready", flush=True)
    stop.wait()
    left = clients.leave()
    while not places_free(port, n.free_streams) and time.monotonic() - left < 30:
        time.sleep(0.05)
    free_s = time.monotonic() - left
    stop_probing.set()
    prober.join(15)
    answers = sorted(lat for lat, _ in probes)
    print(json.dumps({"probes": len(probes), "probes_failed": sum(code != 200 for _, code in probes),
                      "probe_max_s": answers[-1] if answers else None,
                      "probe_p99_s": kit.percentile(answers, 0.99) if answers else None, "free_after_leave_s": free_s,
                      "half_reopened": clients.reopened, "refused": clients.refused}), flush=True)


class Browser:
    """One headless chromium for the whole run (its start-up not measured), the page open or about:blank."""

    def __init__(self, tmp: Path) -> None:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service

        options = webdriver.ChromeOptions()
        options.binary_location = str(kit.which("chromium"))
        for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                    "--disable-background-networking", "--no-first-run", f"--user-data-dir={tmp / 'profile'}"):
            options.add_argument(arg)
        self.driver = webdriver.Chrome(service=Service(executable_path=kit.which("chromedriver")), options=options)

    def show(self, url: str) -> None:
        """Open the page and wait until it drew its first document."""
        self.driver.get(url)
        deadline = time.monotonic() + 30
        while not int(self.driver.execute_script("return document.body.dataset.seq || 0") or 0):
            if time.monotonic() > deadline:
                raise RuntimeError("the status page did not render")
            time.sleep(0.05)

    def blank(self) -> None:
        self.driver.get("about:blank")

    def close(self) -> None:
        self.driver.quit()


def browser_missing() -> str | None:
    """Why the page cannot be opened in a browser here, or None."""
    missing = [t for t in ("chromium", "chromedriver") if kit.which(t) is None]
    try:
        import selenium  # noqa: F401
    except ImportError:
        missing.append("selenium")
    return f"{' and '.join(missing)} not installed" if missing else None


def monitors(daemon: Daemon) -> tuple[str, int]:
    """The status page's URL and Groot2's port, as the daemon said at start."""
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        said = "".join(daemon.said)
        http, groot2 = MONITOR_AT[0].search(said), MONITOR_AT[1].search(said)
        if http and groot2:
            return http.group(1), int(groot2.group(1))
        time.sleep(0.02)
    raise RuntimeError(f"the daemon did not say where its monitors listen: {''.join(daemon.said)[-1000:]!r}")


def family(pid: int) -> list[int]:
    """``pid`` and its descendants."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        kids = Path(f"/proc/{p}/task/{p}/children")
        if kids.exists():
            todo += [int(k) for k in kids.read_text().split()]
    return out


def block(peer: Peer, daemon: Daemon, trials: int) -> tuple[list[float], float, float]:
    """``trials`` trip-to-stop trials: (seconds each, daemon CPU % and its children's (the monitor) over them)."""
    kids = [p for p in family(daemon.proc.pid) if p != daemon.proc.pid]
    cpu0, kid0, t0 = daemon.cpu_s(), sum(kit.cpu_of(k) for k in kids), time.perf_counter()
    trips = [peer.trip() for _ in range(trials)]
    wall = time.perf_counter() - t0
    kid1 = sum(kit.cpu_of(k) for k in kids)
    return trips, 100 * (daemon.cpu_s() - cpu0) / wall, 100 * (kid1 - kid0) / wall


REMOTE, BROWSER, ABUSED = ("remote: Groot2 at 50 Hz + the page's stream", "page in chromium here + Groot2 at 50 Hz",
                            "misbehaving clients + a prober")
Got = tuple[list[float], list[float], list[float]]
"""A mode's trip-to-stop seconds, and per block the daemon's and its monitor process's CPU %."""


@dataclass
class Run:
    """What every block of a run shares."""

    peer: Peer
    daemon: Daemon
    trials: int
    url: str
    port: int
    chromium: Any
    src: Path
    sizes: Misbehaviour
    min_abuse_s: float
    abused: list[dict[str, Any]]
    """What the misbehaving clients' process saw, a document per block."""


def run(opts: Options) -> Table:
    """The monitor table: each way of watching beside the unwatched blocks, worst (highest ratio) first."""
    from canguard.service.monitor.web import Limits

    blocks, trials, fps = (1, 4, 1000.0) if opts.quick else (4, 100, 8000.0)
    sizes = Misbehaviour(4, 6, 2, 2, Limits().max_streams) if opts.quick else \
        Misbehaviour(100, 600, 50, 50, Limits().max_streams)
    no_browser = "--quick" if opts.quick else browser_missing()
    modes = ["unwatched", REMOTE, ABUSED] + ([] if no_browser else [BROWSER])
    got: dict[str, Got] = {m: ([], [], []) for m in modes}
    bus = kit.multicast_bus()
    with kit.scratch("monitor") as d:
        tmp = Path(d)
        daemon = Daemon(tmp / "daemon", bus, opts.src, monitor={"http": "127.0.0.1:0", "groot2": "127.0.0.1:0"})
        peer = Peer(bus)
        chromium = None
        try:
            url, port = monitors(daemon)
            chromium = None if no_browser else Browser(tmp)
            ctx = Run(peer, daemon, trials, url, port, chromium, opts.src, sizes, 0.0 if opts.quick else 6.0, [])
            background = Child("background", bus, opts.src, fps)
            try:
                for _ in range(blocks):
                    for mode in modes:
                        record(got[mode], watched_block(mode, ctx))
            finally:
                background.close()
        finally:
            if chromium is not None:
                chromium.close()
            peer.close()
            daemon.stop()
    table = table_of(got, modes, blocks, trials, fps)
    abuse_rows(table, ctx.abused, sizes, "".join(daemon.said).count("Traceback"))
    notes(table, sizes, no_browser, opts)
    return table


def record(into: Got, result: tuple[list[float], float, float]) -> None:
    """Add a block's trials and CPU figures."""
    into[0].extend(result[0])
    into[1].append(result[1])
    into[2].append(result[2])


def watched_block(mode: str, ctx: Run) -> tuple[list[float], float, float]:
    """One block of ``mode``: its watchers opened, the trials, the watchers closed."""
    watchers = []
    abuser = None
    try:
        t0 = time.monotonic()
        if mode in (REMOTE, BROWSER):
            watchers.append(Watcher(GROOT2_POLLER.format(port=ctx.port), ctx.src))
        if mode == REMOTE:
            watchers.append(Watcher(PAGE_READER.format(url=ctx.url), ctx.src))
        if mode == BROWSER and ctx.chromium is not None:
            ctx.chromium.show(ctx.url)
        if mode == ABUSED:
            http_port = int(ctx.url.rstrip("/").rsplit(":", 1)[1])
            abuser = Watcher(f"import sys; sys.path.insert(0, {str(kit.REPO)!r}); from benchmarks.monitor import "
                             f"misbehave; misbehave({http_port}, {ctx.port}, {asdict(ctx.sizes)!r})", ctx.src)
        result = block(ctx.peer, ctx.daemon, ctx.trials)
        if abuser is not None:  # long enough for the half-requests' timeouts to close them
            time.sleep(max(0.0, ctx.min_abuse_s - (time.monotonic() - t0)))
            ctx.abused.append(json.loads(abuser.close(60.0)))
        return result
    finally:
        for w in watchers + ([abuser] if abuser is not None else []):
            if w.proc.poll() is None:
                w.close()
        if mode == BROWSER and ctx.chromium is not None:
            ctx.chromium.blank()


def table_of(got: dict[str, Got], modes: list[str], blocks: int, trials: int, fps: float) -> Table:
    """The rows: each watched mode's figures beside the unwatched blocks'."""
    table = Table("monitor", f"what watching costs `canguard run` (monitors on loopback, {fps:,.0f} frames/s "
                  f"background): {blocks} blocks of {trials} trip-to-stop trials per way, taking turns, beside the "
                  "same daemon unwatched; then what misbehaving clients got",
                  ["watched by", "measure", "figure", "unwatched", "× unwatched", "unit"], costs=["figure"])
    figures = {m: {"trip → stop p50": (kit.median(trips) * 1e3, "ms"),
                   "trip → stop p99": (kit.percentile(trips, 0.99) * 1e3, "ms"),
                   "daemon CPU": (kit.median(cpu), "% of a core"),
                   "monitor process CPU": (kit.median(mon), "% of a core")}
               for m, (trips, cpu, mon) in got.items()}
    for mode in modes[1:]:
        for measure, (figure, unit) in figures[mode].items():
            plain = figures["unwatched"][measure][0]
            table.rows.append([mode, measure, figure, plain, kit.ratio(figure, plain), unit])
    table.rows.sort(key=lambda r: -(r[4] if isinstance(r[4], float) else 0.0))
    return table


def abuse_rows(table: Table, docs: list[dict[str, Any]], sizes: Misbehaviour, tracebacks: int) -> None:
    """The misbehaving clients' own figures, over their blocks; a traceback fails the suite."""
    probes = sum(d["probes"] for d in docs)
    slowest = max((d["probe_max_s"] for d in docs if d["probe_max_s"] is not None), default=None)
    table.rows += [
        [ABUSED, "probes of / and /api/status sent", probes, None, None, "probes"],
        [ABUSED, "probes of / and /api/status answered 200", probes - sum(d["probes_failed"] for d in docs), None,
         None, "probes"],
        [ABUSED, "slowest probe answer", None if slowest is None else slowest * 1e3, None, None, "ms"],
        [ABUSED, f"every stream place free again ({sizes.free_streams} new streams accepted), after the clients left",
         max(d["free_after_leave_s"] for d in docs), None, None, "s (worst block)"],
        [ABUSED, "half-requests closed by the server and opened again", sum(d["half_reopened"] for d in docs), None,
         None, "connections"],
        [ABUSED, "misbehaving clients' connections refused", sum(d["refused"] for d in docs), None, None,
         "connections"],
        [ABUSED, "tracebacks on the daemon's stderr (the whole run)", tracebacks, None, None, "count"]]
    if tracebacks:
        table.failed = f"{tracebacks} traceback(s) on the daemon's stderr"


def notes(table: Table, sizes: Misbehaviour, no_browser: str | None, opts: Options) -> None:
    """What the table's rows mean."""
    table.notes += [
        "× unwatched: the figure over the same daemon's unwatched blocks' (above 1: watching costs); worst first",
        "CPU: % of one core over the blocks' trials (median of the blocks); the monitor process is the daemon's child",
        f"misbehaving clients: {sizes.streams} event streams never read (ten loopback addresses), {sizes.half} "
        f"half-requests kept open, {sizes.resets} resets every 2 s, {sizes.groot2_clients} Groot2 REQ clients that "
        "never read, garbage on both Groot2 ports; a prober asks for / and /api/status in turn every 100 ms"]
    if no_browser:
        table.notes.append(f"the page in chromium on the robot: not measured ({no_browser})")
    if opts.quick:
        table.notes.append("--quick: one block of a few trials, a few misbehaving clients, no browser: checks that "
                           "the suite runs")
