"""The live block type: a drained receive queue taken as a list of frames, or made into a column block.

    python benchmarks/bench_blocks.py [--frames 60000] [--sizes 1,8,64,512] [--repeat 3]

The live daemon drains its receive queue into a block (one frame on a quiet bus, up to
513 on a busy one) and calls :meth:`Engine.take <canguard.engine.core.Engine.take>`, the
method a replay calls with a log's blocks. A block may be the frames themselves or a
column block (:class:`~canguard.io.candump.Columns`, what the candump and python-can log
readers give): the columns decode each configured message's rows at once, but the frames
must first be made into text columns, and a message's rows are few in a small block.
This measures both, in one process, taking turns: the CPU time per frame of the bundled
config's engine over frames of every message of the bundled DBC (a fifth of them
configured, times 0.5 ms apart), the conversion to columns included. Both must leave the
same counts (else the script says so and stops). Ratios, not absolute figures, are what
to compare across machines.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import cantools

from bench_common import BUNDLED, DBC
from canguard.bt.context import ListSink
from canguard.config.loader import load_config
from canguard.engine.core import Engine
from canguard.io.block import Block
from canguard.io.clock import ManualClock
from canguard.io.frame import Frame


def frames_of_every_message(count: int) -> list[Frame]:
    """``count`` frames cycling through the DBC's messages, 0.5 ms apart, with in-range values (no trip)."""
    db = cantools.database.load_file(str(DBC))
    payloads = []
    for message in db.messages:
        values = {s.name: s.minimum if s.minimum is not None else 0 for s in message.signals}
        for s in message.signals:
            if "current" in s.name.lower():
                values[s.name] = 10.0
            if "present" in s.name.lower():
                values[s.name] = 1
        try:
            data = message.encode(values, strict=False)
        except (ValueError, KeyError):
            data = bytes(message.length)
        payloads.append((message.frame_id, bytes(data), bool(message.is_extended_frame)))
    return [Frame(1000.0 + k * 0.0005, "main", cid, data, ext)
            for k, (cid, data, ext) in ((k, payloads[k % len(payloads)]) for k in range(count))]


def as_columns(frames: list[Frame]) -> Block:
    """Classic frames of one channel, in order, as one block."""
    return Block.of_frames(frames)


def run(cfg: Any, frames: list[Frame], size: int, columns: bool) -> tuple[float, tuple[int, ...]]:
    """CPU seconds to take ``frames`` in blocks of ``size`` (made into columns or not), and the counts left."""
    engine = Engine(cfg, ManualClock(frames[0].t), ListSink(), durable=False)
    start = time.process_time()
    for i in range(0, len(frames), size):
        block = frames[i:i + size]
        engine.take("main", as_columns(block) if columns else Block.of_frames(block))
    cpu = time.process_time() - start
    d = engine.decoder
    return cpu, (engine.stats.frames, d.decoded, d.skipped, engine.stats.ticks, engine.stats.trip_count)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60_000)
    ap.add_argument("--sizes", default="1,8,64,512")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    cfg = load_config(BUNDLED)
    frames = frames_of_every_message(args.frames)
    print(f"{args.frames:,} frames of every message of {DBC.name}, CPU per frame, best of {args.repeat}\n")
    print("| block size | frames | columns | columns / frames |")
    print("| ---: | ---: | ---: | ---: |")
    for size in map(int, args.sizes.split(",")):
        best = {False: float("inf"), True: float("inf")}
        counts: dict[bool, tuple[int, ...]] = {}
        for _ in range(args.repeat):
            for columns in (False, True):
                cpu, counts[columns] = run(cfg, frames, size, columns)
                best[columns] = min(best[columns], cpu)
        if counts[False] != counts[True]:
            raise SystemExit(f"blocks of {size}: frames left {counts[False]}, columns {counts[True]}")
        us = {k: v / len(frames) * 1e6 for k, v in best.items()}
        print(f"| {size} | {us[False]:.2f} µs | {us[True]:.2f} µs | {us[True] / us[False]:.2f}x |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
