"""The protection models over one long run of samples vs the per-sample reference loop, in one process.

Each model advances over a run of ``--samples`` current samples (a motor's load cycles:
idle, ramps, overcurrent bursts, one-sample spikes, a few stale gaps, at ~1 kHz) in one
call (``advance``), and in runs stopped at every edge (``advance(until_edge=True)``, what
the engine does to tick the tree there); the peer is the same samples fed one by one to
the per-sample reference maths the tests hold the models to (``tests/reference_models.py``),
measured in the same run. Both must find the same edges. Best of ``--repeat``.

Then the live bus's case: a run of ONE sample, ``--one`` samples of the same signal fed one
at a time to ``model.advance((t,), (value,))``, beside the reference's ``update`` in the same
run (µs per sample, and the ratio to the reference).

    PYTHONPATH=src python benchmarks/bench_models.py --samples 2000000 --one 200000 --repeat 3
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.reference_models import RefHysteresis, RefI2t, RefInrush, RefThreshold  # noqa: E402

from canguard.protect import Hysteresis, InrushBlanking, LeakyI2t, ThermalI2t, Threshold  # noqa: E402

CASES: dict[str, tuple[Callable[[], Any], Callable[[], Any]]] = {
    "threshold": (lambda: Threshold(30.0), lambda: RefThreshold(max_value=30.0)),
    "hysteresis": (lambda: Hysteresis(30.0, 20.0, 0.005, 0.01, max_gap_s=0.05),
                   lambda: RefHysteresis(overcurrent_a=30.0, recovery_a=20.0, trip_after_s=0.005,
                                         recover_after_s=0.01, max_gap_s=0.05)),
    "hysteresis+inrush": (
        lambda: Hysteresis(30.0, 20.0, 0.005, 0.01, InrushBlanking(2.0, 0.08, 45.0), max_gap_s=0.05),
        lambda: RefHysteresis(overcurrent_a=30.0, recovery_a=20.0, trip_after_s=0.005, recover_after_s=0.01,
                              max_gap_s=0.05, inrush=RefInrush(2.0, 0.08, 45.0))),
    "leaky_i2t": (lambda: LeakyI2t(12.0, 30.0, 2.0, max_gap_s=0.05),
                  lambda: RefI2t(kind="leaky", continuous_a=12.0, peak_a=30.0, peak_time_s=2.0, max_gap_s=0.05)),
    "thermal_i2t": (lambda: ThermalI2t(12.0, tau_s=3.0, tau_cool_s=6.0, max_gap_s=0.05),
                    lambda: RefI2t(kind="thermal", continuous_a=12.0, tau_s=3.0, tau_cool_s=6.0, max_gap_s=0.05)),
}


def load_cycles(n: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """``n`` samples at ~1 kHz (jitter, rare 0.2 s gaps): idle, moves, overloads and spikes, in cycles."""
    rng = np.random.default_rng(seed)
    dt = rng.uniform(0.0009, 0.0011, n)
    dt[rng.random(n) < 1e-5] = 0.2
    t = np.cumsum(dt)
    phase = (t % 8.0) / 8.0  # an 8 s cycle: idle, move, overload, idle
    level = np.select([phase < 0.25, phase < 0.6, phase < 0.75], [0.5, 15.0, 34.0], 1.0)
    v = level + rng.normal(0.0, 1.5, n)
    v[rng.random(n) < 2e-4] = 60.0  # one-sample spikes
    return t, v


def best(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """The shortest wall time of ``repeat`` calls, and the last call's result."""
    times, out = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return min(times), out


def per_sample(make: Callable[[], Any], t: list[float], v: list[float]) -> list[int]:
    """The reference fed one sample at a time: the positions of its edges."""
    ref = make()
    update = ref.update
    return [i for i, (ti, vi) in enumerate(zip(t, v, strict=True)) if update(vi, ti)]


def one_run(make: Callable[[], Any], t: np.ndarray, v: np.ndarray) -> list[int]:
    """The model over the whole run in one call."""
    return make().advance(t, v).index.tolist()  # type: ignore[no-any-return]


def edge_runs(make: Callable[[], Any], t: np.ndarray, v: np.ndarray) -> list[int]:
    """The model over the run stopped at every edge, as the engine feeds it."""
    model, pos, edges = make(), 0, []
    while pos < t.size:
        run = model.advance(t[pos:], v[pos:], until_edge=True)
        edges.extend((pos + run.index).tolist())
        pos += run.taken
    return edges


def runs_of_one(make: Callable[[], Any], t: list[float], v: list[float]) -> list[int]:
    """The samples fed one at a time, each ``advance`` on a 1-tuple run; the edges' positions."""
    model = make()
    advance = model.advance
    return [i for i, (ti, vi) in enumerate(zip(t, v, strict=True)) if advance((ti,), (vi,)).changed]


def one_at_a_time(n: int, repeat: int) -> int:
    """Print the cost of a run of one per model beside the reference's update; 1 when edges differ."""
    t, v = load_cycles(n, seed=2)
    tl, vl = t.tolist(), v.tolist()
    print(f"\nruns of one: {n:,} samples fed one at a time, best of {repeat}, µs per sample")
    print(f"{'model':<18} {'reference':>10} {'advance':>8} {'x':>6}")
    bad = 0
    for name, (make, make_ref) in CASES.items():
        ref_s, want = best(functools.partial(per_sample, make_ref, tl, vl), repeat)
        adv_s, got_adv = best(functools.partial(runs_of_one, make, tl, vl), repeat)
        same = want == got_adv
        bad += not same
        us = 1e6 / n
        print(f"{name:<18} {ref_s * us:>10.2f} {adv_s * us:>8.2f} {adv_s / ref_s:>6.2f}"
              f"{'' if same else '  EDGES DIFFER'}")
    return bad


def main() -> int:
    """Measure every model; print a table; non-zero exit when a model's edges differ from the reference's."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=2_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--one", type=int, default=200_000, help="samples fed one at a time (runs of one)")
    args = ap.parse_args()
    t, v = load_cycles(args.samples)
    tl, vl = t.tolist(), v.tolist()
    print(f"{args.samples:,} samples, best of {args.repeat}")
    print(f"{'model':<18} {'edges':>6} {'per-sample s':>13} {'one run s':>10} {'x':>7} {'at edges s':>11} {'x':>7}")
    bad = 0
    for name, (make, make_ref) in CASES.items():
        ref_s, want = best(functools.partial(per_sample, make_ref, tl, vl), args.repeat)
        run_s, got = best(functools.partial(one_run, make, t, v), args.repeat)
        edge_s, got_edges = best(functools.partial(edge_runs, make, t, v), args.repeat)
        same = got == want == got_edges
        bad += not same
        print(f"{name:<18} {len(want):>6} {ref_s:>13.3f} {run_s:>10.3f} {ref_s / run_s:>7.1f} "
              f"{edge_s:>11.3f} {ref_s / edge_s:>7.1f}{'' if same else '  EDGES DIFFER'}")
    bad += one_at_a_time(args.one, args.repeat)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
