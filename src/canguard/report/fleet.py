"""A fleet summary: one row per replayed log, as JSON lines or Parquet (``canguard replay --fleet-summary``).

Per log: status (ok / failed and why), frames, trips, stops, the first trip's time and the worst margin.
Parquet needs pyarrow (the ``fleet`` extra).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from canguard.report.export import require_pyarrow, schema

COLUMNS = {"log": "string", "status": "string", "reason": "string", "frames": "int64", "trips": "int64",
           "stops": "int64", "first_trip_t": "float64", "stopped_s": "float64", "worst_node": "string",
           "worst_signal": "string", "worst_margin_pct": "float64"}
"""The fleet summary's columns, in order, and their Arrow types."""


def fleet_row(log: str, summary: Mapping[str, Any] | None, error: str = "") -> dict[str, Any]:
    """One log's row: from its replay summary, or (``summary`` None) the reason it failed."""
    row: dict[str, Any] = dict.fromkeys(COLUMNS)
    row["log"] = log
    if summary is None:
        row.update(status="failed", reason=error.strip().splitlines()[0] if error.strip() else "failed")
        return row
    trips = summary.get("trips") or []
    margins = [m for m in summary.get("margins") or [] if m.get("margin_pct") is not None]
    worst: Mapping[str, Any] = min(margins, key=lambda m: m["margin_pct"], default={})
    row.update(
        status="ok", reason="", frames=(summary.get("frames") or {}).get("read"),
        trips=int(summary.get("trip_count", len(trips))), stops=summary.get("stops"),
        first_trip_t=min((t["t"] for t in trips), default=None), stopped_s=summary.get("stopped_s"),
        worst_node=worst.get("node"), worst_signal=worst.get("signal"), worst_margin_pct=worst.get("margin_pct"),
    )
    return row


def write_fleet_summary(path: Path, rows: Iterable[Mapping[str, Any]]) -> None:
    """Write ``rows``: Parquet when ``path`` ends with ``.parquet`` (pyarrow), else JSON lines."""
    rows = list(rows)
    if path.suffix.lower() == ".parquet":
        pa, pq = require_pyarrow(f"--fleet-summary {path}")
        table = pa.Table.from_pylist([{c: r.get(c) for c in COLUMNS} for r in rows], schema=schema(pa, COLUMNS))
        pq.write_table(table, path)
        return
    with open(path, "w", encoding="utf-8") as out:
        for r in rows:
            out.write(json.dumps({c: r.get(c) for c in COLUMNS}, sort_keys=False) + "\n")
