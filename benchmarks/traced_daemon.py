"""``python -m canguard`` under tracemalloc: what the soak uses to tell a leak from fragmentation.

    python benchmarks/traced_daemon.py run -c canguard.yaml     # env below; soak.py --tracemalloc N

Benchmarks only: the product has no tracing hook. Environment:

``CANGUARD_TRACE_DIR``     where to write (default: the current directory)
``CANGUARD_TRACE_FRAMES``  frames per traceback (default 1: cheap; 25 to see who allocates)
``CANGUARD_TRACE_EVERY``   seconds between lines of ``traced.tsv`` (default 30)
``CANGUARD_TRACE_SNAPS``   comma-separated seconds after start at which a snapshot is dumped
                           (``snap_<s>.pickle``; load with ``tracemalloc.Snapshot.load``)

When the daemon exits it dumps ``snap_exit.pickle`` and writes ``trim.tsv``: seconds, RSS MB,
RSS MB after ``malloc_trim(0)``, traced MB. RSS that falls back when glibc returns its free
pages was fragmentation, not live objects. (Not at each snapshot: a trim in mid-run would
change the RSS curve it is meant to explain.)

``traced.tsv`` has one line per sample: seconds, traced MB (current), traced MB (peak), RSS MB,
frames waiting in the bus reader's queue (a loop that falls behind looks like a leak), and
the number of keys and clients in py_trees' global blackboard, and tracemalloc's own memory
in MB (RSS minus it is about what the daemon takes without tracing).

    python benchmarks/traced_daemon.py --compare snap_120.pickle snap_1700.pickle [N]

prints the N (default 15) allocation sites that grew most from one snapshot to the other.
SIGUSR1 dumps a snapshot now (``snap_usr1_<s>.pickle``).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
import tracemalloc
from pathlib import Path
from types import FrameType

OUT = Path(os.environ.get("CANGUARD_TRACE_DIR", "."))
FRAMES = int(os.environ.get("CANGUARD_TRACE_FRAMES", "1"))
EVERY = float(os.environ.get("CANGUARD_TRACE_EVERY", "30"))
SNAPS = sorted(float(s) for s in os.environ.get("CANGUARD_TRACE_SNAPS", "").split(",") if s.strip())
T0 = time.monotonic()


def rss_mb() -> float:
    with open("/proc/self/status", encoding="ascii") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024.0


DAEMONS: list = []
"""The Daemon of this process, once built (for its queue length)."""


def watch_daemon() -> None:
    from canguard.service import daemon

    init = daemon.Daemon.__init__

    def recording_init(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        init(self, *args, **kwargs)
        DAEMONS.append(self)

    daemon.Daemon.__init__ = recording_init  # type: ignore[method-assign]


def queued() -> int:
    return DAEMONS[0].reader.queue.qsize() if DAEMONS else -1


def blackboard() -> tuple[int, int]:
    from py_trees.blackboard import Blackboard

    return len(Blackboard.metadata), len(Blackboard.clients)


def dump(name: str) -> None:
    snap = tracemalloc.take_snapshot().filter_traces([tracemalloc.Filter(False, tracemalloc.__file__)])
    snap.dump(str(OUT / f"{name}.pickle"))


def trim_line(elapsed: float) -> None:
    before = rss_mb()
    traced = tracemalloc.get_traced_memory()[0] / 2**20
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        return
    with open(OUT / "trim.tsv", "a", encoding="ascii") as f:
        f.write(f"{elapsed:.0f}\t{before:.1f}\t{rss_mb():.1f}\t{traced:.2f}\n")


def sampler() -> None:
    snaps = list(SNAPS)
    next_line = EVERY  # the first line once the daemon has started
    while True:
        elapsed = time.monotonic() - T0
        if elapsed >= next_line:
            cur, peak = tracemalloc.get_traced_memory()
            with open(OUT / "traced.tsv", "a", encoding="ascii") as f:
                keys, clients = blackboard()
                f.write(f"{elapsed:.0f}\t{cur / 2**20:.2f}\t{peak / 2**20:.2f}\t{rss_mb():.1f}\t{queued()}"
                        f"\t{keys}\t{clients}\t{tracemalloc.get_tracemalloc_memory() / 2**20:.2f}\n")
            next_line += EVERY
        if snaps and elapsed >= snaps[0]:
            at = snaps.pop(0)
            dump(f"snap_{at:.0f}")
        time.sleep(0.5)


def on_usr1(_signum: int, _frame: FrameType | None) -> None:
    dump(f"snap_usr1_{time.monotonic() - T0:.0f}")


def compare(old: str, new: str, n: int = 15) -> None:
    a, b = tracemalloc.Snapshot.load(old), tracemalloc.Snapshot.load(new)
    key = "traceback" if max((len(t.traceback) for t in b.traces), default=1) > 1 else "lineno"
    total = sum(s.size for s in b.statistics("filename")) - sum(s.size for s in a.statistics("filename"))
    print(f"traced {total / 2**20:+.3f} MB from {old} to {new}; top {n} by growth ({key}):")
    for stat in b.compare_to(a, key)[:n]:
        print(f"{stat.size_diff / 1024:+10.1f} kB {stat.count_diff:+8d} blocks  now {stat.size / 1024:.1f} kB")
        for line in stat.traceback.format(limit=-8 if key == "traceback" else 1):
            print("      " + line)


def main() -> int:
    if sys.argv[1:2] == ["--compare"]:
        compare(*sys.argv[2:4], *[int(x) for x in sys.argv[4:5]])
        return 0
    OUT.mkdir(parents=True, exist_ok=True)
    tracemalloc.start(FRAMES)
    signal.signal(signal.SIGUSR1, on_usr1)
    watch_daemon()
    threading.Thread(target=sampler, name="tracemalloc-sampler", daemon=True).start()
    from canguard.cli.main import main as canguard_main

    sys.argv[0] = "canguard"
    code = int(canguard_main() or 0)
    dump("snap_exit")  # the daemon object is still alive (DAEMONS): its engine is in the snapshot
    trim_line(time.monotonic() - T0)
    return code


if __name__ == "__main__":
    sys.exit(main())
