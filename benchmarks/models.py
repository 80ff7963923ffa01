"""Suite ``models``: the protection models as the engine drives them, beside the per-sample reference maths.

Every model's one entry point is ``advance(times, values, until_edge=True)``: the engine advances a
model over the run of its source's samples up to the next edge (where the tree must tick), then on
from there. Two cases, in one process, best of N:

* **a long run** (replay: a log's block): one motor current of ``SAMPLES`` samples at ~1 kHz (8 s load
  cycles: idle, moves, 34 A overloads, one-sample 60 A spikes, a few 0.2 s gaps), advanced edge by edge;
* **runs of one** (live: a quiet bus gives one frame at a time): each sample advanced alone.

The peer is the per-sample reference maths the tests hold every model to (``tests/reference_models.py``),
fed the same samples in the same run; the edges must be the same samples (else the suite fails).
"""

from __future__ import annotations

import functools
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from benchmarks import kit
from benchmarks.kit import Options, Table

sys.path.insert(0, str(kit.REPO / "tests"))
from canguard.protect import Hysteresis, InrushBlanking, LeakyI2t, ThermalI2t, Threshold
from reference_models import RefHysteresis, RefI2t, RefInrush, RefThreshold

CASES: dict[str, tuple[Callable[[], Any], Callable[[], Any]]] = {
    "threshold": (lambda: Threshold(30.0), lambda: RefThreshold(max_value=30.0)),
    "hysteresis": (lambda: Hysteresis(30.0, 20.0, 0.005, 0.01, max_gap_s=0.05),
                   lambda: RefHysteresis(overcurrent_a=30.0, recovery_a=20.0, trip_after_s=0.005,
                                         recover_after_s=0.01, max_gap_s=0.05)),
    "hysteresis + inrush": (
        lambda: Hysteresis(30.0, 20.0, 0.005, 0.01, InrushBlanking(2.0, 0.08, 45.0), max_gap_s=0.05),
        lambda: RefHysteresis(overcurrent_a=30.0, recovery_a=20.0, trip_after_s=0.005, recover_after_s=0.01,
                              max_gap_s=0.05, inrush=RefInrush(2.0, 0.08, 45.0))),
    "leaky I²t": (lambda: LeakyI2t(12.0, 30.0, 2.0, max_gap_s=0.05),
                  lambda: RefI2t(kind="leaky", continuous_a=12.0, peak_a=30.0, peak_time_s=2.0, max_gap_s=0.05)),
    "thermal I²t": (lambda: ThermalI2t(12.0, tau_s=3.0, tau_cool_s=6.0, max_gap_s=0.05),
                    lambda: RefI2t(kind="thermal", continuous_a=12.0, tau_s=3.0, tau_cool_s=6.0, max_gap_s=0.05)),
}


def load_cycles(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` samples at ~1 kHz (jitter, rare 0.2 s gaps): idle, moves, overloads and spikes, in 8 s cycles."""
    rng = np.random.default_rng(seed)
    dt = rng.uniform(0.0009, 0.0011, n)
    dt[rng.random(n) < 1e-5] = 0.2
    t = np.cumsum(dt)
    phase = (t % 8.0) / 8.0
    v = np.select([phase < 0.25, phase < 0.6, phase < 0.75], [0.5, 15.0, 34.0], 1.0) + rng.normal(0.0, 1.5, n)
    v[rng.random(n) < 2e-4] = 60.0
    return t, v


def reference(make: Callable[[], Any], t: list[float], v: list[float]) -> list[int]:
    """The reference fed one sample at a time: the positions of its edges."""
    update = make().update
    return [i for i, (ti, vi) in enumerate(zip(t, v, strict=True)) if update(vi, ti)]


def edge_runs(make: Callable[[], Any], t: np.ndarray, v: np.ndarray) -> list[int]:
    """The model advanced over the run up to each edge, then on from there: the edges' positions."""
    model, pos, edges = make(), 0, []
    while pos < t.size:
        run = model.advance(t[pos:], v[pos:], until_edge=True)
        edges.extend((pos + run.index).tolist())
        pos += run.taken
    return edges


def runs_of_one(make: Callable[[], Any], t: list[float], v: list[float]) -> list[int]:
    """Each sample advanced alone: the edges' positions."""
    advance = make().advance
    return [i for i, (ti, vi) in enumerate(zip(t, v, strict=True)) if advance((ti,), (vi,), until_edge=True).changed]


def best(fn: Callable[[], list[int]], rounds: int) -> tuple[float, list[int]]:
    """The shortest of ``rounds`` calls (CPU seconds of this thread) and the result."""
    took, out = float("inf"), []
    for _ in range(rounds):
        t0 = time.thread_time()
        out = fn()
        took = min(took, time.thread_time() - t0)
    return took, out


def run(opts: Options) -> Table:
    """The models table, worst (lowest × reference) first."""
    long_n, one_n = (3_000, 1_000) if opts.quick else (2_000_000, 200_000)
    rounds = 1 if opts.quick else opts.rounds
    table = Table("models", f"each protection model advanced as the engine advances it, beside the per-sample "
                  f"reference maths fed the same samples; CPU seconds, best of {rounds}",
                  ["model", "case", "samples", "edges", "canguard s", "canguard ns a sample", "reference s",
                   "× reference"], costs=["canguard s"])
    cases = {"long run, edge by edge (replay)": (load_cycles(long_n, 1), edge_runs),
             "runs of one (live)": (load_cycles(one_n, 2), runs_of_one)}
    for case, ((t, v), way) in cases.items():
        tl, vl = t.tolist(), v.tolist()
        for name, (make, make_ref) in CASES.items():
            ref_s, want = best(functools.partial(reference, make_ref, tl, vl), rounds)
            args = (t, v) if way is edge_runs else (tl, vl)
            got_s, got = best(functools.partial(way, make, *args), rounds)
            if got != want:
                raise RuntimeError(f"{name}, {case}: edges at {got[:5]}... where the reference has {want[:5]}...")
            table.rows.append([name, case, t.size, len(want), got_s, 1e9 * got_s / t.size, ref_s,
                               kit.ratio(ref_s, got_s)])
    table.rows.sort(key=lambda r: r[-1] if isinstance(r[-1], float) else 0.0)
    table.notes += ["× reference: the reference's time over the model's (above 1: the model is faster)",
                    "edges (trips and recoveries) equal to the reference's in every row"]
    if opts.quick:
        table.notes.append("--quick: tiny runs, one round: checks that the suite runs, its figures mean nothing")
    return table
