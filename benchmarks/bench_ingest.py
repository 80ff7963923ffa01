"""Sustained ingest: four udp_multicast buses at 8,000 frames/s each into one ``canguard run``.

``canguard run`` reads four input buses (in0..in3, one multicast group each) and
sends its task / stop frames on a fifth (``out``), so its own frames never mix
with the counted ones. Four sender processes (python-can udp_multicast) send
8,000 frames/s each for ``--seconds``: per 10 ms, on every bus, the BMS (in0) or
one axis' Get_Iq and Get_Torques frames at normal values, the rest ids no config
uses. Afterwards the daemon's Prometheus counter ``canguard_frames_received``
per bus is compared with what each sender sent (lost = sent - received; goal 0),
and the daemon's CPU share comes from /proc/PID/stat (utime + stime).

    PYTHONPATH=src python benchmarks/bench_ingest.py --seconds 60
"""

from __future__ import annotations

import argparse
import os
import random
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

import yaml

from bench_common import wait_for_start

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"
BUNDLED = REPO / "config" / "canguard.yaml"
DBC = REPO / "dbc" / "robot.dbc"
CLK_TCK = os.sysconf("SC_CLK_TCK")

SENDER = """
import signal, sys, time
import can, cantools
db = cantools.database.load_file({dbc!r})
bus = can.Bus(interface="udp_multicast", channel={group!r}, port={port})
index, fps, seconds = {index}, {fps}, {seconds}
def enc(name, **v):
    m = db.get_message_by_name(name)
    return can.Message(arbitration_id=m.frame_id, data=m.encode(v), is_extended_id=m.is_extended_frame)
if index == 0:
    configured = [enc("BMS_Status", Pack_Current=10.0, Pack_Voltage=48.0, State_Of_Charge=80.0,
                      Present=1, Fault=0, Alive_Counter=0)]
else:
    configured = []
configured += [enc(f"Axis{{index}}_Get_Iq", Iq_Setpoint=2.0, Iq_Measured=2.0),
               enc(f"Axis{{index}}_Get_Torques", Torque_Target=1.0, Torque_Estimate=1.0)]
other = [can.Message(arbitration_id=0x600 + i, data=bytes(8)) for i in range(64)]
per_10ms = int(fps / 100)
batch = configured + [other[i % 64] for i in range(per_10ms - len(configured))]
print("ready", flush=True)
sent, start = 0, time.perf_counter()
end = start + seconds
while True:
    now = time.perf_counter()
    if now >= end:
        break
    due = int((now - start) * fps)
    while sent < due:
        bus.send(batch[sent % len(batch)])
        sent += 1
    time.sleep(0.001)
print(sent, time.perf_counter() - start, flush=True)
bus.shutdown()
"""


def child_env(**extra: str) -> dict[str, str]:
    """This checkout's src on PYTHONPATH; no systemd variables unless given."""
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(SRC), env.get("PYTHONPATH", "")) if p)
    env.update(extra)
    return env


