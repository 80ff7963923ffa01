"""A fleet summary: one row per replayed log, as JSON lines or Parquet (``canguard replay --fleet-summary``).

Per log: status (ok / failed and why), frames, trips, stops, the first trip's time and the worst margin.
Parquet needs pyarrow (the ``fleet`` extra).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from canguard.errors import ConfigError

COLUMNS = ("log", "status", "reason", "frames", "trips", "stops", "first_trip_t", "stopped_s",
           "worst_node", "worst_signal", "worst_margin_pct")
"""The fleet summary's columns, in order."""


def fleet_row(log: str, summary: Mapping[str, Any] | None, error: str = "") -> dict[str, Any]:
    """One log's row: from its replay summary, or (``summary`` None) the reason it failed."""
    row: dict[str, Any] = dict.fromkeys(COLUMNS)
    row["log"] = log
    if summary is None:
        row.update(status="failed", reason=error.strip().splitlines()[0] if error.strip() else "failed")
        return row
    trips = summary.get("trips") or []
    margins = [m for m in summary.get("margins") or [] if m.get("margin_pct") is not None]
    worst = min(margins, key=lambda m: m["margin_pct"], default=None)
    frames = summary.get("frames") or {}
    row.update(
        status="ok", reason="", frames=frames.get("read"), trips=int(summary.get("trip_count", len(trips))),
        stops=summary.get("stops"), first_trip_t=min((t["t"] for t in trips), default=None),
        stopped_s=summary.get("stopped_s"),
        worst_node=None if worst is None else worst.get("node"),
        worst_signal=None if worst is None else worst.get("signal"),
        worst_margin_pct=None if worst is None else worst.get("margin_pct"),
    )
    return row


def write_fleet_summary(path: Path, rows: Iterable[Mapping[str, Any]]) -> None:
    """Write ``rows``: Parquet when ``path`` ends with ``.parquet`` (pyarrow), else JSON lines."""
    rows = list(rows)
    if path.suffix.lower() == ".parquet":
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError:
            raise ConfigError(f"--fleet-summary {path}: writing Parquet needs pyarrow: "
                              "pip install 'canguard[fleet]'") from None
        table = pa.Table.from_pylist([{c: r.get(c) for c in COLUMNS} for r in rows], schema=_schema(pa))
        pq.write_table(table, path)
        return
    with open(path, "w", encoding="utf-8") as out:
        for r in rows:
            out.write(json.dumps({c: r.get(c) for c in COLUMNS}, sort_keys=False) + "\n")


def _schema(pa: Any) -> Any:
    text, whole, real = pa.string(), pa.int64(), pa.float64()
    types = {"log": text, "status": text, "reason": text, "frames": whole, "trips": whole, "stops": whole,
             "first_trip_t": real, "stopped_s": real, "worst_node": text, "worst_signal": text,
             "worst_margin_pct": real}
    return pa.schema([(c, types[c]) for c in COLUMNS])
