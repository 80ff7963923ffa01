"""Where watching costs the daemon: CPU and run-queue waits of every process and thread of a watched run.

bench_latency's watched set-up (``--only watched``: the in-process daemon on a virtual bus,
8,000 background frames/s, a trip and a resume every few milliseconds; watched blocks with the
status page and Groot2's monitor served by the monitor process, a Groot2 poller process asking
for STATUS at 50 Hz and, unless ``--no-browser``, the page open in headless chromium), in
alternating unwatched and watched blocks. Over each block's trials (``/proc`` read as they begin
and as they end, nothing sampled in between):

- the CPU time (user + system) of each thread of this process, grouped by name (the daemon's
  loop and bus reader, the monitor link's sender thread, the benchmark's own peer and
  background threads), of the monitor process, the Groot2 poller and chromium's processes;
- the time each of them waited runnable for a CPU (``/proc/.../schedstat``'s second field): the
  scheduler's share, which on two CPUs grows with every busy process beside the daemon;
- the machine's load: all CPUs' busy time (``/proc/stat``) over the block.

Figures are in % of one CPU over the block's wall time; per block, then the mean of each kind.

    python benchmarks/bench_watch_breakdown.py --blocks 3 --trials 300
    python benchmarks/bench_watch_breakdown.py --tree /tmp/old   # another checkout's src and bench_latency
    python benchmarks/bench_watch_breakdown.py --cross   # bench_latency's (d): the deployed daemon, a process
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

TICK = os.sysconf("SC_CLK_TCK")
THREADS = {"(run)": "daemon loop", "(background)": "bench background frames", "(echo)": "bench echo"}
"""bench_latency's unnamed threads (``Thread-N (target)``) by their target."""


def _read(path: str) -> str | None:
    try:
        with open(path, encoding="ascii") as f:
            return f.read()
    except OSError:
        return None  # ended meanwhile


def _usage(stat_dir: str) -> tuple[float, float] | None:
    """(CPU seconds, seconds waited runnable) of a process or thread directory under ``/proc``."""
    stat, sched = _read(f"{stat_dir}/stat"), _read(f"{stat_dir}/schedstat")
    if stat is None or sched is None:
        return None
    fields = stat.rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK, int(sched.split()[1]) / 1e9


def _children() -> dict[int, tuple[int, str]]:
    """{pid: (parent pid, command)} of every process."""
    out = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        text = _read(str(stat))
        if text is None:
            continue
        head, tail = text.rsplit(")", 1)
        out[int(stat.parent.name)] = (int(tail.split()[1]), head.split("(", 1)[1])
    return out


def _kind(pid: int, procs: dict[int, tuple[int, str]]) -> str | None:
    """What a descendant of this process is: the monitor process, the Groot2 poller, chromium, or None."""
    chain = []
    p = pid
    while p in procs and p != os.getpid():
        chain.append(p)
        p = procs[p][0]
    if p != os.getpid():
        return None
    cmdline = (_read(f"/proc/{pid}/cmdline") or "").replace("\0", " ")
    if "canguard.service.monitor.server" in cmdline:
        return "monitor process"
    if "canguard run" in cmdline:
        return "daemon process"
    if "'background' ==" in cmdline:
        return "bench background process"
    if "zmq.REQ" in cmdline:
        return "Groot2 poller"
    if any(procs[c][1].startswith(("chrom", "chromedriver")) for c in chain):
        return "chromium"
    return None


def descendants() -> dict[int, str]:
    """{pid: kind} of this process's watched descendants (a scan of ``/proc``: done once a second)."""
    procs = _children()
    return {pid: kind for pid in procs if (kind := _kind(pid, procs)) is not None}


def snapshot(watched: dict[int, str]) -> dict[str, tuple[float, float]]:
    """{kind: (CPU s, waited s)}: this process's threads by name, and the ``watched`` processes by kind."""
    out: dict[str, list[float]] = defaultdict(lambda: [0.0, 0.0])
    names = {t.native_id: t.name for t in threading.enumerate()}
    for task in Path("/proc/self/task").iterdir():
        used = _usage(str(task))
        if used is None:
            continue
        name = names.get(int(task.name), "other threads")
        name = "bus reader" if name.startswith("canguard-bus") else THREADS.get(name.split(" ")[-1], name)
        out[name][0] += used[0]
        out[name][1] += used[1]
    for pid, kind in watched.items():
        used = _usage(f"/proc/{pid}")
        if used is not None:
            out[kind][0] += used[0]
            out[kind][1] += used[1]
    return {k: (v[0], v[1]) for k, v in out.items()}


