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

    python benchmarks/traced_daemon.py --stages [TRIALS]

times the trip-to-stop path inside the daemon instead (no tracemalloc): ``canguard run`` on a
udp_multicast group with the bundled config, the trials of ``benchmarks/live.py`` (an echo round trip,
then a trip) in turns; for each trip, µs from the tripping frame's arrival (the kernel's stamp) to the
receive that returned it, from there to each stage, and from the stop's first send to the loop's next wait
(what the measuring peer competes with). The echo process joins the group after the daemon here, so it is
woken first (benchmarks/live.py alternates the order): its round trips are context, not the floor.
Prints p50 / p99 of each stage and the wall times of trips and echoes.

    valgrind --tool=cachegrind --cache-sim=no python benchmarks/traced_daemon.py --count TRIALS

runs the same trips in this process, on python-can's virtual bus under a manual clock, for
instruction counts: the counts at two numbers of trials, subtracted, are the instructions of a trip.
"""

from __future__ import annotations

import ctypes
import itertools
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


STAGES = ("arrival → receive", "receive → take", "take → edge tick", "edge tick → stop", "stop → send",
          "first frame's send", "receive → send", "send → next wait")
"""The columns of a stage line: µs from one mark to the next (the marks of :func:`trace_stages`)."""
MARKS = ("recv", "take", "edge", "halt", "send", "sent")


def trace_stages(out: Path) -> None:
    """Mark each step of the loop (perf_counter at the receive's return, the take, the edge tick, the stop of a
    running task (the gate's ``ahead`` of a sure halt, or the halt), the stop's first send and its return); a
    step that sent a stop appends its stages to ``out`` at the loop's next wait."""
    from canguard.engine.core import Engine
    from canguard.engine.gate import TaskGate
    from canguard.io.bus import BusReader
    from canguard.service.daemon import Daemon

    marks: dict[str, float] = {}
    pc = time.perf_counter
    receive, take, edge, halt, send = (BusReader.receive, Daemon.take_received, Engine.edge_tick, TaskGate.halt,
                                       BusReader.send)

    def receive_(self, *args):  # type: ignore[no-untyped-def]
        if "sent" in marks:
            t = [marks[m] for m in MARKS] + [pc()]
            us = [(b - a) * 1e6 for a, b in itertools.pairwise(t)]
            us.insert(5, (t[4] - t[0]) * 1e6)
            us.insert(0, (marks["recv"] - marks["arrived"]) * 1e6)
            with open(out, "a", encoding="ascii") as f:
                f.write("\t".join(f"{x:.1f}" for x in us) + "\n")
        marks.clear()
        items = receive(self, *args)
        marks["recv"] = pc()
        if items:  # the kernel's stamp of the last frame received, on the monotonic clock (perf_counter's here)
            marks["arrived"] = items[-1][2]
        return items

    def take_(self, *args):  # type: ignore[no-untyped-def]
        marks["take"] = pc()
        return take(self, *args)

    def edge_(self, *args):  # type: ignore[no-untyped-def]
        marks.setdefault("edge", pc())
        return edge(self, *args)

    def halt_(self, *args):  # type: ignore[no-untyped-def]
        if self.state == TaskGate.RUNNING and "edge" in marks:
            marks.setdefault("halt", pc())
        return halt(self, *args)

    def ahead_(self, *args):  # type: ignore[no-untyped-def]
        if self.state == TaskGate.RUNNING and "edge" in marks and self.halts_next is not None and self.halts_next():
            marks.setdefault("halt", pc())
        return ahead(self, *args)

    def send_(self, *args):  # type: ignore[no-untyped-def]
        if "halt" not in marks or "send" in marks:
            return send(self, *args)
        marks["send"] = pc()
        ok = send(self, *args)
        marks["sent"] = pc()
        return ok

    BusReader.receive, Daemon.take_received, Engine.edge_tick = receive_, take_, edge_  # type: ignore[method-assign]
    TaskGate.halt, BusReader.send = halt_, send_  # type: ignore[method-assign]
    ahead = getattr(TaskGate, "ahead", None)  # the stop sent at the trip, before the tree's tick
    if ahead is not None:
        TaskGate.ahead = ahead_  # type: ignore[method-assign]


def stages(trials: int) -> int:
    """``--stages``: the daemon's stages of ``trials`` trips (beside as many echo round trips), p50 / p99."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from benchmarks import kit
    from benchmarks.live import rig

    bus = kit.multicast_bus()
    with kit.scratch("stages") as d:
        tmp = Path(d)
        out = tmp / "stages.tsv"
        with rig(tmp, bus, kit.SRC, False, script=Path(__file__), env={"CANGUARD_TRACE_STAGES": str(out)}) as (
                _daemon, peer):
            trips, echoes = peer.turns(trials)
        rows = [[float(x) for x in line.split()] for line in out.read_text(encoding="ascii").splitlines()]
    print(f"{len(rows)} trips, µs p50 / p99 of each stage:")
    for i, name in enumerate(STAGES):
        col = [r[i] for r in rows]
        print(f"  {name:22s} {kit.median(col):8.1f} {kit.percentile(col, 0.99):8.1f}")
    t50, t99, e50, e99 = (kit.median(trips) * 1e3, kit.percentile(trips, 0.99) * 1e3, kit.median(echoes) * 1e3,
                          kit.percentile(echoes, 0.99) * 1e3)
    print(f"trip → stop ms p50 / p99 {t50:.3f} / {t99:.3f}; echo {e50:.3f} / {e99:.3f}; p99 ratio {t99 / e99:.2f}; "
          f"load {os.getloadavg()[0]:.2f}")
    return 0


def count(trials: int) -> int:
    """``--count``: ``trials`` trips in this process (a normal frame, the ticks of 50 ms, an overcurrent frame)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    import can

    from benchmarks import kit
    from benchmarks.live import BMS_ID, bms
    from canguard.config.loader import load_config
    from canguard.engine.core import Engine
    from canguard.engine.events import EventJournal
    from canguard.engine.gate import BusSink
    from canguard.io.block import Block
    from canguard.io.clock import ManualClock
    from canguard.io.frame import Frame

    with kit.scratch("count") as d:
        cfg = load_config(kit.write_config(Path(d), {"interface": "virtual", "channel": "count"}))
        bus, peer = can.Bus(interface="virtual", channel="count"), can.Bus(interface="virtual", channel="count")
        clock = ManualClock(1.0)
        journal = EventJournal(cfg.events, sync_in_background=True)  # as the daemon's
        engine = Engine(cfg, clock, BusSink(lambda _name, msg: bus.send(msg, timeout=0) is None), events=journal,
                        save_heat=False)
        engine.start(clock.now())
        normal, over = (bytes(bms(a).data) for a in (10.0, 40.0))
        for _ in range(trials):
            for data, dt in ((normal, 0.05), (over, 0.002)):
                clock.advance_to(clock.now() + dt)
                engine.take("main", Block.of_frames((Frame(clock.now(), "main", BMS_ID, data, True),)))
                engine.advance(clock.now())
                while peer.recv(0) is not None:
                    pass
        engine.finish()
        journal.close()
        bus.shutdown()
        peer.shutdown()
        print(engine.gate.stops, "stops")
    return 0


def main() -> int:
    if sys.argv[1:2] == ["--compare"]:
        compare(*sys.argv[2:4], *[int(x) for x in sys.argv[4:5]])
        return 0
    if sys.argv[1:2] == ["--count"]:
        return count(int(sys.argv[2]))
    if sys.argv[1:2] == ["--stages"]:
        return stages(int(sys.argv[2]) if sys.argv[2:] else 1000)
    if os.environ.get("CANGUARD_TRACE_STAGES"):
        trace_stages(Path(os.environ["CANGUARD_TRACE_STAGES"]))
        from canguard.cli.main import main as canguard_main

        sys.argv[0] = "canguard"
        return int(canguard_main() or 0)
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
