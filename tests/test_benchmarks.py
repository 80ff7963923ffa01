"""Every benchmark suite still runs: ``python -m benchmarks SUITE --quick`` (tiny sizes, no figure asserted)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from checkout import REPO

SUITES = ("replay", "live", "monitor", "fleet", "models", "startup", "soak")


@pytest.mark.slow
@pytest.mark.parametrize("suite", SUITES)
def test_suite_runs_quick(suite: str, tmp_path: Path) -> None:
    """The suite prints its table and writes the same as JSON: the header, and a figure in every cost column."""
    out = tmp_path / f"{suite}.json"
    proc = subprocess.run([sys.executable, "-m", "benchmarks", suite, "--quick", "--json", str(out)], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    doc = json.loads(out.read_text(encoding="utf-8"))
    assert doc["suite"] == suite and f"**{suite}**" in proc.stdout
    assert doc["commit"] and doc["machine"]["cores"] >= 1 and doc["command"].endswith(f"{suite} --quick --json {out}")
    assert doc["rows"], "no rows"
    for column in doc["costs"]:
        assert any(isinstance(row[column], (int, float)) for row in doc["rows"]), f"no figure in {column!r}"
