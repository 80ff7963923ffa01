"""The I²t accumulators over a run of steps: the leaky bucket's bounded running sum, the thermal image's steps.

Both give the value after each step exactly as adding / stepping one after the other
would (the per-sample maths the tests keep as the reference), so a run gives the same
trips at the same samples as its samples fed one by one.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

    from canguard.protect.columns import FloatArray


def next_where(mask: np.ndarray) -> np.ndarray:
    """For each position, the first position at or after it where ``mask`` is set (``len``: none)."""
    import numpy as np

    n = mask.size
    pos = np.where(mask, np.arange(n), n)
    return np.minimum.accumulate(pos[::-1])[::-1]


def clamped_sum(start: float, steps: FloatArray, cap: float, add: Callable[[float, float], float]) -> FloatArray:
    """The running sum ``acc ← add(acc, step)`` from ``start``, after each step; ``add`` bounds it to [0, ``cap``].

    Exactly the float results of ``add`` one step after the other (the kernel): between the
    samples where a bound is hit, a sequential ``numpy.add.accumulate`` from the last value adds
    in the same order; at a bound ``add`` itself takes the step, and the steps that keep it
    there (<= 0 at the floor, >= 0 at the cap) are skipped as a block. The scan runs in
    windows that double while no bound is hit, so a run costs a few passes.
    """
    import numpy as np

    n = steps.size
    out = np.empty(n)
    stays: tuple[np.ndarray, np.ndarray] | None = None  # where each bound is left, found at the first hit
    acc, pos, size = float(start), 0, 64
    while pos < n:
        end = min(n, pos + size)
        run = np.add.accumulate(np.concatenate(((acc,), steps[pos:end])))[1:]
        hit = (~((run >= 0.0) & (run <= cap))).nonzero()[0]
        if not hit.size:
            out[pos:end] = run
            acc, pos, size = float(run[-1]), end, 2 * size
            continue
        p = pos + int(hit[0])
        out[pos:p] = run[: p - pos]
        acc = add(float(out[p - 1]) if p > pos else acc, float(steps[p]))
        if p + 1 == n:
            out[p] = acc
            break
        if stays is None:
            stays = next_where(steps > 0), next_where(steps < 0)
        stay = int(stays[acc != 0.0][p + 1])
        out[p:stay] = acc
        pos, size = stay, 64
    return out


def thermal_steps(theta: float, q: Sequence[float], dt: Sequence[float], tau_heat: float, tau_cool: float,
                  cap: float) -> list[float]:
    """θ after each step ``θ ← q + (θ − q)·exp(−dt/τ)`` (no step where dt is 0), clamped to [0, ``cap``].

    τ is ``tau_cool`` while ``q < θ`` (cooling), else ``tau_heat``. Plain floats: the state
    picks the time constant, so the steps run one after the other.
    """
    exp = math.exp
    out: list[float] = []
    append = out.append
    for qi, d in zip(q, dt, strict=True):
        if d > 0.0:
            theta = qi + (theta - qi) * exp(-d / (tau_cool if qi < theta else tau_heat))
            if theta < 0.0:
                theta = 0.0
            elif theta > cap:
                theta = cap
        append(theta)
    return out
