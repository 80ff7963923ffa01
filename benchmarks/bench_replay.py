"""Speed and memory of ``canguard replay`` against cantools decode and can-utils' log2long.

Run from anywhere (``src/`` is put on the path when canguard is not installed)::

    python benchmarks/bench_replay.py [--frames N] [--rss-frames M] [--profile] [--cache DIR]

It writes a realistic candump -L log with canguard's simulator (scenarios
``normal`` + ``load``: four ODrive axes, a BMS and 40 unconfigured ids, ~8,000
frames/s of simulated time; the duration is chosen so that the log has about N
frames) and caches it in ``DIR`` (default: ``$TMPDIR/canguard-bench-replay``).
Then, in one run, it times:

* ``canguard replay LOG -c config/canguard.yaml --json`` end to end in a
  subprocess (interpreter start-up included), with the subprocess' peak RSS
  (``os.wait4``'s rusage of that child only);
* the same replay in-process (:func:`canguard.cli.replay.replay_one`);
* ``cantools decode --single-line dbc/robot.dbc < LOG > /dev/null`` (decodes
  and prints; pure Python, so by default timed on a 100,000-frame prefix and
  scaled: the figure is frames/s either way);
* can-utils ``log2long < LOG > /dev/null`` (C: parses and prints; best of 3),
  skipped with a note when can-utils is not installed;

and prints frames/s and the ratios canguard / cantools (issue 6 goal >= 10) and
canguard / log2long (goal >= 0.3). ``--rss-frames 10000000`` also replays a
10 M-frame log in a subprocess and prints its peak RSS next to the N-frame
one (goal <= 100 MB, flat in the log's length). ``--profile`` runs the
in-process replay under cProfile and prints the top 15 functions by tottime.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import itertools
import os
import pstats
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

try:
    import canguard  # noqa: F401
except ImportError:  # not pip-installed: use the source tree next to this file
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from bench_common import compiled
from canguard.cli.replay import ReplayOptions, replay_one
from canguard.config.loader import load_config
from canguard.sim import write_log

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"
CONFIG = REPO / "config" / "canguard.yaml"
DBC = REPO / "dbc" / "robot.dbc"
SCENARIOS = ("normal", "load")
FRAMES_PER_S = 8000.0
"""Frames per second of simulated time with the load scenario (its stated bus load)."""
SEED = 0


def sim_log(cache: Path, frames: int) -> tuple[Path, int]:
    """The cached simulator log of about ``frames`` frames (written once): (path, exact frame count)."""
    cache.mkdir(parents=True, exist_ok=True)
    path = cache / f"sim-{'-'.join(SCENARIOS)}-seed{SEED}-{frames}.log"
    if not path.exists():
        t0 = time.perf_counter()
        tmp = path.with_suffix(".tmp.log")
        n = write_log(tmp, frames / FRAMES_PER_S, db=str(DBC), scenarios=list(SCENARIOS), seed=SEED)
        tmp.replace(path)
        print(f"wrote {path} ({n:,} frames, {path.stat().st_size / 1e6:.0f} MB) in "
              f"{time.perf_counter() - t0:.1f} s", file=sys.stderr)
    with path.open("rb") as f:
        n = sum(chunk.count(b"\n") for chunk in iter(lambda: f.read(1 << 20), b""))
    return path, n


def prefix(path: Path, lines: int) -> Path:
    """The first ``lines`` lines of ``path``, cached next to it."""
    out = path.with_name(f"{path.stem}.first{lines}.log")
    if not out.exists():
        with path.open("rb") as src, out.open("wb") as dst:
            dst.writelines(itertools.islice(src, lines))
    return out


def env() -> dict[str, str]:
    """The environment of subprocesses: canguard from this source tree."""
    old = os.environ.get("PYTHONPATH")
    return {**os.environ, "PYTHONPATH": str(SRC) + (os.pathsep + old if old else "")}


def replay_subprocess(log: Path) -> tuple[float, float, dict[str, object]]:
    """``canguard replay LOG --json`` in a subprocess: (wall seconds, peak RSS MB, summary)."""
    import json

    with tempfile.TemporaryFile("w+") as out:
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-m", "canguard", "replay", str(log), "-c", str(CONFIG), "--json"],
            stdout=out, stderr=subprocess.PIPE, env=env(), text=True,
        )
        assert proc.stderr is not None
        err = proc.stderr.read()  # small; read before waiting so a chatty child cannot block
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            raise SystemExit(f"canguard replay failed ({proc.returncode}):\n{err}")
        out.seek(0)
        summary = json.load(out)
    return wall, usage.ru_maxrss / 1024, summary


def replay_inprocess(log: Path, profile: bool) -> tuple[float, str]:
    """replay_one in this process: (seconds, cProfile top 15 by tottime or "")."""
    cfg = load_config(CONFIG)
    prof = cProfile.Profile() if profile else None
    t0 = time.perf_counter()
    if prof is not None:
        prof.enable()
    replay_one(cfg, log, ReplayOptions())
    if prof is not None:
        prof.disable()
    wall = time.perf_counter() - t0
    text = ""
    if prof is not None:
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(15)
        text = buf.getvalue()
    return wall, text


def time_shell(cmd: list[str], log: Path, repeat: int) -> float | None:
    """Best wall time of ``cmd < LOG > /dev/null`` over ``repeat`` runs (None when cmd is missing)."""
    exe = shutil.which(cmd[0])
    if exe is None:
        return None
    best = float("inf")
    for _ in range(repeat):
        with log.open("rb") as stdin:
            t0 = time.perf_counter()
            subprocess.run([exe, *cmd[1:]], stdin=stdin, stdout=subprocess.DEVNULL, check=True)
            best = min(best, time.perf_counter() - t0)
    return best


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=1_000_000, help="frames in the log (default 1,000,000)")
    ap.add_argument("--rss-frames", type=int, default=0, metavar="M",
                    help="also replay an M-frame log for peak RSS (e.g. 10000000)")
    ap.add_argument("--cantools-frames", type=int, default=100_000, metavar="K",
                    help="time cantools on a K-frame prefix and scale (0: the whole log; default 100,000)")
    ap.add_argument("--profile", action="store_true",
                    help="cProfile the in-process replay: top 15 by tottime")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "canguard-bench-replay",
                    help="where generated logs are kept between runs")
    args = ap.parse_args(argv)
    compiled(SRC)  # bytecode as an installed wheel has it (bench_common.compiled)

    log, n = sim_log(args.cache, args.frames)
    print(f"log: {log} ({n:,} frames, {log.stat().st_size / 1e6:.0f} MB); config {CONFIG.relative_to(REPO)}")

    e2e_s, rss_mb, summary = replay_subprocess(log)
    inproc_s, profile_text = replay_inprocess(log, profile=False)
    frames = summary["frames"]
    assert isinstance(frames, dict) and frames["read"] == n, frames
    trips = summary["trips"]
    assert isinstance(trips, list)

    ct_n = n if args.cantools_frames <= 0 or args.cantools_frames >= n else args.cantools_frames
    ct_log = log if ct_n == n else prefix(log, ct_n)
    ct_s = time_shell(["cantools", "decode", "--single-line", str(DBC)], ct_log, repeat=1)
    l2l_s = time_shell(["log2long"], log, repeat=3)

    e2e_fps, inproc_fps = n / e2e_s, n / inproc_s
    rows = [
        ("canguard replay (subprocess, end to end)", e2e_fps),
        ("canguard replay_one (in-process)", inproc_fps),
    ]
    if ct_s is not None:
        note = "" if ct_n == n else f" (on the first {ct_n:,} frames, scaled)"
        rows.append((f"cantools decode --single-line{note}", ct_n / ct_s))
    if l2l_s is not None:
        rows.append(("can-utils log2long (best of 3)", n / l2l_s))
    print("\n| command | frames/s |\n| --- | ---: |")
    for name, fps in rows:
        print(f"| {name} | {fps:,.0f} |")
    print(f"\nreplay: {frames['decoded']:,} decoded, {len(trips)} trips, "
          f"{summary['ticks']:,} ticks, {summary['frames_sent']:,} frames canguard would send")
    if ct_s is not None:
        ct_fps = ct_n / ct_s
        print(f"canguard / cantools: {e2e_fps / ct_fps:.1f}x end to end, "
              f"{inproc_fps / ct_fps:.1f}x in-process (goal >= 10x)")
    else:
        print("cantools not found: pip install cantools")
    if l2l_s is not None:
        l2l_fps = n / l2l_s
        print(f"canguard / log2long: {e2e_fps / l2l_fps:.2f}x end to end, "
              f"{inproc_fps / l2l_fps:.2f}x in-process (goal >= 0.3x)")
    else:
        print("log2long not found: apt-get install -y can-utils")
    print(f"peak RSS of the replay subprocess: {rss_mb:.1f} MB ({n:,} frames)")

    if args.rss_frames:
        big, big_n = sim_log(args.cache, args.rss_frames)
        big_s, big_rss, _ = replay_subprocess(big)
        print(f"peak RSS of the replay subprocess: {big_rss:.1f} MB ({big_n:,} frames, "
              f"{big_n / big_s:,.0f} frames/s end to end; goal <= 100 MB)")

    if args.profile:
        _, profile_text = replay_inprocess(log, profile=True)
        print("\ncProfile of the in-process replay (top 15 by tottime):")
        print(profile_text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
