"""Start-up and memory of ``canguard run``.

1. Start to ``READY=1``: ``canguard run`` as a subprocess with a real
   NOTIFY_SOCKET (a unix datagram socket this script binds), from ``Popen`` to
   the READY=1 datagram, over ``--runs`` runs (default 5); the peer figure is
   ``python -c pass`` from ``Popen`` to exit. Goal: <= 1 s.
2. RSS under load: one daemon fed 8,000 frames/s (a sender process on
   udp_multicast: BMS at 100 Hz, the rest ids no config uses) for
   ``--minutes`` (default 10); VmRSS from /proc/PID/status every ``--every``
   seconds (default 60) and at the end. Goal: <= 80 MB and flat.

    PYTHONPATH=src python benchmarks/bench_startup.py --runs 5 --minutes 10

3. With ``--commands N``: the fixed cost of short commands (issue 16), best and median of N
   whole processes, wall and CPU seconds: ``canguard --help``, ``--version``, ``check``,
   ``replay`` of a 3-frame log (``--json``), next to ``python -c pass``. ``--src DIR`` times
   another source tree (a before/after comparison); ``--runs 0`` skips part 1, ``--minutes 0`` part 2.

    python benchmarks/bench_startup.py --commands 10 --runs 0 --minutes 0
"""

from __future__ import annotations

import argparse
import os
import random
import resource
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

from bench_common import clean_up_on_sigterm, compiled, write_config

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"
DBC = REPO / "dbc" / "robot.dbc"

SENDER = """
import sys, time
import can, cantools
db = cantools.database.load_file({dbc!r})
m = db.get_message_by_name("BMS_Status")
bms = can.Message(arbitration_id=m.frame_id, is_extended_id=True, data=m.encode(dict(
    Pack_Current=10.0, Pack_Voltage=48.0, State_Of_Charge=80.0, Present=1, Fault=0, Alive_Counter=0)))
other = [can.Message(arbitration_id=0x600 + i, data=bytes(8)) for i in range(64)]
batch = [bms] + [other[i % 64] for i in range(int({fps} / 100) - 1)]
bus = can.Bus(interface="udp_multicast", channel={group!r}, port={port})
sent, start = 0, time.perf_counter()
while True:
    due = int((time.perf_counter() - start) * {fps})
    while sent < due:
        bus.send(batch[sent % len(batch)])
        sent += 1
    time.sleep(0.001)
"""


def child_env(**extra: str) -> dict[str, str]:
    """This checkout's src on PYTHONPATH; no systemd variables unless given."""
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(SRC), env.get("PYTHONPATH", "")) if p)
    env.update(extra)
    return env


def unique_udp(rnd: random.Random) -> dict[str, Any]:
    """A udp_multicast bus on a random group and port."""
    group = f"239.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}"
    return {"interface": "udp_multicast", "channel": group, "port": rnd.randint(20000, 60000)}


def vmrss_mb(pid: int) -> float:
    """VmRSS of ``pid`` in MB (/proc/PID/status)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def start_to_ready(config: Path, timeout_s: float = 30.0) -> float:
    """Seconds from Popen of ``canguard run`` to its READY=1 datagram."""
    d = tempfile.mkdtemp(prefix="cgb")
    path = os.path.join(d, "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    proc = None
    try:
        sock.bind(path)
        sock.settimeout(0.5)
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "canguard", "run", "-c", str(config)],
                                env=child_env(NOTIFY_SOCKET=path))
        while True:
            if time.perf_counter() - t0 > timeout_s or proc.poll() is not None:
                raise RuntimeError("canguard run sent no READY=1")
            try:
                data = sock.recv(4096).decode()
            except TimeoutError:
                continue
            if "READY=1" in data.split("\n"):
                return time.perf_counter() - t0
    finally:
        if proc is not None and proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)
        sock.close()
        shutil.rmtree(d, ignore_errors=True)


def python_pass() -> float:
    """Seconds from Popen of ``python -c pass`` to its exit."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True, env=child_env(), timeout=30)
    return time.perf_counter() - t0


TINY_LOG = """(1700000000.000010) can0 18FF50E5#005E147FAA010100
(1700000000.000010) can0 014#F4CA7A3FC1E66F3F
(1700000000.000210) can0 01C#ABD0AF3D6C6EB23D
"""


