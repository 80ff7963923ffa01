"""``canguard tune --plot FILE``: per guard, the healthy |values| with the old and new figures and the faults."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from canguard.report.plot import require_matplotlib
from canguard.report.tune import BIN_RATIO


def plot_tune(path: Path, guards: list[Any]) -> None:
    """One panel per threshold guard the healthy logs exercised (I²t ratings are factors: not drawn)."""
    plt = require_matplotlib()
    shown = [g for g in guards if g.hist and not g.scale]
    fig, axes = plt.subplots(max(len(shown), 1), 1, figsize=(8, 2.2 * max(len(shown), 1)), squeeze=False)
    for ax, g in zip(axes[:, 0], shown, strict=False):
        bins = sorted((int(k), c) for k, c in g.hist.items() if k != "z")
        if bins:
            left = [BIN_RATIO ** k for k, _c in bins]
            width = [x * (BIN_RATIO - 1.0) for x in left]
            ax.bar(left, [c for _k, c in bins], width=width, align="edge", color="tab:blue", label="healthy |value|")
            ax.set_xscale("log")
            ax.set_yscale("log")
        if g.old is not None and math.isfinite(g.old):
            ax.axvline(g.old, color="grey", linestyle="--", label=f"old {g.port} {g.old:.4g}")
        if g.new is not None:
            ax.axvline(g.new, color="tab:green", label=f"new {g.new:.4g}")
        for f in g.faults:
            ax.axvline(f.value, color="tab:red", linestyle=":", label=f"fault {Path(f.log).name} {f.value:.4g}")
        ax.set_title(f"{g.node} ({g.type} on {g.source}): {g.status}", fontsize=9)
        ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
