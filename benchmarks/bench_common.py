"""What several benchmarks share: the bundled config rewritten for a benchmark's bus and temp dir."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
BUNDLED = REPO / "config" / "canguard.yaml"
DBC = REPO / "dbc" / "robot.dbc"


def write_config(tmp: Path, bus: dict[str, Any]) -> Path:
    """The bundled config on ``bus``, with absolute paths and events / state in ``tmp``."""
    doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
    doc["dbc"] = [str(DBC)]
    doc["tree"]["file"] = str((BUNDLED.parent / doc["tree"]["file"]).resolve())
    doc["buses"] = {"main": bus}
    doc["events"] = str(tmp / "events.jsonl")
    doc["state"]["file"] = str(tmp / "i2t_state.json")
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path