def command_costs(runs: int, tmp: Path, src: Path) -> None:
    """Best / median wall and CPU seconds of short ``canguard`` commands, whole processes."""
    log = tmp / "tiny.log"
    log.write_text(TINY_LOG, encoding="ascii")
    config = REPO / "config" / "canguard.yaml"
    commands = {
        "python -c pass": ["-c", "pass"],
        "canguard --help": ["-m", "canguard", "--help"],
        "canguard --version": ["-m", "canguard", "--version"],
        "canguard check": ["-m", "canguard", "check", "-c", str(config)],
        "canguard replay (3 frames) --json": ["-m", "canguard", "replay", str(log), "-c", str(config), "--json"],
    }
    env = child_env()
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(src), env.get("PYTHONPATH", "")) if p)
    print(f"\nshort commands, {runs} runs each ({src}): best / median seconds")
    print("| command | wall | CPU |")
    print("| --- | ---: | ---: |")
    for name, argv in commands.items():
        walls, cpus = [], []
        for _ in range(runs):
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            subprocess.run([sys.executable, *argv], check=True, env=env, capture_output=True, timeout=60)
            walls.append(time.perf_counter() - t0)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpus.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
        print(f"| {name} | {min(walls):.3f} / {statistics.median(walls):.3f} "
              f"| {min(cpus):.3f} / {statistics.median(cpus):.3f} |")


def rss_under_load(config: Path, bus: dict[str, Any], minutes: float, every_s: float, fps: float) -> None:
    """Print the daemon's VmRSS every ``every_s`` while a sender feeds it ``fps`` frames/s."""
    kids: list[subprocess.Popen[bytes]] = []
    try:
        events = Path(yaml.safe_load(config.read_text())["events"])
        events.unlink(missing_ok=True)  # the start-up runs wrote theirs there
        daemon = subprocess.Popen([sys.executable, "-m", "canguard", "run", "-c", str(config)],
                                  env=child_env())
        kids.append(daemon)
        deadline = time.monotonic() + 30
        while not (events.exists() and b'"start"' in events.read_bytes()):
            if time.monotonic() > deadline or daemon.poll() is not None:
                raise RuntimeError("canguard run did not start")
            time.sleep(0.05)
        code = SENDER.format(dbc=str(DBC), group=bus["channel"], port=bus["port"], fps=fps)
        kids.append(subprocess.Popen([sys.executable, "-c", code], env=child_env()))
        t0 = time.monotonic()
        end = t0 + minutes * 60
        print(f"\nRSS of canguard run at {fps:,.0f} frames/s for {minutes:g} min")
        print(f"  {'t (s)':>7} {'VmRSS MB':>9}")
        print(f"  {0:7.0f} {vmrss_mb(daemon.pid):9.1f}")
        samples = []
        while True:
            now = time.monotonic()
            if now >= end:
                break
            time.sleep(min(every_s, end - now))
            rss = vmrss_mb(daemon.pid)
            samples.append(rss)
            print(f"  {time.monotonic() - t0:7.0f} {rss:9.1f}", flush=True)
        if daemon.poll() is not None:
            raise RuntimeError("canguard run died under load")
        print(f"  first {samples[0]:.1f} MB, last {samples[-1]:.1f} MB, max {max(samples):.1f} MB")
    finally:
        for k in kids:
            if k.poll() is None:
                k.send_signal(signal.SIGTERM)
                try:
                    k.wait(10)
                except subprocess.TimeoutExpired:
                    k.kill()
                    k.wait(10)


def main(argv: list[str] | None = None) -> int:
    """Measure start to READY=1, then RSS under load."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5, help="start-up runs (default 5)")
    ap.add_argument("--minutes", type=float, default=10.0, help="RSS run length (default 10; 0 skips)")
    ap.add_argument("--every", type=float, default=60.0, help="seconds between RSS samples (default 60)")
    ap.add_argument("--fps", type=float, default=8000.0, help="frames/s during the RSS run (default 8000)")
    ap.add_argument("--commands", type=int, default=0, metavar="N",
                    help="time short commands (--help, --version, check, a 3-frame replay) N times each "
                         "(default 0: not)")
    ap.add_argument("--src", type=Path, default=SRC,
                    help="with --commands: the source tree to time (default: this one)")
    args = ap.parse_args(argv)
    clean_up_on_sigterm()  # a killed run stops the daemon and load it started (bench_common)
    compiled(args.src.resolve())  # bytecode as an installed wheel has it (bench_common.compiled)
    rnd = random.Random()
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if args.commands > 0:
            command_costs(args.commands, tmp, args.src.resolve())
        bus = unique_udp(rnd)
        config = write_config(tmp, bus)
        python_pass()  # warm the page cache for both
        if args.runs > 0:
            ready = [start_to_ready(config) for _ in range(args.runs)]
            peer = [python_pass() for _ in range(args.runs)]
            r, p = statistics.median(ready), statistics.median(peer)
            print(f"\nstart -> READY=1 over {args.runs} runs (s): median {r:.3f}, min {min(ready):.3f}, "
                  f"max {max(ready):.3f}")
            print(f"python -c pass (s):                  median {p:.3f}, min {min(peer):.3f}, "
                  f"max {max(peer):.3f}")
            print(f"ratio canguard READY / python start: {r / p:.1f}")
        if args.minutes > 0:
            rss_under_load(config, bus, args.minutes, args.every, args.fps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
