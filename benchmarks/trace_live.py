"""Where the cross-process trip-to-stop time goes: per-hop p50 / p99 of bench_latency's (b) trials.

    python benchmarks/trace_live.py --trials 300

The set-up of ``bench_latency.py --only cross-process`` (``canguard run`` over udp_multicast, a
background process at 8,000 frames/s), with the daemon started through this file's ``--daemon``
mode, which wraps three of its calls to stamp the overcurrent frame and the stop frame on their
way through (benchmarks only: the product has no tracing hook). All stamps are ``time.time()``
or the kernel's receive stamp (``SO_TIMESTAMPNS``, the same clock), so the two processes agree.

Hops, per trial:

``wire``     peer's send call -> kernel receive stamp in the daemon's socket
``recv``     that stamp -> python-can's ``recv`` returned the message to canguard (a reader thread's, or,
             where the loop reads the socket itself, the loop's: then it holds the loop's wake-up and
             whatever the loop was still doing, a tick, other frames)
``queue``    recv returned -> its block entered ``Engine.take`` (the reader thread's queue and the loop's
             drain; or the socket reads after it in the same batch)
``engine``   ``Engine.take`` entered -> the stop frame handed to the bus (decode, models, tree, gate)
``send``     the send call itself
``back``     send returned -> kernel receive stamp in the peer's socket
``peer``     that stamp -> the peer's ``recv`` returned it
``total``    the peer's send call -> the peer's ``recv`` returned the stop frame (bench_latency's figure)

and ``fsync``: every ``os.fsync`` of the daemon (the journal's durability), and ``in fsync``: for
the trials whose overcurrent frame arrived while one ran, how much of it was still to run (what the
frame waited for where the loop itself syncs; where a thread of the journal's own syncs, the loop
does not wait for it and the figure only says how often the two overlapped).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "src"))

BMS_ID = 0x18FF50E5
ESTOP0 = 0x02


def daemon_main(out: str, argv: list[str]) -> int:
    """``canguard run`` with stamps at recv return, loop dequeue and stop send; written to ``out`` at exit."""
    from canguard.io import bus as busmod

    marks: list[tuple[str, float, float]] = []
    to_frames = busmod.to_frames

    def stamped_frames(msgs: Any, name: str) -> Any:
        now = time.time()
        marks.extend(("recv", now, float(msg.timestamp)) for msg in msgs if msg.arbitration_id == BMS_ID)
        return to_frames(msgs, name)

    busmod.to_frames = stamped_frames  # type: ignore[assignment]
    from canguard.engine.core import Engine

    take = Engine.take

    def stamped_take(self: Any, bus: str, block: Any) -> None:
        if any(f.arbitration_id == BMS_ID for f in block):
            marks.append(("take", time.time(), 0.0))
        take(self, bus, block)

    Engine.take = stamped_take  # type: ignore[method-assign]
    send = busmod.BusReader.send

    def stamped_send(self: Any, bus_name: str, msg: Any) -> bool:
        t = time.time()
        ok = send(self, bus_name, msg)
        if msg.arbitration_id == ESTOP0:
            marks.append(("send", t, time.time()))
        return ok

    busmod.BusReader.send = stamped_send  # type: ignore[method-assign]
    fsync = os.fsync

    def stamped_fsync(fd: int) -> None:
        t = time.time()
        try:
            fsync(fd)
        finally:
            marks.append(("fsync", t, time.time()))

    os.fsync = stamped_fsync  # the journal's durability, in whichever thread calls it
    from canguard.cli.main import main as canguard_main

    sys.argv = ["canguard", *argv]
    try:
        code = int(canguard_main() or 0)
    finally:
        Path(out).write_text(json.dumps(marks), encoding="ascii")
    return code


def pct(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, round(q * (len(s) - 1)))] * 1e3


def trials(peer: Any, n: int, rnd: random.Random) -> list[dict[str, float]]:
    """bench_latency's guard trials, keeping the peer's stamps of each."""
    from bench_latency import SET_STATE0, bms_msg, ready_for_trial, recv_until

    peer.set_filters([{"can_id": ESTOP0, "can_mask": 0x7FF, "extended": False},
                      {"can_id": SET_STATE0, "can_mask": 0x7FF, "extended": False}])
    normal, over = bms_msg(10.0), bms_msg(40.0)
    out: list[dict[str, float]] = []
    for _ in range(n):
        ready_for_trial(peer, normal, rnd)
        t0 = time.time()
        peer.send(over)
        msg = recv_until(peer, lambda m: m.arbitration_id == ESTOP0)
        out.append({"t0": t0, "rx": float(msg.timestamp), "got": time.time()})
    return out


def hops(peer_marks: list[dict[str, float]], marks: list[list[Any]]) -> dict[str, list[float]]:
    """Each trial's hops: the daemon's first stamps of each kind inside the trial's window."""
    out: dict[str, list[float]] = {k: [] for k in ("wire", "recv", "queue", "engine", "send", "back", "peer",
                                                   "total")}
    syncs = [(m[1], m[2]) for m in marks if m[0] == "fsync"]
    out["fsync"] = [end - start for start, end in syncs]
    out["in fsync"] = []
    for tr in peer_marks:
        inside = [m for m in marks if tr["t0"] - 1e-4 <= m[1] <= tr["got"] and m[0] != "fsync"]
        first = {}
        for kind, t, extra in inside:
            first.setdefault(kind, (t, extra))
        if len(first) < 3:
            continue
        (recv_t, rx_t), (take_t, _), (send_t, sent_t) = first["recv"], first["take"], first["send"]
        # the overcurrent frame arrived while the journal's fsync ran: the part of it still to run
        out["in fsync"] += [end - rx_t for start, end in syncs if start <= rx_t < end]
        for key, value in (("wire", rx_t - tr["t0"]), ("recv", recv_t - rx_t), ("queue", take_t - recv_t),
                           ("engine", send_t - take_t), ("send", sent_t - send_t), ("back", tr["rx"] - sent_t),
                           ("peer", tr["got"] - tr["rx"]), ("total", tr["got"] - tr["t0"])):
            out[key].append(value)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=300)
    ap.add_argument("--fps", type=float, default=8000.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--daemon", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.daemon:
        return daemon_main(args.daemon[0], args.daemon[1:])
    import can

    from bench_common import clean_up_on_sigterm, wait_for_start, write_config
    from bench_latency import child_env, start_child

    clean_up_on_sigterm()
    rnd = random.Random(args.seed)
    group = f"239.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}"
    port = rnd.randint(20000, 60000)
    kids: list[subprocess.Popen[str]] = []
    peer = can.Bus(interface="udp_multicast", channel=group, port=port)
    try:
        with tempfile.TemporaryDirectory() as d:
            tmp = Path(d)
            cfg = write_config(tmp, {"interface": "udp_multicast", "channel": group, "port": port})
            out = tmp / "marks.json"
            daemon = subprocess.Popen([sys.executable, __file__, "--daemon", str(out), "run", "-c", str(cfg)],
                                      env=child_env(), text=True)
            kids.append(daemon)
            wait_for_start(daemon, tmp / "events.jsonl")
            bg = start_child("background", group, port, args.fps)
            kids.append(bg)
            time.sleep(0.2)
            peer_marks = trials(peer, args.trials, rnd)
            bg.send_signal(signal.SIGTERM)
            bg.communicate(timeout=30)
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(10)
            marks = json.loads(out.read_text(encoding="ascii"))
    finally:
        for k in kids:
            if k.poll() is None:
                k.kill()
            k.wait(10)
        peer.shutdown()
    by_hop = hops(peer_marks, marks)
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs; {len(by_hop['total'])} of {args.trials} "
          f"trials matched; background {args.fps:,.0f} frames/s")
    print(f"  {'hop':9} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'count':>6}")
    for key, values in by_hop.items():
        if values:
            print(f"  {key:9} {pct(values, 0.5):8.3f} {pct(values, 0.99):8.3f} {max(values) * 1e3:8.3f} "
                  f"{len(values):6d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
