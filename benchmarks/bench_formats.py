"""``canguard replay`` of one log in each of python-can's formats, against python-can's reader alone.

    python benchmarks/bench_formats.py [--frames N] [--repeat R] [--formats asc,blf,trc,csv,mf4] [--keep DIR]

Writes a candump -L log of about N frames (default 600,000) with ``canguard simulate
--scenario overload``, converts it with python-can's own writers (``can.Logger``) to
each format (MF4 only when asammdf is installed: ``pip install -e .[mf4]``), then
times, whole processes with interpreter start-up, best of R runs (wall time and CPU
time, user + system, of the child: CPU time is what other jobs on a shared machine
disturb least):

* ``canguard replay LOG -c config/canguard.yaml --json``: the reader's blocks on the
  column path where it can take them;
* the same with ``Engine.columns = False``: every frame a block of one, as a quiet live bus
  gives them (the reference path; before issue 16 item 3 python-can logs always went this way);
* python-can's reader alone iterating the file (``READER_LOOP``): the floor, since
  replay cannot be faster than reading the messages.

"engine" below is replay minus the floor: what canguard adds on top of python-can. ASC is read
by canguard's own block reader (``src/canguard/io/asc_blocks.py``; python-can's only for what
it does not take): for it python-can's reader is the peer, not a floor.
The summaries of every format and path are checked equal (but for the log's name
and the first / last timestamps: ASC and TRC timestamps are relative to the start;
MF4 keeps offsets from the file's start time).
The table lists the slowest format first.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_common import compiled

REPO = Path(__file__).resolve().parents[1]
OWN_READERS = ("asc",)
"""Formats canguard reads with its own block reader (python-can's for what it does not take: io/asc_blocks.py)."""
CONFIG = REPO / "config" / "canguard.yaml"
FRAMES_PER_S = 600_072 / 233.4
"""Frames per simulated second of the overload scenario (4 axes, BMS, noise ids)."""

READER_LOOP = """
import sys, can
n = 0
for _msg in can.LogReader(sys.argv[1]):
    n += 1
print(n)
"""

FORMATS = "asc,blf,trc,csv" + (",mf4" if importlib.util.find_spec("asammdf") else "")
"""The formats measured by default: MF4 only when asammdf (python-can's MF4 reader and writer) is installed."""

FEED_ONLY = """
import sys
from canguard.cli.main import main
from canguard.engine.core import Engine
Engine.columns = False
sys.exit(main(sys.argv[1:]))
"""


def run(cmd: list[str], repeat: int) -> tuple[float, float, bytes]:
    """Best wall time and best CPU time (user + system) of ``repeat`` runs of ``cmd``, and its last stdout."""
    walls, cpus = [], []
    out = b""
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"))
    for _ in range(repeat):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, env=env)
        walls.append(time.perf_counter() - t0)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
        if proc.returncode not in (0, 1):  # 1: the log tripped
            raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr.decode()[-2000:]}")
        out = proc.stdout
    return min(walls), min(cpus), out


def convert(log: Path, fmt: str) -> Path:
    """``log`` (candump -L) written again by python-can's writer for ``fmt``."""
    import can

    out = log.with_suffix("." + fmt)
    with can.Logger(str(out)) as writer:
        for msg in can.CanutilsLogReader(str(log)):
            writer.on_message_received(msg)
    return out


def comparable(summary: bytes) -> dict[str, object]:
    """A ``--json`` summary without what differs by format alone (the path, relative timestamps)."""
    doc = json.loads(summary)
    for key in ("log", "first_t", "last_t"):
        doc.pop(key, None)
    return doc


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=600_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--formats", default=FORMATS, help=f"comma-separated (default {FORMATS}; mf4 needs asammdf)")
    ap.add_argument("--keep", type=Path, default=None, help="write the logs here and keep them")
    args = ap.parse_args(argv)
    compiled(REPO / "src")  # bytecode as an installed wheel has it (bench_common.compiled)
    work = args.keep or Path(tempfile.mkdtemp(prefix="canguard-formats-"))
    work.mkdir(parents=True, exist_ok=True)
    log = work / "overload.log"
    if not log.exists():
        seconds = f"{args.frames / FRAMES_PER_S:.1f}"
        subprocess.run([sys.executable, "-m", "canguard", "simulate", "--scenario", "overload", "--duration",
                        seconds, "--out", str(log)], check=True, env=dict(os.environ, PYTHONPATH=str(REPO / "src")))
    with open(log, encoding="ascii") as f:
        n = sum(1 for _ in f)
    replay = [sys.executable, "-m", "canguard", "replay"]
    feed = [sys.executable, "-c", FEED_ONLY, "replay"]
    rows = []
    reference = None
    for fmt in ["log", *args.formats.split(",")]:
        path = log if fmt == "log" else convert(log, fmt)
        cols = run([*replay, str(path), "-c", str(CONFIG), "--json"], args.repeat)
        frames = run([*feed, str(path), "-c", str(CONFIG), "--json"], args.repeat)
        floor = run([sys.executable, "-c", READER_LOOP, str(path)], args.repeat) if fmt != "log" else None
        for what, (_w, _c, out) in (("columns", cols), ("frame by frame", frames)):
            got = comparable(out)
            reference = reference or got
            if got != reference:
                raise SystemExit(f"{fmt} ({what}): the summary differs from the candump log's")
        rows.append((fmt, cols, frames, floor))
        print(f"measured {fmt}", file=sys.stderr)
    rows.sort(key=lambda r: -r[1][1])  # slowest first (CPU time of the replay)
    print(f"\ncanguard replay of {n:,} frames (overload scenario, config/canguard.yaml) per format; whole "
          f"processes, best of {args.repeat}; seconds as wall / CPU (user + system); slowest first\n")
    print("| format | replay (blocks) | replay, frame by frame | python-can reader alone | engine share "
          "(replay − reader) | replay frames/s (CPU) |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for fmt, cols, frames, floor in rows:
        own = fmt in OWN_READERS  # read by canguard's own reader: python-can's is the peer, not a floor
        name = "candump -L" if fmt == "log" else fmt.upper()
        name += " (canguard's reader)" if own or fmt == "log" else ""
        fl = f"{floor[0]:.2f} / {floor[1]:.2f}" if floor else "—"
        share = f"{cols[1] - floor[1]:.2f} s ({(cols[1] - floor[1]) / cols[1]:.0%})" if floor and not own else (
            f"python-can's reader alone takes {floor[1] / cols[1]:.2f}x the whole replay" if floor else "—")
        print(f"| {name} | {cols[0]:.2f} / {cols[1]:.2f} | {frames[0]:.2f} / {frames[1]:.2f} | {fl} | {share} "
              f"| {n / cols[1]:,.0f} |")
    if args.keep is None:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
