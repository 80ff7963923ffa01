"""``replay --plot``: what an engineer looks at first after a trip.

``.png`` / ``.svg`` by matplotlib (an optional extra); ``.html``: the SVG inline. ``tune --plot``: per guard.
"""

from __future__ import annotations

import io
import math
from array import array
from pathlib import Path
from typing import TYPE_CHECKING, Any

from canguard.errors import ConfigError
from canguard.report.tune import BIN_RATIO, Capture
from canguard.units import I2T_LIMIT_PCT, quantity

if TYPE_CHECKING:
    from canguard.engine.core import Engine

FORMATS = (".png", ".svg", ".html")


def require_matplotlib() -> Any:
    """Import matplotlib with the Agg backend, or raise a clear error saying how to get it."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise ConfigError("--plot needs matplotlib, an optional extra: pip install 'canguard[plot]' "
                          "(or pip install matplotlib)") from exc
    return plt


class Recorder:
    """Collects the valid samples of every value, I²t levels (:meth:`publish`: a tick) and stop intervals."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self.series = {(name, role): Capture() for name, src in engine.cfg.sources.items() for role in src.value_roles}
        for (name, role), capture in self.series.items():
            engine.ctx.subscribe(name, role, capture)  # fed as the models are
        self.levels: dict[str, tuple[array, array]] = {}
        self.trips: list[tuple[float, str, str]] = []
        self.stops: list[list[float]] = []
        engine.listen(self._event)

    def publish(self, engine: Any, now: float) -> None:
        """After a tick: each I²t level."""
        for node, model in self.engine.ctx.heat_models.items():
            ts, vs = self.levels.setdefault(node, (array("d"), array("d")))
            ts.append(now)
            vs.append(model.snapshot().level_pct)

    def _event(self, ev: dict[str, Any]) -> None:
        kind = ev.get("event")
        t = float(ev.get("t", math.nan))
        if kind == "trip":
            self.trips.append((t, str(ev.get("node", "")), str(ev.get("source", ""))))
        elif kind == "stop":
            self.stops.append([t, math.nan])
        elif kind == "resume" and self.stops and math.isnan(self.stops[-1][1]):
            self.stops[-1][1] = t

    def save(self, path: Path, summary: dict[str, Any]) -> None:
        """Draw and write the figure; the format follows the extension."""
        suffix = path.suffix.lower()
        if suffix not in FORMATS:
            raise ConfigError(f"--plot {path}: unknown extension {suffix!r}, expected one of {', '.join(FORMATS)}")
        plt = require_matplotlib()
        guards = self.engine.guards()
        series = {key: cols for key, cols in ((k, c.columns()) for k, c in self.series.items()) if cols[0].size}
        sources = sorted({(g.source, g.role) for g in guards} & set(series)) or sorted(series)
        level_nodes = sorted(self.levels)
        rows = max(1, len(sources)) + (1 if level_nodes else 0)
        fig, axes = plt.subplots(rows, 1, figsize=(11, 2.6 * rows), sharex=True, squeeze=False)
        t0 = summary.get("first_t") or 0.0
        end = summary.get("last_t") or t0
        for ax, (source, role) in zip(axes[:, 0], sources, strict=False):
            ts, vs = series[(source, role)]
            ax.plot(ts - t0, vs, lw=0.8, label=f"{source} {role}")
            for g in guards:
                if (g.source, g.role) == (source, role) and g.kind == "threshold":
                    thr = g.threshold()
                    ax.axhline(thr, ls="--", lw=0.8, color="tab:red", label=f"{g.node} {quantity(thr, g.unit)}")
                    ax.axhline(-thr, ls="--", lw=0.8, color="tab:red")
            unit = next((g.unit for g in guards if (g.source, g.role) == (source, role) and g.unit), "")
            ax.set_ylabel(f"{role} ({unit})" if unit else role)
            ax.legend(loc="upper right", fontsize=7)
        if level_nodes:
            ax = axes[-1, 0]
            for node in level_nodes:
                times, levels = self.levels[node]
                ax.plot([t - t0 for t in times], list(levels), lw=0.8, label=node)
            ax.axhline(100.0, ls="--", lw=0.8, color="tab:red")
            ax.set_ylabel(f"I²t level ({I2T_LIMIT_PCT})")
            ax.legend(loc="upper right", fontsize=7)
        for ax in axes[:, 0]:
            for start, stop in self.stops:
                ax.axvspan(start - t0, (end if math.isnan(stop) else stop) - t0, color="tab:red", alpha=0.12)
            for t, _, _ in self.trips:
                ax.axvline(t - t0, color="tab:red", lw=0.6)
        axes[-1, 0].set_xlabel(f"time since first frame (s; t0 = {t0:.6f})")
        fig.suptitle(f"{summary.get('log')}: {len(summary.get('trips', []))} trips, "
                     f"stopped {summary.get('stopped_s')} s")
        fig.tight_layout()
        if suffix == ".html":
            buf = io.StringIO()
            fig.savefig(buf, format="svg")
            path.write_text("<!doctype html><html><head><meta charset='utf-8'><title>canguard replay</title></head>"
                            f"<body>{buf.getvalue()}</body></html>", encoding="utf-8")
        else:
            fig.savefig(path)
        plt.close(fig)


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
