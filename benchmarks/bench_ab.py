"""Two versions of canguard on the same logs, run in alternation: a change's effect without the machine's drift.

    python benchmarks/bench_ab.py --old REV [--new REV] [--frames 2000000] [--repeat 5] [--shapes own,many_ids]

On a shared machine the same replay's time moves by 20 % between runs minutes apart, more than
most changes are worth; ``bench_replay_shapes.py`` compares with peers in the same run, not
with yesterday's code. This script exports ``--old`` (and ``--new``, default: the working tree)
with ``git archive`` into a temporary directory, writes the logs of the chosen shapes once
(``bench_replay_shapes.py``'s), and times whole ``canguard replay LOG -c CONFIG --json``
processes, the two versions taking turns, best and median of ``--repeat``, wall and CPU
(user + system). The two versions' summaries must be equal (else the change altered
behaviour, and the script says so and stops).
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import bench_replay_shapes as shapes
from bench_common import compiled

REPO = Path(__file__).resolve().parents[1]
MAKERS = {"fd_mux_motorola": shapes.fd_mux_motorola, "many_ids": shapes.many_ids,
          "ext_motorola": shapes.ext_motorola, "two_buses": shapes.two_buses}


def export(rev: str, into: Path) -> Path:
    """The ``src`` directory of revision ``rev``, exported into ``into``."""
    archive = into / "src.tar"
    subprocess.run(["git", "-C", str(REPO), "archive", "-o", str(archive), rev, "src"], check=True)
    with tarfile.open(archive) as tar:
        try:
            tar.extractall(into / rev.replace("/", "_"), filter="data")
        except TypeError:  # a Python without extraction filters (3.10 before 3.10.12): our own archive
            tar.extractall(into / rev.replace("/", "_"))
    return compiled(into / rev.replace("/", "_") / "src")


def run(src: Path, log: Path, cfg: Path) -> tuple[float, float, str]:
    """Wall seconds, CPU seconds and the summary of one replay with ``src`` on the path."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "canguard", "replay", str(log), "-c", str(cfg), "--json"],
                          env={**os.environ, "PYTHONPATH": str(src)}, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode not in (0, 1):
        raise SystemExit(f"{src}: canguard replay {log.name}: exit {proc.returncode}: {proc.stderr[-1500:]}")
    return wall, after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, proc.stdout


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", required=True, help="a git revision (commit, tag, HEAD~3...)")
    ap.add_argument("--new", default=None, help="a git revision (default: the working tree's src)")
    ap.add_argument("--frames", type=int, default=2_000_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--shapes", default="own,many_ids,ext_motorola,fd_mux_motorola",
                    help=f"comma-separated: own, {', '.join(MAKERS)}")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="canguard-ab-"))
    try:
        trees = {f"old ({args.old})": export(args.old, work),
                 f"new ({args.new or 'working tree'})": export(args.new, work) if args.new else compiled(REPO / "src")}
        print(f"whole processes, the two versions in turn, {args.repeat} rounds, {args.frames:,} frames a log; "
              "seconds as best / median, wall then CPU\n")
        print("| shape | " + " | ".join(trees) + " | new / old (best CPU) |")
        print("| --- | " + " | ".join("---:" for _ in trees) + " | ---: |")
        for name in args.shapes.split(","):
            if name == "own":
                _dbc, cfg, log = shapes.own_shape(work, args.frames)
            elif name in MAKERS:
                _dbc, cfg, log = shapes.write_shape(MAKERS[name](), work, args.frames)
            else:
                raise SystemExit(f"--shapes: unknown shape {name!r}: expected own or one of {', '.join(MAKERS)}")
            times: dict[str, list[tuple[float, float]]] = {k: [] for k in trees}
            outputs: dict[str, str] = {}
            for _ in range(args.repeat):
                for label, src in trees.items():
                    wall, cpu, out = run(src, log, cfg)
                    times[label].append((wall, cpu))
                    outputs[label] = out
            old, new = outputs.values()
            if old != new:
                raise SystemExit(f"{name}: the two versions' summaries differ: the change altered behaviour")
            cells = []
            for label in trees:
                walls, cpus = sorted(w for w, _ in times[label]), sorted(c for _, c in times[label])
                mid = len(walls) // 2
                cells.append(f"{walls[0]:.3f} / {walls[mid]:.3f}, CPU {cpus[0]:.3f} / {cpus[mid]:.3f}")
            best = [min(c for _, c in times[label]) for label in trees]
            print(f"| {name} | " + " | ".join(cells) + f" | {best[1] / best[0]:.2f} |")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
