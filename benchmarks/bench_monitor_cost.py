"""What the monitors cost the daemon's own interpreter: CPU of their threads there, and the engine thread's publish.

The latency a stop waits for the monitors is the time they hold the daemon's GIL. On a shared
machine the trip-to-stop tail (``bench_latency.py --only watched``) moves with the load more than
with them; this counts their share directly, which the load hardly moves: bench_latency's watched
in-process daemon (status page and Groot2 monitor on loopback, a Groot2 poller process asking for
STATUS at 50 Hz, 8,000 background frames/s, the trip and resume trials), with

- the CPU time of the daemon's threads named ``canguard-monitor-*`` (``/proc/self/task/*/stat``,
  sampled every 20 ms, 10 ms resolution), in % of the run's wall time;
- :meth:`Observer.publish` on the engine's thread: calls per second, wall and CPU time per call
  (``time.perf_counter`` / ``time.thread_time`` around it: benchmarks only, the product has no hook).

    PYTHONPATH=src python benchmarks/bench_monitor_cost.py --blocks 3 --trials 300
    python benchmarks/bench_monitor_cost.py --tree /path/to/other/checkout   # the same for another commit
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Any

THREAD_PREFIX = "canguard-monitor"
"""The daemon's monitor threads are named ``canguard-monitor-*``."""


def thread_cpu_s() -> dict[int, tuple[str, float]]:
    """{native thread id: (Python thread name, CPU seconds)} of this process's living Python threads."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for thread in threading.enumerate():
        tid = thread.native_id
        try:
            with open(f"/proc/self/task/{tid}/stat", encoding="ascii") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue  # the thread ended
        if tid is not None:
            out[tid] = (thread.name, (int(fields[11]) + int(fields[12])) / tick)
    return out


def main(argv: list[str] | None = None) -> int:
    """Run watched blocks and print the monitors' share of the daemon's interpreter."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", type=Path, default=Path(__file__).resolve().parents[1],
                    help="the checkout whose src/ and benchmarks/bench_latency.py to use (default: this one)")
    ap.add_argument("--blocks", type=int, default=3, help="watched blocks (a fresh daemon each)")
    ap.add_argument("--trials", type=int, default=300, help="trip trials per block")
    args = ap.parse_args(argv)
    sys.path[:0] = [str(args.tree / "src"), str(args.tree / "benchmarks")]
    import bench_latency
    from canguard.service.monitor import snapshot

    calls: list[tuple[float, float]] = []
    publish = snapshot.Observer.publish

    def timed(self: Any, engine: Any, now: float) -> None:
        t0, c0 = time.perf_counter(), time.thread_time()
        publish(self, engine, now)
        calls.append((time.perf_counter() - t0, time.thread_time() - c0))

    snapshot.Observer.publish = timed  # type: ignore[method-assign]
    rnd = random.Random(1)
    cpu_s = wall_s = 0.0
    for r in range(args.blocks):
        seen: dict[int, tuple[str, float]] = {}
        stop = threading.Event()

        def sample(into: dict[int, tuple[str, float]] = seen, until: threading.Event = stop) -> None:
            while not until.wait(0.02):
                into.update(thread_cpu_s())

        sampler = threading.Thread(target=sample, name="sampler")
        sampler.start()
        t0 = time.perf_counter()
        bench_latency.watched_block(args.trials, 8000.0, rnd, None, watch=True)
        wall = time.perf_counter() - t0
        stop.set()
        sampler.join()
        used = sum(c for name, c in seen.values() if name.startswith(THREAD_PREFIX))
        cpu_s += used
        wall_s += wall
        print(f"block {r}: the monitors' threads in the daemon's process used {used / wall * 100:.2f} % of the run")
    w = sorted(c[0] for c in calls)
    c = sorted(c[1] for c in calls)
    print(f"{args.tree} ({args.blocks} blocks of {args.trials} trials, load {os.getloadavg()[0]:.1f})")
    print(f"  monitor threads in the daemon's process: {cpu_s / wall_s * 100:.2f} % CPU of the wall time")
    print(f"  Observer.publish on the engine's thread: {len(calls) / wall_s:.0f}/s, wall mean "
          f"{statistics.mean(w) * 1e6:.1f} us, p99 {w[int(0.99 * (len(w) - 1))] * 1e6:.1f} us; CPU mean "
          f"{statistics.mean(c) * 1e6:.1f} us, {sum(c) / wall_s * 100:.2f} % of the wall time")
    return 0


if __name__ == "__main__":
    sys.exit(main())
