"""The live path's cost per frame: blocks of one, this checkout against another revision, taking turns.

    python benchmarks/bench_live_frame.py [--old REV] [--repeat 5] [--runs 3] [--decode-loops 200000]
    valgrind --tool=cachegrind --cache-sim=no python benchmarks/bench_live_frame.py --count struct 20000

A quiet live bus gives the engine one frame at a time (:meth:`Engine.feed
<canguard.engine.core.Engine.feed>`, the block path with a block of one). This measures, in
one process per version and measurement, the CPU time (``time.process_time``) of:

- ``feed``: the bundled config's engine (``config/canguard.yaml``, ``dbc/robot.dbc``, a
  manual clock) fed every frame of the ``examples/*.log.gz`` logs one by one on bus
  ``main``, a fresh engine per log (each log ``--runs`` times, the best run counted):
  ticks, trips and events included, as live;
- ``decode struct`` / ``decode bits``: ``Decoder.decode`` of one frame of a message decoded
  with ``struct`` (``Axis0_Get_Iq``) and of one decoded with the bit maths (``BMS_Status``:
  a Motorola current and a presence flag), in a loop;
- ``decode none``: ``Decoder.decode`` of a frame of no configured message.

With ``--old REV`` the revision's ``src`` (``git archive``) is measured too, the versions
taking turns (each first in turn); the best of ``--repeat`` is printed, with the ratio new / old. Both versions
must count the same frames, ticks and trips over the logs (else the script says so and
stops). Compare ratios, not absolute figures, across machines. ``--count KIND N`` only feeds
``N`` frames of one kind after a warm-up, for an instruction counter (valgrind's cachegrind):
the count of ``N`` minus that of ``0``, over ``N``, is the instructions per frame, unmoved by the
machine's load.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples"
MEASURES = ("feed", "decode struct", "decode bits", "decode none")


def _decode_ns(decode: Any, frame: Any, loops: int) -> float:
    """CPU nanoseconds of one ``decode(frame, "main")``: the best of 20 runs of ``loops / 20`` calls."""
    each = max(1, loops // 20)
    best = float("inf")
    for _ in range(20):
        start = time.process_time()
        for _ in range(each):
            decode(frame, "main")
        best = min(best, time.process_time() - start)
    return best / each * 1e9


def worker(loops: int, runs: int) -> dict[str, Any]:
    """The measures of the canguard on ``sys.path`` (run in a process of its own); each log fed ``runs`` times."""
    from canguard.bt.context import ListSink
    from canguard.config.loader import load_config
    from canguard.decode.decoder import Decoder
    from canguard.engine.core import Engine
    from canguard.io.clock import ManualClock
    from canguard.io.frame import Frame
    from canguard.io.logs import read_log

    cfg = load_config(REPO / "config" / "canguard.yaml")
    logs = [list(read_log(p)) for p in sorted(EXAMPLES.glob("*.log.gz"))]
    cpu = 0.0
    frames = ticks = trips = 0
    for log in logs:
        best = float("inf")
        for _ in range(runs):  # the best of a few short runs: a shared machine's load is seen less
            engine = Engine(cfg, ManualClock(log[0].t), ListSink(), durable=False)
            feed = engine.feed
            start = time.process_time()
            for frame in log:
                feed("main", frame)
            best = min(best, time.process_time() - start)
        cpu += best
        frames += engine.stats.frames
        ticks += engine.stats.ticks
        trips += engine.stats.trip_count
    decoder = Decoder(cfg)
    struct_frame = Frame(1.0, "main", 0x014, bytes.fromhex("F4CA7A3FC1E66F3F"))
    bits_frame = Frame(1.0, "main", 0x18FF50E5, bytes.fromhex("005E147FAA010100"), True)
    none_frame = Frame(1.0, "main", 0x7FF, bytes(8))
    return {
        "feed": cpu / frames * 1e6,
        "decode struct": _decode_ns(decoder.decode, struct_frame, loops),
        "decode bits": _decode_ns(decoder.decode, bits_frame, loops),
        "decode none": _decode_ns(decoder.decode, none_frame, loops),
        "counts": [frames, ticks, trips],
    }


def count_loop(kind: str, n: int) -> None:
    """Feed ``n`` frames of one ``kind`` (``struct``, ``bits``, ``none``: at one time stamp, no tick due;
    ``tick``: a frame every 10 ms) after a warm-up: run under an instruction counter, minus ``n`` = 0."""
    from canguard.bt.context import ListSink
    from canguard.config.loader import load_config
    from canguard.engine.core import Engine
    from canguard.io.clock import ManualClock
    from canguard.io.frame import Frame

    cfg = load_config(REPO / "config" / "canguard.yaml")
    frames = {"struct": Frame(1000.0, "main", 0x014, bytes.fromhex("F4CA7A3FC1E66F3F")),
              "bits": Frame(1000.0, "main", 0x18FF50E5, bytes.fromhex("005E147FAA010100"), True),
              "none": Frame(1000.0, "main", 0x7FF, bytes(8))}
    engine = Engine(cfg, ManualClock(1000.0), ListSink(), durable=False)
    for frame in frames.values():
        engine.feed("main", frame)
    engine.feed("main", frames["struct"]._replace(t=1000.001))
    feed = engine.feed
    if kind == "tick":
        for i in range(n):
            feed("main", frames["struct"]._replace(t=1000.01 + i * 0.01))
        return
    frame = frames[kind]._replace(t=1000.002)
    for _ in range(n):
        feed("main", frame)


def measure(src: Path, loops: int, runs: int) -> dict[str, Any]:
    """One worker process with ``src`` first on the path."""
    proc = subprocess.run([sys.executable, __file__, "--worker", "--decode-loops", str(loops), "--runs", str(runs)],
                          env={**os.environ, "PYTHONPATH": str(src)}, capture_output=True, text=True, check=False)
    if proc.returncode:
        raise SystemExit(f"{src}: worker failed: {proc.stderr[-1500:]}")
    result: dict[str, Any] = json.loads(proc.stdout)
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", help="a git revision to compare with (its src exported with git archive)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--decode-loops", type=int, default=200_000)
    ap.add_argument("--runs", type=int, default=3, help="feeds of each log per process (the best counts)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--count", nargs=2, metavar=("KIND", "N"),
                    help="only feed N frames of KIND (struct, bits, none, tick), for an instruction counter")
    args = ap.parse_args()
    if args.count:
        count_loop(args.count[0], int(args.count[1]))
        return 0
    if args.worker:
        print(json.dumps(worker(args.decode_loops, args.runs)))
        return 0
    sys.path.insert(0, str(Path(__file__).parent))
    from bench_ab import export

    with tempfile.TemporaryDirectory() as tmp:
        versions = {"new": REPO / "src"}
        if args.old:
            versions["old"] = export(args.old, Path(tmp))
        best: dict[str, dict[str, float]] = {name: dict.fromkeys(MEASURES, float("inf")) for name in versions}
        counts: dict[str, Any] = {}
        order = list(versions.items())
        for _ in range(args.repeat):
            order.reverse()  # each version first in turn: on a shared machine the second process of a pair fared
            for name, src in order:  # better or worse by 15-30 %, whichever version it was (measured 2026-11-27)
                found = measure(src, args.decode_loops, args.runs)
                counts[name] = found["counts"]
                for key in MEASURES:
                    best[name][key] = min(best[name][key], found[key])
        if len({json.dumps(c) for c in counts.values()}) > 1:
            raise SystemExit(f"the versions differ in (frames, ticks, trips): {counts}")
    frames, ticks, trips = counts["new"]
    print(f"examples/*.log.gz frame by frame: {frames:,} frames, {ticks:,} ticks, {trips} trips; "
          f"CPU, best of {args.repeat}\n")
    head = "| measure | new |" + (f" old ({args.old}) | new / old |" if args.old else "")
    print(head)
    print("| --- | ---: |" + (" ---: | ---: |" if args.old else ""))
    for key in MEASURES:
        unit, scale = ("µs/frame", 1.0) if key == "feed" else ("ns", 1.0)
        row = f"| {key} | {best['new'][key] * scale:.2f} {unit} |"
        if args.old:
            row += f" {best['old'][key] * scale:.2f} {unit} | {best['new'][key] / best['old'][key]:.2f}x |"
        print(row)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
