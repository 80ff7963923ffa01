"""Suite ``monitor``: what being watched costs the deployed daemon, beside the same daemon unwatched.

The live suite's ``canguard run`` (bundled config, udp_multicast, background traffic at ``FPS``
frames/s from a process of its own) with ``monitor: {http, groot2}`` on ephemeral loopback ports.
Blocks of trip-to-stop trials (the live suite's) take turns:

* unwatched (the peer): nobody reads the monitors;
* watched remotely: a Groot2 stand-in asks for STATUS at 50 Hz and a process reads the status page's
  event stream (``/api/status``, what the page's EventSource reads): a browser on another machine;
* watched by a browser on the robot: the page open in headless chromium beside the daemon (where
  chromium, chromedriver and selenium are installed).

Per block: trip-to-stop p50 / p99, and the CPU of the daemon and of its monitor process (``/proc``) in %
of one core over the block.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
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

    def close(self) -> int:
        """Stop it: the answers it got."""
        self.proc.send_signal(signal.SIGTERM)
        try:
            out, _ = self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.communicate()
            return -1
        return int(out.strip() or 0)


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


def run(opts: Options) -> Table:
    """The monitor table: each way of watching beside the unwatched blocks, worst (highest p99 ratio) first."""
    blocks, trials, fps = (1, 4, 1000.0) if opts.quick else (4, 100, 8000.0)
    no_browser = "--quick" if opts.quick else browser_missing()
    modes = ["unwatched", "remote: Groot2 at 50 Hz + the page's stream"] + ([] if no_browser else
                                                                         ["page in chromium here + Groot2 at 50 Hz"])
    got: dict[str, tuple[list[float], list[float], list[float]]] = {m: ([], [], []) for m in modes}
    bus = kit.multicast_bus()
    with kit.scratch("monitor") as d:
        tmp = Path(d)
        daemon = Daemon(tmp / "daemon", bus, opts.src, monitor={"http": "127.0.0.1:0", "groot2": "127.0.0.1:0"})
        peer = Peer(bus)
        chromium = None
        try:
            url, port = monitors(daemon)
            chromium = None if no_browser else Browser(tmp)
            background = Child("background", bus, opts.src, fps)
            try:
                for _ in range(blocks):
                    for mode in modes:
                        record(got[mode], watched_block(mode, peer, daemon, trials, url, port, chromium, opts.src))
            finally:
                background.close()
        finally:
            if chromium is not None:
                chromium.close()
            peer.close()
            daemon.stop()
    return table_of(got, modes, blocks, trials, fps, no_browser, opts)


def record(into: tuple[list[float], list[float], list[float]], result: tuple[list[float], float, float]) -> None:
    """Add a block's trials and CPU figures."""
    into[0].extend(result[0])
    into[1].append(result[1])
    into[2].append(result[2])


def watched_block(mode: str, peer: Peer, daemon: Daemon, trials: int, url: str, port: int, chromium: Any,
                  src: Path) -> tuple[list[float], float, float]:
    """One block of ``mode``: its watchers opened, the trials, the watchers closed."""
    watchers = []
    try:
        if mode != "unwatched":
            watchers.append(Watcher(GROOT2_POLLER.format(port=port), src))
        if mode.startswith("remote"):
            watchers.append(Watcher(PAGE_READER.format(url=url), src))
        if mode.startswith("page") and chromium is not None:
            chromium.show(url)
        return block(peer, daemon, trials)
    finally:
        for w in watchers:
            w.close()
        if mode.startswith("page") and chromium is not None:
            chromium.blank()


def table_of(got: dict[str, tuple[list[float], list[float], list[float]]], modes: list[str], blocks: int, trials: int,
             fps: float, no_browser: str | None, opts: Options) -> Table:
    """The rows: each watched mode beside the unwatched blocks."""
    table = Table("monitor", f"what watching costs `canguard run` (monitors on loopback, {fps:,.0f} frames/s "
                  f"background): {blocks} blocks of {trials} trip-to-stop trials per way, taking turns, beside the "
                  "same daemon unwatched", ["watched by", "trials", "p50 ms", "p99 ms", "daemon CPU %",
                                            "monitor process CPU %", "unwatched p99 ms", "× unwatched p99",
                                            "× unwatched daemon CPU"], costs=["p99 ms", "daemon CPU %"])
    plain = got["unwatched"]
    p99_plain, cpu_plain = kit.percentile(plain[0], 0.99) * 1e3, kit.median(plain[1])
    for mode in modes:
        trips, cpu, mon = got[mode]
        p99 = kit.percentile(trips, 0.99) * 1e3
        table.rows.append([mode, len(trips), kit.median(trips) * 1e3, p99, kit.median(cpu), kit.median(mon),
                           p99_plain, kit.ratio(p99, p99_plain), kit.ratio(kit.median(cpu), cpu_plain)])
    table.rows.sort(key=lambda r: -(r[7] if isinstance(r[7], float) else 0.0))
    table.notes.append("CPU: % of one core over the blocks' trials (median of the blocks); the monitor process is the "
                       "daemon's child")
    if no_browser:
        table.notes.append(f"the page in chromium on the robot: not measured ({no_browser})")
    if opts.quick:
        table.notes.append("--quick: one block of a few trials, no browser: checks that the suite runs")
    return table

