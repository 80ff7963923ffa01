"""``canguard replay`` of a ROS bag against the candump replay of the same frames, whole processes.

    python benchmarks/bench_rosbag.py [--frames N] [--repeat R] [--storages mcap,sqlite3,ros1] [--cache DIR]

Takes the simulator log of ``bench_replay.py`` (about N frames, default 1,000,000; cached in
``DIR``), writes its frames as ``can_msgs/msg/Frame`` messages on ``/from_can_bus`` into a
rosbag2 MCAP bag, a rosbag2 sqlite3 bag and a ROS 1 bag with the ``rosbags`` writers (the
messages packed here with ``struct``, laid out as CDR / ROS 1 serialise them: rosbags'
own serialiser, which the tests use, takes ~10 us a message), then times, best of R
(default 3), alternating:

* ``python -m canguard replay LOG -c config/canguard.yaml --json`` on the candump log;
* the same on each bag;
* the same on the MCAP bag with ``--export-signals FILE.mcap`` (samples, guard states, events and
  frames sent as MCAP).

The summaries are checked equal (but for the log's name and the bag's stamp counts). The
goals: a bag replays at >= 0.5x the candump replay's speed (its time <= 2x); the MCAP export
costs <= 1.5x the replay of the same bag without it.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_common import compiled
from bench_replay import sim_log

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config" / "canguard.yaml"
TOPIC = "/from_can_bus"


def _messages(log: Path, ros1: bool) -> list[tuple[int, bytes]]:
    """The log's frames as (record time ns, serialised can_msgs/msg/Frame)."""
    from canguard.io.logs import read_log

    out = []
    frame_id = b"can0\x00"
    head = struct.Struct("<4sIII" if ros1 else "<4siII")
    for f in read_log(log):
        ns = round(f.t * 1e6) * 1000
        sec, nsec = divmod(ns, 10**9)
        data = bytes(f.data).ljust(8, b"\x00")
        if ros1:
            raw = struct.pack("<IIII", 0, sec, nsec, 4) + b"can0"
        else:
            raw = head.pack(b"\x00\x01\x00\x00", sec, nsec, len(frame_id)) + frame_id + b"\x00\x00\x00"
        raw += struct.pack("<I???B", f.arbitration_id, f.is_remote_frame, f.is_extended_id, f.is_error_frame,
                           len(f.data)) + data
        out.append((ns, raw))
    return out


def write_bags(log: Path, where: Path, storages: list[str]) -> dict[str, Path]:
    """The log's frames as bags of each storage (written once into ``where``)."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from canguard.io.rosmsgs import CAN_MSGS_FRAME

    bags = {}
    for storage in storages:
        ros1 = storage == "ros1"
        path = where / (f"{log.stem}.bag" if ros1 else f"{log.stem}-{storage}")
        bags[storage] = path
        if path.exists():
            continue
        store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        store.register(get_types_from_msg(CAN_MSGS_FRAME, "can_msgs/msg/Frame"))
        tmp = path.with_name(path.name + ".tmp")
        if ros1:
            with Writer1(tmp) as w:
                msgdef, md5 = store.generate_msgdef("can_msgs/msg/Frame")
                conn = w.add_connection(TOPIC, "can_msgs/msg/Frame", msgdef=msgdef, md5sum=md5)
                for ns, raw in _messages(log, True):
                    w.write(conn, ns, raw)
        else:
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            with Writer2(tmp, version=9, storage_plugin=plugin) as w:
                conn = w.add_connection(TOPIC, "can_msgs/msg/Frame", typestore=store)
                for ns, raw in _messages(log, False):
                    w.write(conn, ns, raw)
        tmp.rename(path)
    return bags


def replay(path: Path, *extra: str) -> tuple[float, dict[str, object]]:
    """Wall time of ``canguard replay PATH --json`` in a subprocess, and its summary."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "canguard", "replay", str(path), "-c", str(CONFIG), "--json", *extra],
                          capture_output=True, text=True, check=False)
    took = time.perf_counter() - t0
    if proc.returncode not in (0, 1):
        raise SystemExit(f"replay {path}: exit {proc.returncode}\n{proc.stderr[-2000:]}")
    return took, json.loads(proc.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--storages", default="mcap,sqlite3,ros1")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "canguard-bench-replay")
    args = ap.parse_args()
    compiled(REPO / "src" / "canguard")
    log, n = sim_log(args.cache, args.frames)
    bags = write_bags(log, args.cache, args.storages.split(","))
    best: dict[str, float] = {}
    summaries: dict[str, dict[str, object]] = {}
    export = Path(tempfile.mkdtemp(prefix="canguard-bench-rosbag-")) / "signals.mcap"
    runs: list[tuple[str, Path, tuple[str, ...]]] = [("candump", log, ()), *((k, v, ()) for k, v in bags.items())]
    if "mcap" in bags:
        runs.append(("mcap --export-signals", bags["mcap"], ("--export-signals", str(export))))
    for _ in range(args.repeat):
        for name, path, extra in runs:
            took, summary = replay(path, *extra)
            best[name] = min(best.get(name, float("inf")), took)
            summaries[name] = {k: v for k, v in summary.items() if k not in ("log", "stamps")}
    for name in summaries:
        if summaries[name] != summaries["candump"]:
            raise SystemExit(f"{name}: the summary differs from candump's")
    print(f"{n:,} frames, best of {args.repeat}, whole processes ({time.strftime('%Y-%m-%d')}, "
          f"{os.uname().nodename}):")
    print("| log | s | frames/s | bag / candump speed |")
    print("| --- | ---: | ---: | ---: |")
    for name, took in sorted(best.items(), key=lambda kv: -kv[1]):
        ratio = "" if name == "candump" else f"{best['candump'] / took:.2f}x"
        print(f"| {name} | {took:.3f} | {n / took:,.0f} | {ratio} |")
    if "mcap --export-signals" in best:
        print(f"MCAP export / replay of the MCAP bag without it: {best['mcap --export-signals'] / best['mcap']:.2f}x "
              f"({export.stat().st_size / 1e6:.1f} MB)")


if __name__ == "__main__":
    main()
