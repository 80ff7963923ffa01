"""What several benchmarks share: the bundled config rewritten for a benchmark's bus and temp dir."""

from __future__ import annotations

import compileall
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
BUNDLED = REPO / "config" / "canguard.yaml"
DBC = REPO / "dbc" / "robot.dbc"


def clean_up_on_sigterm() -> None:
    """A SIGTERM (``kill``, ``pkill``, a CI timeout) ends this benchmark as an exception would: its ``finally``
    blocks run and stop the daemons and load generators it started. By default Python dies at once and
    leaves them running, loading the machine for every later measurement (it happened: session 9)."""
    signal.signal(signal.SIGTERM, lambda signum, _frame: sys.exit(128 + signum))


def compiled(src: Path) -> Path:
    """``src`` with its bytecode written, as ``pip install`` writes it for an installed wheel; returns ``src``.

    Without it a benchmark would time compiling canguard from source in every process wherever the
    bytecode is not written on import (``PYTHONDONTWRITEBYTECODE=1``, set on the project's machines):
    90 ms a process with no ``.pyc`` at all, 35 ms with some stale, measured on a 3-frame replay.
    """
    if not compileall.compile_dir(str(src), quiet=1, workers=1):
        raise SystemExit(f"{src}: compileall failed")
    return src


def write_config(tmp: Path, bus: dict[str, Any], monitor: dict[str, Any] | None = None) -> Path:
    """The bundled config on ``bus``, with absolute paths and events / state in ``tmp`` (and ``monitor:``)."""
    doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
    doc["dbc"] = [str(DBC)]
    doc["tree"]["file"] = str((BUNDLED.parent / doc["tree"]["file"]).resolve())
    doc["buses"] = {"main": bus}
    doc["events"] = str(tmp / "events.jsonl")
    doc["state"]["file"] = str(tmp / "i2t_state.json")
    if monitor:
        doc["monitor"] = monitor
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def wait_for_start(daemon: subprocess.Popen[Any], events: Path, timeout_s: float = 30.0) -> None:
    """Wait until a `canguard run` subprocess has journalled its start event; RuntimeError if it never does."""
    deadline = time.monotonic() + timeout_s
    while not (events.exists() and b'"start"' in events.read_bytes()):
        if time.monotonic() > deadline or daemon.poll() is not None:
            raise RuntimeError("canguard run did not start")
        time.sleep(0.05)
