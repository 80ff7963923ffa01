"""canguard's own CPU per frame of ingest, beside python-can's receive of the same frames (same run).

    python benchmarks/bench_ingest_engine.py [--seconds 10] [--fps 8000] [--profile] [--count N]

bench_ingest's set-up (four udp_multicast buses, one sender process each at ``--fps``: per 10 ms the
BMS or one axis' two configured frames, the rest ids no config uses), in two phases:

1. **python-can's receive (the peer).** This process waits on the four buses' sockets with
   ``select`` and drains each ready one with python-can's ``recv(0)``, up to
   :data:`~canguard.service.daemon.DRAIN_DIRECT` per wake-up shared among the ready buses, as the
   daemon's reader does. Its CPU (``time.process_time``) is python-can's receive; the messages are
   kept as they were drained: a wake-up's blocks of ``can.Message`` per bus, and when it came.
2. **canguard's path.** The frames the senders send (``--frames sent``, the default: their pattern at
   ``--fps`` for ``--seconds``, made into ``can.Message`` by python-can's own udp_multicast unpack, so a
   busy machine that starves the senders in phase 1 does not thin them out), drained as a daemon that
   keeps up would drain them: it wakes ``--latency-ms`` after the first frame waiting (by the kernel's
   stamp) and takes what has arrived, up to DRAIN_DIRECT shared among the ready buses. ``--frames
   received``: phase 1's messages drained so; ``--frames as-drained``: phase 1's wake-ups as they were
   (on a busy machine full batches of frames seconds old, which the daemon answers with overrun stops).
   Each wake-up at its own offset from the start (every stamp moved by the same amount), through the
   daemon's own objects: a :class:`~canguard.service.daemon.Daemon` built from the config (its buses
   opened: it sends on its own), its reader's :meth:`~canguard.io.bus.BusReader.admit` (messages to
   frames, the buses' blocks merged by kernel stamp), :meth:`~canguard.service.daemon.Daemon.take_received`
   (the blocks through ``Engine.take``) and ``Engine.advance`` to now, as the daemon's loop calls them. CPU
   is this thread's (``time.thread_time``) around those calls only; the waits between wake-ups cost none.

Printed: frames, CPU and frames per CPU-second of each phase, canguard's split (admit / take /
advance), and both together: what the whole daemon would reach if it spent nothing else.
``--profile`` runs phase 2 under cProfile and prints its top functions.
"""

from __future__ import annotations

import argparse
import math
import os
import random
import select
import subprocess
import sys
import tempfile
import time
from collections import deque
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "src"))

import can  # noqa: E402

from bench_common import clean_up_on_sigterm  # noqa: E402
from bench_ingest import DBC, SENDER, child_env, write_config  # noqa: E402
from canguard.config.schema import BusConfig  # noqa: E402
from canguard.io.bus import open_bus  # noqa: E402
from canguard.service.daemon import DRAIN_DIRECT, Daemon  # noqa: E402

Wake = tuple[float, list[tuple[str, list[Any]]]]
"""One wake-up of the receive loop: when (``time.monotonic()``), and each ready bus's messages."""


