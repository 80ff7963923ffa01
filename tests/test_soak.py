"""The short soak (benchmarks/soak.py): daemon subprocess, simulated robot at ~8,000 frames/s, faults injected.

Checks what the 30-minute run checks: every injected fault got its reaction within the
bound, no journal line torn or lost, every trip followed by a stop, exit 0 on SIGTERM.
42 s, seed 44: a dropout (stale battery), an overload (I²t trip of axis0: the daemon integrates the
live frames for seconds), a rejected and a good reload: the schedule's kinds of reaction (a trip, a
stale source, a rejected reload) and its reload pair, each judged. The single-frame current spike,
the one other kind of fault that gives a trip, needs 50 s with all of these (seed 7561; no seed of the
first 20,000 gives all in 48 s): its trip and stop are proved live by the monitor and daemon tests.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from checkout import REPO


@pytest.mark.slow
def test_short_soak(tmp_path: Path) -> None:
    """`python benchmarks/soak.py --minutes 0.7 --seed 44` (42 s) passes its own checks."""
    report = tmp_path / "soak.json"
    # Without the background load: on a busy CI machine the simulator must keep real time, or its
    # own lag would count as canguard's reaction time (the 30-minute run keeps the full load).
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "soak.py"), "--minutes", "0.7", "--seed", "44",
                           "--sample", "5", "--no-load", "--bound", "3", "--json", str(report)],
                          capture_output=True, text=True, timeout=150)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = json.loads(report.read_text())
    judged, total = out["reactions_within_bound"].split()[0].split("/")
    assert judged == total and int(total) >= 4
    assert out["torn_or_lost_lines"] == 0 and out["trips_without_stop"] == 0 and out["daemon_exit"] == 0
