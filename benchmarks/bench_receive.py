"""CPU per frame of receiving alone: ``BusReader.receive`` reading its socket itself vs a receive thread.

    python benchmarks/bench_receive.py [--seconds 5] [--fps 8000] [--rounds 3]

One python-can udp_multicast sender process at ``--fps`` (bench_latency's background); in this
process a :class:`~canguard.io.bus.BusReader` on the same group, ``direct=True`` (the daemon's loop
reads the socket) and ``direct=False`` (a receive thread and a queue) taking turns for
``--seconds`` each, ``--rounds`` times, taking up to 33 frames a call as the daemon does. Printed per
turn: frames, CPU seconds of this process (all its threads, ``time.process_time``) and frames per
CPU-second, which a busy machine changes far less than it changes latencies; and how long the frames
had waited since the kernel received them (p50 / p99), which it does change.
"""

from __future__ import annotations

import argparse
import random
import signal
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "src"))

from bench_latency import start_child  # noqa: E402
from canguard.config.schema import BusConfig  # noqa: E402
from canguard.io.bus import BusReader  # noqa: E402


def turn(cfg: BusConfig, direct: bool, seconds: float) -> str:
    """One turn of receiving for ``seconds``; its line of figures."""
    reader = BusReader([cfg], direct=direct)
    reader.start()
    try:
        n, waits = 0, []
        cpu0, t0 = time.process_time(), time.monotonic()
        while time.monotonic() - t0 < seconds:
            items = reader.receive(0.05, 33)
            wall = time.time()
            n += len(items)
            waits += [wall - frame.t for _, frame, _ in items]
        cpu = time.process_time() - cpu0
    finally:
        reader.stop()
    waits.sort()
    pick = lambda q: waits[min(len(waits) - 1, int(q * len(waits)))] * 1e3 if waits else float("nan")  # noqa: E731
    way = "direct (the caller reads)" if reader.direct else "receive thread + queue"
    return (f"  {way:26} {n:8d} {cpu:7.2f} {n / max(cpu, 1e-9):12,.0f} {pick(0.5):9.2f} {pick(0.99):9.2f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--fps", type=float, default=8000.0)
    ap.add_argument("--rounds", type=int, default=3, help="turns each way (default 3)")
    args = ap.parse_args(argv)
    rnd = random.Random()
    group, port = f"239.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}", rnd.randint(20000, 60000)
    cfg = BusConfig(name="main", kwargs={"interface": "udp_multicast", "channel": group, "port": port})
    sender = start_child("background", group, port, args.fps)
    print(f"udp_multicast, a sender at {args.fps:,.0f} frames/s; {args.seconds:g} s a turn")
    print(f"  {'':26} {'frames':>8} {'CPU s':>7} {'frames/CPU-s':>12} {'wait p50':>9} {'p99 ms':>9}")
    try:
        for _ in range(args.rounds):
            for direct in (True, False):
                print(turn(cfg, direct, args.seconds), flush=True)
    finally:
        sender.send_signal(signal.SIGTERM)
        sender.communicate(timeout=30)
    return 0


if __name__ == "__main__":
    sys.exit(main())
