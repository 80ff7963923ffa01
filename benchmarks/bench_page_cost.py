"""What the status page costs the browser, per document drawn: chromium's CPU for pages fed the same documents.

Two steps, so every page variant sees the same documents at the same rate:

1. ``--record FILE``: ``canguard run`` (bench_latency's (d) daemon, its monitors on ephemeral loopback
   ports) with bench_latency's trip-and-resume trials and background traffic; the status stream's
   documents as the page would get them, one JSON document a line.
2. ``--docs FILE PAGE...``: a small server streams those documents (``event: status``, their ``seq``
   renumbered) at ``--hz`` to each page in turn in one headless chromium (bench_latency's
   ``Browser``), in ``--rounds`` interleaved rounds; chromium's CPU (user + system of its processes,
   per process so one that ends meanwhile does not count against the next page) over ``--seconds``,
   the page already open. Pages are HTML files: ``src/canguard/data/monitor/index.html`` or an edited
   copy (a page that draws less, or nothing).

    python benchmarks/bench_page_cost.py --record /tmp/docs.jsonl --seconds 25
    python benchmarks/bench_page_cost.py --docs /tmp/docs.jsonl src/canguard/data/monitor/index.html /tmp/blank.html
    python benchmarks/bench_page_cost.py --docs /tmp/docs.jsonl --hz 8 src/canguard/data/monitor/index.html

A page that sets no ``data-seq`` on its body needs it in its HTML (``<body data-seq="1">``): the
browser waits for it before measuring.
"""

from __future__ import annotations

import argparse
import http.server
import json
import os
import random
import socketserver
import statistics
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_latency as bl


def record(out: Path, seconds: float, fps: float) -> int:
    """Write the status stream's documents of a daemon under trip trials for ``seconds``; how many."""
    rnd = random.Random(3)
    group, port = bl.multicast_group(rnd)
    peer = bl.can.Bus(interface="udp_multicast", channel=group, port=port)
    docs: list[str] = []
    with tempfile.TemporaryDirectory() as d:
        daemon = bl.DaemonProcess(Path(d) / "daemon", group, port, {"http": "127.0.0.1:0", "groot2": "127.0.0.1:0"})
        try:
            url, _ = daemon.monitors()
            done = threading.Event()

            def read() -> None:
                req = urllib.request.Request(url + "api/status", headers={"Accept": "text/event-stream"})
                with urllib.request.urlopen(req) as resp:
                    for line in resp:
                        if line.startswith(b"data: "):
                            docs.append(line[6:].decode().strip())
                        if done.is_set():
                            return

            threading.Thread(target=read, daemon=True).start()
            end = time.monotonic() + seconds

            def trials() -> list[float]:
                out: list[float] = []
                while time.monotonic() < end:
                    out += bl.guard_trials(peer, 20, rnd)
                return out

            bl.with_background(group, port, fps, trials)
            done.set()
        finally:
            daemon.stop()
            peer.shutdown()
    out.write_text("".join(doc + "\n" for doc in docs), encoding="utf-8")
    return len(docs)


class _Server(socketserver.ThreadingMixIn, http.server.HTTPServer):
    daemon_threads = True

    def __init__(self, page: bytes, docs: list[str], hz: float) -> None:
        self.page, self.docs, self.hz = page, docs, hz
        super().__init__(("127.0.0.1", 0), _Handler)


class _Handler(http.server.BaseHTTPRequestHandler):
    server: _Server

    def log_message(self, format: str, *args: object) -> None:
        pass

    def do_GET(self) -> None:
        if not self.path.startswith("/api/status"):
            page = self.server.page
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(page)))
            self.end_headers()
            self.wfile.write(page)
            return
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream")
        self.end_headers()
        docs, period = self.server.docs, 1.0 / self.server.hz
        n = 0
        next_at = time.monotonic()
        try:
            while True:
                doc = json.loads(docs[n % len(docs)])
                n += 1
                doc["seq"] = n
                self.wfile.write(b"event: status\ndata: " + json.dumps(doc, separators=(",", ":")).encode() + b"\n\n")
                self.wfile.flush()
                next_at += period
                time.sleep(max(0.0, next_at - time.monotonic()))
        except OSError:
            return  # the page was closed


def measure(pages: list[Path], docs: list[str], hz: float, seconds: float, rounds: int) -> None:
    """Each page fed ``docs`` at ``hz``, ``rounds`` times interleaved; chromium's CPU in % of one core."""
    results: dict[str, list[float]] = {str(p): [] for p in pages}
    with tempfile.TemporaryDirectory() as d:
        browser = bl.Browser(Path(d))
        try:
            for _ in range(rounds):
                for page in pages:
                    server = _Server(page.read_bytes(), docs, hz)
                    threading.Thread(target=server.serve_forever, daemon=True).start()
                    try:
                        browser.show(f"http://127.0.0.1:{server.server_address[1]}/")
                        time.sleep(3.0)  # the previous page's renderer ends, this one settles
                        before, t0 = browser.cpu_by_pid(), time.perf_counter()
                        time.sleep(seconds)
                        after, wall = browser.cpu_by_pid(), time.perf_counter() - t0
                    finally:
                        browser.blank()
                        server.shutdown()
                        server.server_close()
                    cpu = sum(v - before.get(pid, 0.0) for pid, v in after.items())
                    results[str(page)].append(100 * cpu / wall)
                    print(f"  {page}: chromium {100 * cpu / wall:.1f} % of one core (load {os.getloadavg()[0]:.1f})",
                          flush=True)
        finally:
            browser.close()
    print(f"\nchromium's CPU, % of one core, {hz:g} documents/s, {rounds} rounds of {seconds:g} s: median (runs)")
    for page, values in results.items():
        print(f"  {statistics.median(values):6.1f}  ({', '.join(f'{v:.1f}' for v in values)})  {page}")


def main(argv: list[str] | None = None) -> int:
    """Record documents, or measure pages fed them."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--record", type=Path, help="write the documents of a live daemon under trials here")
    ap.add_argument("--docs", type=Path, help="feed the documents of this file to each PAGE")
    ap.add_argument("pages", type=Path, nargs="*", metavar="PAGE")
    ap.add_argument("--hz", type=float, default=10.0, help="documents per second to each page (default 10)")
    ap.add_argument("--seconds", type=float, default=12.0, help="per page and round (recording: how long)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--fps", type=float, default=4000.0, help="background frames/s while recording")
    args = ap.parse_args(argv)
    if args.record:
        print(f"{record(args.record, args.seconds, args.fps)} documents in {args.record}")
        return 0
    if not args.docs or not args.pages:
        ap.error("--record FILE, or --docs FILE and at least one PAGE")
    docs = [line for line in args.docs.read_text(encoding="utf-8").splitlines() if line]
    measure(args.pages, docs, args.hz, args.seconds, args.rounds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