def write_config(tmp: Path, groups: list[tuple[str, int]], out: tuple[str, int]) -> Path:
    """The bundled config on four input buses and one output bus."""
    doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
    doc["dbc"] = [str(DBC)]
    doc["tree"]["file"] = str((BUNDLED.parent / doc["tree"]["file"]).resolve())
    doc["buses"] = {f"in{i}": {"interface": "udp_multicast", "channel": g, "port": p}
                    for i, (g, p) in enumerate(groups)}
    doc["buses"]["out"] = {"interface": "udp_multicast", "channel": out[0], "port": out[1]}
    doc["sources"]["/battery_state"]["bus"] = "in0"
    doc["sources"]["/joint_states"]["bus"] = "in0"
    doc["sources"]["/joint_states"]["effort"] = [
        {"message": f"Axis{i}_Get_Torques", "signal": "Torque_Estimate", "name": f"axis{i}", "bus": f"in{i}"}
        for i in range(4)
    ]
    for i in range(4):
        doc["sources"][f"axis{i}"]["bus"] = f"in{i}"
    for section in (doc["task"], doc["stop"]):
        for frame in section["frames"]:
            frame["bus"] = "out"
    for frame in doc["stop"].get("escalate", []):
        frame["bus"] = "out"
    for action in doc.get("actions", {}).values():
        for frame in action["frames"]:
            frame["bus"] = "out"
    doc["events"] = str(tmp / "events.jsonl")
    doc["state"]["file"] = str(tmp / "i2t_state.json")
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def cpu_s(pid: int) -> float:
    """utime + stime of ``pid`` in seconds (/proc/PID/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def run_delay_s(pid: int) -> float:
    """Seconds the threads of ``pid`` spent runnable but waiting for a CPU (/proc/PID/task/*/schedstat)."""
    total = 0
    for stat in Path(f"/proc/{pid}/task").glob("*/schedstat"):
        try:
            total += int(stat.read_text().split()[1])
        except (OSError, IndexError, ValueError):
            continue  # a thread that ended meanwhile
    return total / 1e9


def scrape(addr: str) -> dict[str, float]:
    """canguard_frames_received_total by bus from the daemon's /metrics."""
    text = urllib.request.urlopen(f"http://{addr}/metrics", timeout=5).read().decode()
    out: dict[str, float] = {}
    for m in re.finditer(r'^canguard_frames_received_total\{bus="([^"]+)"\} (\S+)$', text, re.M):
        out[m.group(1)] = float(m.group(2))
    return out


def free_port() -> int:
    """A free TCP port on localhost for the metrics server."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def main(argv: list[str] | None = None) -> int:
    """Run the senders and the daemon, then print sent / received / lost per bus and CPU share."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="how long to send (default 60)")
    ap.add_argument("--fps", type=float, default=8000.0, help="frames/s per bus (default 8000)")
    args = ap.parse_args(argv)
    rnd = random.Random()
    groups = [(f"239.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}.{i + 1}", rnd.randint(20000, 60000))
              for i in range(5)]
    metrics = f"127.0.0.1:{free_port()}"
    kids: list[subprocess.Popen[Any]] = []
    try:
        with tempfile.TemporaryDirectory() as d:
            tmp = Path(d)
            cfg = write_config(tmp, groups[:4], groups[4])
            daemon = subprocess.Popen([sys.executable, "-m", "canguard", "run", "-c", str(cfg),
                                       "--metrics", metrics], env=child_env())
            kids.append(daemon)
            wait_for_start(daemon, tmp / "events.jsonl")
            senders = []
            for i, (g, p) in enumerate(groups[:4]):
                code = SENDER.format(dbc=str(DBC), group=g, port=p, index=i, fps=args.fps,
                                     seconds=args.seconds)
                s = subprocess.Popen([sys.executable, "-c", code], env=child_env(), stdout=subprocess.PIPE,
                                     text=True)
                kids.append(s)
                senders.append(s)
            for s in senders:
                assert s.stdout is not None
                if s.stdout.readline().strip() != "ready":
                    raise RuntimeError("a sender did not start")
            cpu0, t0, wait0 = cpu_s(daemon.pid), time.perf_counter(), run_delay_s(daemon.pid)
            results = [s.communicate(timeout=args.seconds + 60)[0].split() for s in senders]
            cpu1, t1, wait1 = cpu_s(daemon.pid), time.perf_counter(), run_delay_s(daemon.pid)
            time.sleep(2.5)  # the daemon publishes its counters once a second
            after = scrape(metrics)
            daemon.send_signal(signal.SIGTERM)
            daemon.wait(30)
    finally:
        for k in kids:
            if k.poll() is None:
                k.kill()
            k.wait(10)
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs; 4 udp_multicast buses x "
          f"{args.fps:,.0f} frames/s for {args.seconds:g} s")
    print(f"  {'bus':5} {'sent':>10} {'rate/s':>8} {'received':>10} {'lost':>8}")
    total_sent = total_lost = 0.0
    for i, (sent, elapsed) in enumerate(results):
        bus = f"in{i}"
        got = after.get(bus, 0.0)  # nothing but the sender talks on in0..in3
        lost = int(sent) - got
        total_sent += int(sent)
        total_lost += lost
        print(f"  {bus:5} {int(sent):10d} {int(sent) / float(elapsed):8.0f} {got:10.0f} {lost:8.0f}")
    pct = 100 * total_lost / max(1, total_sent)
    print(f"  total sent {total_sent:.0f}, lost {total_lost:.0f} ({pct:.3f} %)")
    print(f"  canguard CPU: {cpu1 - cpu0:.1f} s in {t1 - t0:.1f} s = {100 * (cpu1 - cpu0) / (t1 - t0):.0f} % "
          f"of one core")
    print(f"  canguard waited for a CPU (runnable, not running): {wait1 - wait0:.1f} s, summed over its threads")
    print(f"  frames received per canguard CPU-second: {(total_sent - total_lost) / max(1e-9, cpu1 - cpu0):,.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
