"""Parse speed of canguard's candump -L reader against can-utils' log2long and python-can.

Run from anywhere (``src/`` is put on the path when canguard is not installed)::

    python benchmarks/bench_parse.py [--frames N] [--repeat R] [--keep DIR]

It writes a realistic candump -L log into a temporary directory (ODrive-style
standard ids ``node << 5 | cmd`` for six axes, a BMS extended id, 8-byte
payloads, strictly increasing timestamps, ~10 kHz), then times in one run:

* canguard: ``read_log`` fully consumed (frames/s), peak RSS of the process
  (to show the reader streams: it does not grow with the log);
* can-utils ``log2long < LOG > /dev/null`` (C: parses and prints), if installed
  (``apt-get install -y can-utils``); skipped with a note otherwise;
* python-can ``can.CanutilsLogReader`` (pure Python, a second peer).

and prints frames/s for each and the ratios canguard / log2long and
canguard / python-can. canguard and log2long take the best of ``--repeat`` runs.
"""

from __future__ import annotations

import argparse
import random
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections import deque
from pathlib import Path

try:
    import canguard  # noqa: F401
except ImportError:  # not pip-installed: use the source tree next to this file
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from canguard.io.logs import ReadStats, read_log

ODRIVE_CMDS = (0x01, 0x09, 0x14, 0x17, 0x1C)  # heartbeat, encoder estimates, Iq, bus V/I, torques
BMS_ID = 0x18FF50E5


def write_log(path: Path, frames: int, seed: int = 6) -> None:
    """Write ``frames`` candump -L lines to ``path``, streaming (a block of lines at a time)."""
    rng = random.Random(seed)
    t_us = 1_700_000_000_000_000
    with path.open("w", encoding="ascii") as out:
        block: list[str] = []
        for i in range(frames):
            t_us += 90 + rng.randrange(21)  # ~10 kHz bus load, jittered, strictly increasing
            payload = rng.getrandbits(64).to_bytes(8, "little").hex().upper()
            if i % 25 == 24:
                line = f"({t_us // 1_000_000}.{t_us % 1_000_000:06d}) can0 {BMS_ID:08X}#{payload}\n"
            else:
                arb = rng.randrange(6) << 5 | rng.choice(ODRIVE_CMDS)
                line = f"({t_us // 1_000_000}.{t_us % 1_000_000:06d}) can0 {arb:03X}#{payload}\n"
            block.append(line)
            if len(block) == 10_000:
                out.write("".join(block))
                block.clear()
        out.write("".join(block))


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far, in MB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def time_canguard(path: Path) -> tuple[float, int]:
    stats = ReadStats()
    t0 = time.perf_counter()
    deque(read_log(path, stats=stats), maxlen=0)
    return time.perf_counter() - t0, stats.frames


def time_log2long(path: Path) -> float | None:
    exe = shutil.which("log2long")
    if exe is None:
        return None
    with path.open("rb") as stdin:
        t0 = time.perf_counter()
        subprocess.run([exe], stdin=stdin, stdout=subprocess.DEVNULL, check=True)
        return time.perf_counter() - t0


def time_python_can(path: Path) -> tuple[float, int]:
    import can

    t0 = time.perf_counter()
    n = 0
    for _ in can.CanutilsLogReader(str(path)):
        n += 1
    return time.perf_counter() - t0, n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000, help="frames in the generated log")
    ap.add_argument("--repeat", type=int, default=3, help="best of R runs for canguard and log2long")
    ap.add_argument("--keep", type=Path, default=None, help="write the log into DIR and keep it")
    args = ap.parse_args(argv)

    tmp = None if args.keep else tempfile.TemporaryDirectory(prefix="canguard-bench-")
    folder = args.keep if args.keep else Path(tmp.name)  # type: ignore[union-attr]
    folder.mkdir(parents=True, exist_ok=True)
    log = folder / "bench.log"
    try:
        t0 = time.perf_counter()
        write_log(log, args.frames)
        size_mb = log.stat().st_size / 1e6
        print(f"log: {args.frames:,} frames, {size_mb:.1f} MB, written in {time.perf_counter() - t0:.1f} s")
        rss_before = peak_rss_mb()

        cg = min(time_canguard(log) for _ in range(max(1, args.repeat)))
        cg_fps = cg[1] / cg[0]
        rss_after = peak_rss_mb()
        print(f"canguard read_log        {cg_fps:>12,.0f} frames/s   ({cg[0]:.2f} s)")
        print(f"  peak RSS {rss_after:.1f} MB (before reading: {rss_before:.1f} MB)")

        l2l_times = [time_log2long(log) for _ in range(max(1, args.repeat))]
        l2l = None if l2l_times[0] is None else min(t for t in l2l_times if t is not None)
        if l2l is None:
            print("can-utils log2long       not installed (apt-get install -y can-utils): ratio skipped")
        else:
            print(f"can-utils log2long       {args.frames / l2l:>12,.0f} frames/s   ({l2l:.2f} s)")

        pc = time_python_can(log)
        pc_fps = pc[1] / pc[0]
        print(f"python-can CanutilsLogReader {pc_fps:>8,.0f} frames/s   ({pc[0]:.2f} s)")

        if l2l is not None:
            print(f"ratio canguard / log2long   = {cg_fps / (args.frames / l2l):.2f}")
        print(f"ratio canguard / python-can = {cg_fps / pc_fps:.2f}")
    finally:
        if tmp is not None:
            tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
