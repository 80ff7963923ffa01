"""Suite ``startup``: how long canguard takes to start and how much memory it holds, beside Python's own floor.

* ``canguard run`` from ``Popen`` to its READY=1 datagram (a real NOTIFY_SOCKET bound here), beside
  ``python -c pass`` from ``Popen`` to exit;
* short commands, whole processes (``canguard --version``, ``check``, a 3-frame ``replay --json``),
  beside ``python -c pass``;
* the daemon's VmRSS when ready and after ``LOAD_S`` seconds of traffic at ``FPS`` frames/s (a sender
  process on its udp_multicast bus), beside a process that only imports canguard's dependencies
  (python-can, cantools, numpy, py_trees, PyYAML).
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

from benchmarks import kit
from benchmarks.kit import Options, Table

SENDER = """
import sys, time
import can, cantools
db = cantools.database.load_file({dbc!r})
m = db.get_message_by_name("BMS_Status")
bms = can.Message(arbitration_id=m.frame_id, is_extended_id=True, data=m.encode(dict(
    Pack_Current=10.0, Pack_Voltage=48.0, State_Of_Charge=80.0, Present=1, Fault=0, Alive_Counter=0)))
other = [can.Message(arbitration_id=0x600 + i, data=bytes(8)) for i in range(64)]
batch = [bms] + [other[i % 64] for i in range(max(1, int({fps} / 100) - 1))]
bus = can.Bus(interface="udp_multicast", channel={group!r}, port={port})
print("ready", flush=True)
sent, start = 0, time.perf_counter()
while True:
    due = int((time.perf_counter() - start) * {fps})
    while sent < due:
        bus.send(batch[sent % len(batch)])
        sent += 1
    time.sleep(0.001)
"""

FLOOR = """
import can, cantools, numpy, py_trees, yaml
for line in open("/proc/self/status"):
    if line.startswith("VmRSS:"):
        print(int(line.split()[1]) / 1024)
"""

TINY_LOG = """(1700000000.000010) can0 18FF50E5#005E147FAA010100
(1700000000.000010) can0 014#F4CA7A3FC1E66F3F
(1700000000.000210) can0 01C#ABD0AF3D6C6EB23D
"""


def ready_and_rss(config: Path, bus: dict[str, object], src: Path, load_s: float, fps: float
                  ) -> tuple[float, float, float]:
    """One daemon: seconds from Popen to READY=1, VmRSS MB then and after ``load_s`` s of traffic at ``fps``."""
    where = config.parent / "notify"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(where))
    sock.settimeout(0.2)
    kids: list[subprocess.Popen[str]] = []
    try:
        t0 = time.perf_counter()
        daemon = subprocess.Popen([sys.executable, "-m", "canguard", "run", "-c", str(config)], text=True,
                                  env=kit.child_env(src, NOTIFY_SOCKET=str(where)))
        kids.append(daemon)
        while True:
            if time.perf_counter() - t0 > 60 or daemon.poll() is not None:
                raise RuntimeError("canguard run sent no READY=1")
            try:
                if "READY=1" in sock.recv(4096).decode().split("\n"):
                    break
            except TimeoutError:
                continue
        ready_s = time.perf_counter() - t0
        rss0 = kit.vmrss_mb(daemon.pid)
        code = SENDER.format(dbc=str(kit.DBC), group=bus["channel"], port=bus["port"], fps=fps)
        sender = subprocess.Popen([sys.executable, "-c", code], env=kit.child_env(src), stdout=subprocess.PIPE,
                                  text=True)
        kids.append(sender)
        assert sender.stdout is not None
        if sender.stdout.readline().strip() != "ready":
            raise RuntimeError("the sender did not start")
        end = time.monotonic() + load_s
        while time.monotonic() < end:  # keep reading its STATUS= lines, as systemd does
            with contextlib.suppress(TimeoutError):
                sock.recv(4096)
        if daemon.poll() is not None:
            raise RuntimeError("canguard run died under load")
        return ready_s, rss0, kit.vmrss_mb(daemon.pid)
    finally:
        for k in reversed(kids):
            kit.stop_process(k)
        sock.close()
        where.unlink(missing_ok=True)


def run(opts: Options) -> Table:
    """The start-up table, worst (highest canguard / peer) first."""
    rounds = 1 if opts.quick else opts.rounds
    load_s, fps = (0.5, 1000.0) if opts.quick else (30.0, 8000.0)
    table = Table("startup", f"start-up time and memory of canguard beside Python's own floor; best of {rounds}",
                  ["measure", "canguard", "peer", "peer figure", "canguard / peer", "unit"], costs=["canguard"])
    rows: list[list[kit.Cell]] = []
    with kit.scratch("startup") as d:
        tmp = Path(d)
        log = tmp / "tiny.log"
        log.write_text(TINY_LOG, encoding="ascii")
        bus = kit.multicast_bus()
        config = kit.write_config(tmp, bus)
        py = [sys.executable]
        commands = {"canguard --version": [*py, "-m", "canguard", "--version"]}
        if not opts.quick:
            commands["canguard check"] = [*py, "-m", "canguard", "check", "-c", str(kit.CONFIG)]
            commands["canguard replay (3 frames) --json"] = [*py, "-m", "canguard", "replay", str(log), "-c",
                                                             str(kit.CONFIG), "--json"]
        runs = [lambda: kit.process([*py, "-c", "pass"], opts.src)]
        runs += [lambda c=c: kit.process(c, opts.src) for c in commands.values()]
        got = kit.best_of(runs, rounds)
        floor = got[0]
        for name, t in zip(commands, got[1:], strict=True):
            rows.append([f"{name}, wall", t.wall_s, "python -c pass", floor.wall_s, kit.ratio(t.wall_s, floor.wall_s),
                         "s"])
        ready, rss_ready, rss_load = float("inf"), 0.0, 0.0
        for _ in range(rounds):
            r, m0, m1 = ready_and_rss(config, bus, opts.src, load_s, fps)
            if r < ready:
                ready, rss_ready, rss_load = r, m0, m1
        rows.append(["canguard run: Popen to READY=1", ready, "python -c pass", floor.wall_s,
                     kit.ratio(ready, floor.wall_s), "s"])
        deps = float(kit.process([*py, "-c", FLOOR], opts.src).out)
        rows.append(["canguard run: VmRSS at READY=1", rss_ready, "process importing the dependencies", deps,
                     kit.ratio(rss_ready, deps), "MB"])
        rows.append([f"canguard run: VmRSS after {load_s:g} s at {fps:,.0f} frames/s", rss_load,
                     "process importing the dependencies", deps, kit.ratio(rss_load, deps), "MB"])
    rows.sort(key=lambda r: -(r[4] if isinstance(r[4], float) else 0.0))
    table.rows = rows
    table.notes.append(f"{os.cpu_count()} cores; bytecode compiled beforehand, as an installed wheel has it")
    if opts.quick:
        table.notes.append("--quick: one round, `--version` only, 0.5 s of load: checks that the suite runs")
    return table