def busy_s() -> float:
    """All CPUs' busy seconds so far (``/proc/stat``)."""
    fields = [int(x) for x in (_read("/proc/stat") or "").splitlines()[0].split()[1:]]
    return (sum(fields) - fields[3] - fields[4]) / TICK


class Window:
    """Each kind's usage over the trials of a block: :func:`snapshot` when they begin and when they end."""

    def __init__(self) -> None:
        self.shares: dict[str, tuple[float, float]] = {}
        """{kind: (% CPU, % waited runnable)} of one CPU over the trials' wall time."""
        self.busy_pct = 0.0
        """All CPUs' busy time over the trials, in % of one CPU."""

    def around(self, trials: Callable[..., list[float]]) -> Callable[..., list[float]]:
        """``trials`` measured: bench_latency's ``guard_trials`` with a snapshot before and after."""

        def measured(*args: Any, **kwargs: Any) -> list[float]:
            watched = descendants()
            first, busy0, t0 = snapshot(watched), busy_s(), time.perf_counter()
            try:
                return trials(*args, **kwargs)
            finally:
                last, busy, wall = snapshot(watched), busy_s() - busy0, time.perf_counter() - t0
                self.shares = {k: (100 * (last[k][0] - first[k][0]) / wall, 100 * (last[k][1] - first[k][1]) / wall)
                               for k in last if k in first}
                self.busy_pct = 100 * busy / wall

        return measured


def main(argv: list[str] | None = None) -> int:
    """Run alternating blocks and print each kind's CPU and run-queue wait."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", type=Path, default=Path(__file__).resolve().parents[1],
                    help="the checkout whose src/ and benchmarks/bench_latency.py to use (default: this one)")
    ap.add_argument("--blocks", type=int, default=3, help="unwatched + watched block pairs")
    ap.add_argument("--trials", type=int, default=300, help="trip trials per block")
    ap.add_argument("--no-browser", action="store_true", help="without chromium")
    ap.add_argument("--cross", action="store_true",
                    help="bench_latency's (d) instead: one `canguard run` process on udp_multicast at nice -10, "
                         "the watchers per block (its loop, bus reads and journal thread are 'daemon process')")
    args = ap.parse_args(argv)
    sys.path[:0] = [str(args.tree / "src"), str(args.tree / "benchmarks")]
    import tempfile

    import bench_latency

    rnd = random.Random(1)
    window = Window()
    bench_latency.guard_trials = window.around(bench_latency.guard_trials)
    table: dict[tuple[bool, str], list[tuple[float, float]]] = defaultdict(list)
    busy: dict[bool, list[float]] = defaultdict(list)
    p99: dict[bool, list[float]] = defaultdict(list)
    threading.current_thread().name = "peer (bench main)"

    def record(watch: bool, lat: list[float]) -> None:
        for kind, share in window.shares.items():
            table[watch, kind].append(share)
        busy[watch].append(window.busy_pct)
        p99[watch].append(bench_latency.figures(lat)["p99"])

    if args.cross:
        bench_latency.watched_cross(args.blocks * args.trials, 8000.0, rnd, blocks=args.blocks,
                                    browser=not args.no_browser, on_block=record)
    else:
        with tempfile.TemporaryDirectory() as d:
            browser = None if args.no_browser else bench_latency.Browser(Path(d))
            try:
                for _ in range(args.blocks):
                    for watch in (False, True):
                        record(watch, bench_latency.watched_block(args.trials, 8000.0, rnd, browser, watch=watch))
            finally:
                if browser is not None:
                    browser.close()
    print(f"\n{args.tree}: {args.blocks} block pairs of {args.trials} trials, {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.1f}; % of one CPU, mean over blocks (CPU used / waited runnable)")
    kinds = sorted({k for _, k in table}, key=lambda k: -statistics.mean(c for c, _ in table[True, k] or [(0, 0)]))
    print(f"  {'':28} {'unwatched':>16} {'watched':>16}")
    for kind in kinds:
        cells = []
        for watch in (False, True):
            rows = table[watch, kind]
            cells.append(f"{statistics.mean(c for c, _ in rows):6.1f} / {statistics.mean(w for _, w in rows):6.1f}"
                         if rows else f"{'-':>16}")
        print(f"  {kind:28} {cells[0]:>16} {cells[1]:>16}")
    print(f"  {'all CPUs busy (machine)':28} {statistics.mean(busy[False]):16.1f} {statistics.mean(busy[True]):16.1f}")
    print(f"  {'p99 trip-to-stop ms (blocks)':28} {statistics.median(p99[False]):16.2f} "
          f"{statistics.median(p99[True]):16.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