def record(groups: list[tuple[str, int]], fps: float, seconds: float) -> tuple[list[Wake], float, float, float]:
    """Phase 1: the senders run; this process drains the buses as the daemon does.

    (wake-ups, CPU s, wall s, wall clock minus monotonic clock)."""
    configs = [BusConfig(name=f"in{i}", kwargs={"interface": "udp_multicast", "channel": g, "port": p})
               for i, (g, p) in enumerate(groups)]
    buses = {c.name: open_bus(c) for c in configs}
    fds = {bus.fileno(): (name, bus) for name, bus in buses.items()}
    kids: list[subprocess.Popen[str]] = []
    wakes: list[Wake] = []
    try:
        for i, (g, p) in enumerate(groups):
            code = SENDER.format(dbc=str(DBC), group=g, port=p, index=i, fps=fps, seconds=seconds)
            kids.append(subprocess.Popen([sys.executable, "-c", code], env=child_env(), stdout=subprocess.PIPE,
                                         text=True))
        for kid in kids:
            assert kid.stdout is not None
            if kid.stdout.readline().strip() != "ready":
                raise RuntimeError("a sender did not start")
        cpu0, t0 = time.process_time(), time.monotonic()
        end = t0 + seconds
        while time.monotonic() < end:
            ready, _, _ = select.select(list(fds), [], [], 0.05)
            if not ready:
                continue
            share = max(1, DRAIN_DIRECT // len(ready))
            got: list[tuple[str, list[Any]]] = []
            for fd in ready:
                name, bus = fds[fd]
                msgs = []
                while len(msgs) < share:
                    msg = bus.recv(0)
                    if msg is None:
                        break
                    msgs.append(msg)
                if msgs:
                    got.append((name, msgs))
            wakes.append((time.monotonic(), got))
        cpu, wall = time.process_time() - cpu0, time.monotonic() - t0
        for kid in kids:
            kid.communicate(timeout=60)
    finally:
        for kid in kids:
            if kid.poll() is None:
                kid.kill()
                kid.wait(10)
        for bus in buses.values():
            bus.shutdown()
    return wakes, cpu, wall, time.time() - time.monotonic()


BURST_S = 0.001
"""A sender's loop sends what is due, then sleeps 1 ms: its frames come in bursts this far apart."""
SEND_GAP_S = 15e-6
"""Between two frames of a burst (a python-can send)."""


def nominal(fps: float, seconds: float, offset: float) -> list[Wake]:
    """The frames bench_ingest's four senders send at ``fps`` each for ``seconds``, as python-can's
    udp_multicast receive makes them (its own ``pack_message`` / ``unpack_message``), stamped from now on:
    per bus a burst every :data:`BURST_S` (a random phase per bus), :data:`SEND_GAP_S` between frames.

    Given as one wake-up per bus holding all of its messages (:func:`kept_up` drains them); ``offset``: the
    wall clock minus the monotonic clock."""
    import cantools
    from can.interfaces.udp_multicast.utils import pack_message, unpack_message

    db = cantools.database.load_file(str(DBC))

    def enc(name: str, **values: float) -> can.Message:
        m = db.get_message_by_name(name)
        return can.Message(arbitration_id=m.frame_id, data=m.encode(values), is_extended_id=m.is_extended_frame)

    rnd = random.Random(1)
    start = time.time() + 0.5
    got: list[tuple[str, list[Any]]] = []
    per_burst = max(1, round(fps * BURST_S))
    for index in range(4):
        configured = [enc("BMS_Status", Pack_Current=10.0, Pack_Voltage=48.0, State_Of_Charge=80.0, Present=1,
                          Fault=0, Alive_Counter=0)] if index == 0 else []
        configured += [enc(f"Axis{index}_Get_Iq", Iq_Setpoint=2.0, Iq_Measured=2.0),
                       enc(f"Axis{index}_Get_Torques", Torque_Target=1.0, Torque_Estimate=1.0)]
        other = [can.Message(arbitration_id=0x600 + i, data=bytes(8)) for i in range(64)]
        per_10ms = int(fps / 100)
        packed = [pack_message(m) for m in configured + [other[i % 64] for i in range(per_10ms - len(configured))]]
        phase = rnd.uniform(0.0, BURST_S)
        msgs = [unpack_message(packed[k % len(packed)], check=True,
                               replace={"timestamp": start + phase + (k // per_burst) * BURST_S
                                        + (k % per_burst) * SEND_GAP_S})
                for k in range(int(fps * seconds))]
        got.append((f"in{index}", msgs))
    return [(start - offset, got)]


def kept_up(wakes: list[Wake], offset: float, latency_s: float) -> list[Wake]:
    """The recorded messages as a daemon that keeps up would drain them: it wakes ``latency_s`` after the first
    frame waiting (its kernel stamp) and drains each ready bus, up to DRAIN_DIRECT shared among them."""
    queues: dict[str, deque[Any]] = {}
    for _at, got in wakes:
        for name, msgs in got:
            queues.setdefault(name, deque()).extend(msgs)
    for name, q in queues.items():  # a bus's own frames are in order; sorted only to be sure
        queues[name] = deque(sorted(q, key=lambda m: float(m.timestamp)))
    out: list[Wake] = []
    now = -math.inf
    while True:
        heads = [float(q[0].timestamp) for q in queues.values() if q]
        if not heads:
            return out
        now = max(now, min(heads) + latency_s)
        ready = [(name, q) for name, q in queues.items() if q and float(q[0].timestamp) <= now]
        share = max(1, DRAIN_DIRECT // len(ready))
        got: list[tuple[str, list[Any]]] = []
        for name, q in ready:
            msgs = []
            while q and len(msgs) < share and float(q[0].timestamp) <= now:
                msgs.append(q.popleft())
            got.append((name, msgs))
        out.append((now - offset, got))


def replay(daemon: Daemon, wakes: list[Wake], offset: float) -> tuple[float, float, float, int, float]:
    """Phase 2: every wake-up's blocks through the daemon's path at their own pace; CPU s of (admit, take, advance),
    frames, and how late (s) the latest wake-up came (this process starved of a CPU).

    ``offset``: the recording's wall clock minus its monotonic clock."""
    reader, engine, clock = daemon.reader, daemon.engine, daemon.clock
    admit, take, advance = reader.admit, daemon.take_received, engine.advance
    cpu = time.thread_time
    t_admit = t_take = t_advance = 0.0
    frames = 0
    late = 0.0
    start = time.monotonic() + 0.05
    # a stamp s (recorded wall clock) was s - offset on the recording's monotonic clock; moved to this phase's
    stamp_shift = (time.time() - time.monotonic()) - offset + start - wakes[0][0]
    engine.start(clock.now())
    for at, got in wakes:
        for _name, msgs in got:
            for msg in msgs:
                msg.timestamp += stamp_shift
        delay = start + (at - wakes[0][0]) - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            late = max(late, -delay)
        c0 = cpu()
        items: list[Any] = []
        for name, msgs in got:
            admit(name, msgs, items)
        if len(got) > 1:
            items.sort(key=lambda item: item[2])  # BusReader.receive: buses drained one after the other
        c1 = cpu()
        if items:
            take(engine, items)
        c2 = cpu()
        advance(clock.now())
        c3 = cpu()
        t_admit += c1 - c0
        t_take += c2 - c1
        t_advance += c3 - c2
        frames += len(items)
    return t_admit, t_take, t_advance, frames, late


WARM_UP = 4000
"""Frames ``--count`` takes before it counts."""


class StepClock:
    """A live clock (``advance_to`` a no-op, as :class:`~canguard.io.clock.LiveClock`'s) that moves only when set:
    ``--count`` steps it to each wake-up's time, so every run ticks the same ticks however slow it runs."""

    def __init__(self, t: float) -> None:
        self.t = t

    def now(self) -> float:
        """The time it was set to."""
        return self.t

    def advance_to(self, t: float) -> None:
        """Live time moves by itself: nothing to do."""


class SteppedDaemon(Daemon):
    """The daemon on a :class:`StepClock` (benchmarks only)."""

    step_clock = StepClock(1000.0)

    def build_engine(self, cfg: Any, previous: Any = None) -> Any:
        self.clock = self.step_clock  # type: ignore[assignment]
        return super().build_engine(cfg, previous)


def count(cfg: Path, frames: int, fps: float, dry: bool) -> tuple[float, int]:
    """``--count``: the first ``frames`` frames the senders send, through the same calls as :func:`replay` but
    without waiting, the clock stepped to each wake-up (stamps on its own time base, not the wall clock's, so
    the reader takes them as arriving when read), after a warm-up of :data:`WARM_UP` frames (which brings in
    what the first blocks import and compile); CPU s of this thread and frames taken after the warm-up.
    ``dry``: everything but taking the ``frames`` (the baseline an instruction count subtracts)."""
    seconds = (WARM_UP + frames) / (4 * fps)
    wakes = kept_up(nominal(fps, seconds, 0.0), 0.0, 0.0002) if frames else []
    clock = SteppedDaemon.step_clock
    taken = False
    clock.t = wakes[0][0] - 0.01 if wakes else 1000.0
    shift = 1000.0 - clock.t  # the synthetic stamps moved to 1000 s: far from the wall clock
    clock.t += shift
    daemon = SteppedDaemon(cfg)
    reader, engine = daemon.reader, daemon.engine
    reader.start()  # the task's frames go out on its output bus, as in phase 2
    try:
        engine.start(clock.now())
        n = 0
        cpu0 = time.thread_time()
        for at, got in wakes:
            if n >= WARM_UP and (dry or not taken):
                if dry:
                    break
                taken, n, cpu0 = True, 0, time.thread_time()
            clock.t = at + shift
            items: list[Any] = []
            for name, msgs in got:
                for msg in msgs:
                    msg.timestamp += shift
                reader.admit(name, msgs, items)
            if len(got) > 1:
                items.sort(key=lambda item: item[2])
            daemon.take_received(engine, items)
            engine.advance(clock.now())
            n += len(items)
        cpu = time.thread_time() - cpu0
    finally:
        engine.finish(reason="benchmark end")
        reader.stop()
        daemon.journal.close()
    return (cpu, n) if taken else (0.0, 0)


def main(argv: list[str] | None = None) -> int:
    """Record, then replay through canguard's path; print both phases' frames per CPU-second."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="how long to receive (default 10)")
    ap.add_argument("--fps", type=float, default=8000.0, help="frames/s per bus (default 8000)")
    ap.add_argument("--frames", choices=("sent", "received", "as-drained"), default="sent",
                    help="phase 2's frames: what the senders send at --fps (default; the senders' pattern, made by "
                         "python-can's own udp_multicast unpack), what phase 1 received, drained as a daemon that "
                         "keeps up would, or phase 1's wake-ups as they were (a starved receiver's)")
    ap.add_argument("--latency-ms", type=float, default=0.2,
                    help="kept-up shape: the wake-up this long after the first frame waiting (default 0.2)")
    ap.add_argument("--count", type=int, default=None, metavar="N",
                    help="no sockets, no waiting: the first N frames the senders send through canguard's path, the "
                         "clock stepped to each wake-up (for instruction counts: valgrind --tool=cachegrind "
                         "--cache-sim=no, N frames minus N with --dry); prints CPU per frame")
    ap.add_argument("--dry", action="store_true", help="with --count: make the N frames, take none")
    ap.add_argument("--profile", action="store_true", help="phase 2 under cProfile; print its top functions")
    args = ap.parse_args(argv)
    clean_up_on_sigterm()
    if args.count is not None:
        with tempfile.TemporaryDirectory() as d:
            rnd = random.Random()
            groups = [(f"239.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}.{i + 1}", rnd.randint(20000, 60000))
                      for i in range(5)]
            cpu, n = count(write_config(Path(d), groups[:4], groups[4]), args.count, args.fps, args.dry)
        print(f"--count {args.count}: {n} frames, {cpu:.3f} CPU s, "
              f"{1e6 * cpu / max(n, 1):.2f} us/frame ({n / max(cpu, 1e-9):,.0f} frames/CPU-s)")
        return 0
    rnd = random.Random()
    groups = [(f"239.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}.{i + 1}", rnd.randint(20000, 60000))
              for i in range(5)]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        cfg = write_config(tmp, groups[:4], groups[4])
        wakes, rx_cpu, rx_wall, offset = record(groups[:4], args.fps, args.seconds)
        n = sum(len(msgs) for _at, got in wakes for _name, msgs in got)  # received in phase 1
        if not n:
            raise SystemExit("no frame received")
        if args.frames == "sent":
            wakes = kept_up(nominal(args.fps, args.seconds, offset), offset, args.latency_ms / 1e3)
        elif args.frames == "received":
            wakes = kept_up(wakes, offset, args.latency_ms / 1e3)
        ages = sorted(at + offset - float(m.timestamp) for at, got in wakes for _name, msgs in got for m in msgs)
        env_before = os.environ.pop("NOTIFY_SOCKET", None)
        daemon = Daemon(cfg)
        daemon.reader.start()  # its output bus sends the task's frames; nothing is sent on its input buses now
        try:
            if args.profile:
                import cProfile
                import pstats

                prof = cProfile.Profile()
                parts = prof.runcall(replay, daemon, wakes, offset)
            else:
                parts = replay(daemon, wakes, offset)
        finally:
            daemon.engine.finish(reason="benchmark end")
            daemon.reader.stop()
            daemon.journal.close()
            if env_before is not None:
                os.environ["NOTIFY_SOCKET"] = env_before
    t_admit, t_take, t_advance, frames, late = parts
    own = t_admit + t_take + t_advance
    sizes = sorted(len(msgs) for _at, got in wakes for _name, msgs in got)
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs; 4 udp_multicast buses x {args.fps:,.0f} "
          f"frames/s for {args.seconds:g} s; {frames} frames in {len(wakes)} wake-ups, "
          f"{len(sizes)} bus blocks (median {sizes[len(sizes) // 2]}, max {sizes[-1]} frames); "
          f"the latest wake-up {1e3 * late:.1f} ms late")
    print(f"  age of a frame when drained (kernel stamp to wake-up): p50 {1e3 * ages[len(ages) // 2]:.1f} ms, "
          f"p99 {1e3 * ages[int(0.99 * len(ages))]:.1f} ms")
    print(f"  python-can receive (select + recv):  {rx_cpu:6.2f} CPU s  {n / max(rx_cpu, 1e-9):12,.0f} frames/CPU-s  "
          f"{1e6 * rx_cpu / n:6.2f} us/frame ({n} frames received in {rx_wall:.1f} s)")
    print(f"  canguard's path (admit+take+advance): {own:6.2f} CPU s  "
          f"{frames / max(own, 1e-9):12,.0f} frames/CPU-s  {1e6 * own / frames:6.2f} us/frame")
    for label, part in (("admit (messages to frames, merge)", t_admit), ("take_received (Engine.take)", t_take),
                        ("Engine.advance (ticks)", t_advance)):
        print(f"    {label:36} {part:6.2f} CPU s  {1e6 * part / frames:6.2f} us/frame")
    rx_us, own_us = 1e6 * rx_cpu / n, 1e6 * own / frames
    print(f"  both: {rx_us + own_us:.2f} us/frame = {1e6 / (rx_us + own_us):,.0f} frames/CPU-s; "
          f"canguard's share {100 * own_us / (rx_us + own_us):.0f} %")
    if args.profile:
        pstats.Stats(prof).sort_stats("tottime").print_stats(30)
    return 0


if __name__ == "__main__":
    sys.exit(main())
