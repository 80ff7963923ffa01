"""bench_latency's cross-process trial, two versions of canguard and the echo floor taking turns trial by trial.

    python benchmarks/bench_latency_ab.py --old REV [--new REV] [--trials 300] [--fps 8000]

On a shared machine the load moves more between two runs minutes apart than most changes are
worth. Here both versions run at once (``git archive`` of ``--old`` and of ``--new``, default the
working tree's ``src``), each ``canguard run`` on its own udp_multicast group with its own
background sender at ``--fps``, and a python-can echo process on a third group with the same
background: the floor. One peer runs a trial on each in turn (bench_latency's trial: normal BMS
frame, wait for the task frames, a random 0-3 ms pause, a 40 A BMS frame, time until the first
Estop; for the echo, one round trip), so all three meet the same machine.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))

import can  # noqa: E402

from bench_common import clean_up_on_sigterm, wait_for_start, write_config  # noqa: E402
from bench_latency import (  # noqa: E402
    CLOSED_LOOP,
    ECHO_REP,
    ECHO_REQ,
    ESTOP0,
    SET_STATE0,
    bms_msg,
    child_env,
    drain,
    figures,
    recv_until,
    start_child,
)


def export(rev: str, into: Path) -> Path:
    """The ``src`` of revision ``rev`` (or this checkout's, for ``"."``), as a directory."""
    if rev == ".":
        return REPO / "src"
    archive = into / f"{rev}.tar"
    subprocess.run(["git", "-C", str(REPO), "archive", "-o", str(archive), rev, "src"], check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(into / rev, filter="data")
    return into / rev / "src"


def group(rnd: random.Random) -> tuple[str, int]:
    """A multicast group and port no other run uses."""
    return f"239.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}", rnd.randint(20000, 60000)


class Guarded:
    """One version's ``canguard run`` on its own group, and the peer's bus on it."""

    def __init__(self, src: Path, tmp: Path, where: tuple[str, int]) -> None:
        tmp.mkdir()
        cfg = write_config(tmp, {"interface": "udp_multicast", "channel": where[0], "port": where[1]})
        env = child_env()
        env["PYTHONPATH"] = str(src)
        self.proc = subprocess.Popen([sys.executable, "-m", "canguard", "run", "-c", str(cfg)], env=env, text=True)
        wait_for_start(self.proc, tmp / "events.jsonl")
        self.peer = can.Bus(interface="udp_multicast", channel=where[0], port=where[1])
        self.peer.set_filters([{"can_id": ESTOP0, "can_mask": 0x7FF, "extended": False},
                               {"can_id": SET_STATE0, "can_mask": 0x7FF, "extended": False}])
        self.normal, self.over = bms_msg(10.0), bms_msg(40.0)

    def trial(self, rnd: random.Random) -> float:
        """One overcurrent -> first Estop latency (s)."""
        resumed = lambda m: m.arbitration_id == SET_STATE0 and bytes(m.data) == CLOSED_LOOP  # noqa: E731
        for attempt in range(100):
            self.peer.send(self.normal)
            try:
                recv_until(self.peer, resumed, timeout_s=0.1)
                break
            except RuntimeError:
                if attempt == 99:
                    raise
        time.sleep(rnd.uniform(0.0, 0.003))
        drain(self.peer)
        t0 = time.perf_counter()
        self.peer.send(self.over)
        recv_until(self.peer, lambda m: m.arbitration_id == ESTOP0)
        return time.perf_counter() - t0

    def close(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(20)
        finally:
            self.peer.shutdown()


def echo_trial(peer: Any, rnd: random.Random) -> float | None:
    """One peer -> echo -> peer round trip (s); None when a datagram was lost."""
    time.sleep(rnd.uniform(0.0, 0.003))
    drain(peer)
    t0 = time.perf_counter()
    peer.send(can.Message(arbitration_id=ECHO_REQ, data=bytes(8), is_extended_id=False))
    try:
        recv_until(peer, lambda m: m.arbitration_id == ECHO_REP, timeout_s=0.5)
    except RuntimeError:
        return None
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--old", required=True, help="revision of the old version")
    ap.add_argument("--new", default=".", help="revision of the new version (default: this checkout's src)")
    ap.add_argument("--trials", type=int, default=300, help="trials per version and of the echo (default 300)")
    ap.add_argument("--fps", type=float, default=8000.0, help="background frames/s on each group (default 8000)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    clean_up_on_sigterm()
    rnd = random.Random(args.seed)
    kids: list[subprocess.Popen[str]] = []
    guarded: dict[str, Guarded] = {}
    samples: dict[str, list[float]] = {"old": [], "new": [], "echo": []}
    echo_peer = None
    try:
        with tempfile.TemporaryDirectory() as d:
            tmp = Path(d)
            srcs = {"old": export(args.old, tmp), "new": export(args.new, tmp)}
            where = {name: group(rnd) for name in ("old", "new", "echo")}
            for name, src in srcs.items():
                guarded[name] = Guarded(src, tmp / name, where[name])
            kids.append(start_child("echo", *where["echo"]))
            echo_peer = can.Bus(interface="udp_multicast", channel=where["echo"][0], port=where["echo"][1])
            echo_peer.set_filters([{"can_id": ECHO_REP, "can_mask": 0x7FF, "extended": False}])
            for g, p in where.values():
                kids.append(start_child("background", g, p, args.fps))
            time.sleep(0.5)
            lost = 0
            for k in range(args.trials):
                order = ["old", "new"] if k % 2 == 0 else ["new", "old"]
                for name in order:
                    samples[name].append(guarded[name].trial(rnd))
                while (rtt := echo_trial(echo_peer, rnd)) is None:
                    lost += 1
                samples["echo"].append(rtt)
    finally:
        for kid in kids:
            kid.send_signal(signal.SIGTERM)
        for g in guarded.values():
            g.close()
        for kid in kids:
            try:
                kid.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                kid.kill()
        if echo_peer is not None:
            echo_peer.shutdown()
    print(f"python {sys.version.split()[0]}, python-can {can.__version__}, {os.cpu_count()} CPUs, load "
          f"{os.getloadavg()[0]:.1f}; {args.trials} trials each, taking turns; background {args.fps:,.0f} frames/s "
          f"on each of 3 groups; old {args.old}, new {args.new}" + (f"; {lost} echo round trips lost" if lost else ""))
    floor = figures(samples["echo"])
    print(f"  {'':28} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} {'p50/echo':>9} {'p99/echo':>9}")
    for name in ("old", "new", "echo"):
        f = figures(samples[name])
        print(f"  {name:28} {f['p50']:8.3f} {f['p99']:8.3f} {f['max']:8.3f} {f['p50'] / floor['p50']:9.2f} "
              f"{f['p99'] / floor['p99']:9.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
