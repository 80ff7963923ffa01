"""The short soak (benchmarks/soak.py): daemon subprocess, simulated robot at ~650 frames/s, faults injected.

Checks what the 30-minute run checks: every injected fault got its reaction within the
bound, no journal line torn or lost, every trip followed by a stop, exit 0 on SIGTERM.
50 s, seed 7561: a current spike (battery trip), a dropout (stale battery), an overload (I²t trip
of axis0), a rejected and a good reload: the schedule's three kinds of reaction and its reload
pair (no seed of the first 20,000 gives them in 48 s; seed 3's 60 s held a spike, a dropout and
garbage frames: the same kinds of reaction).
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
    """`python benchmarks/soak.py --minutes 0.834 --seed 7561 --no-load --light` (50 s) passes its own checks."""
    report = tmp_path / "soak.json"
    # Without the background load and with the axes' streams at a fifth of their rates (--light, ~650
    # frames/s): the same faults, reactions, reloads and journal at a quarter of the frames, on a CI
    # machine busy with the rest of the suite (the 30-minute run keeps the full rates and load).
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks" / "soak.py"), "--minutes", "0.834", "--seed", "7561",
                           "--sample", "5", "--no-load", "--light", "--bound", "3", "--json", str(report)],
                          capture_output=True, text=True, timeout=150)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = json.loads(report.read_text())
    judged, total = out["reactions_within_bound"].split()[0].split("/")
    assert judged == total and int(total) >= 5
    assert out["torn_or_lost_lines"] == 0 and out["trips_without_stop"] == 0 and out["daemon_exit"] == 0


def test_reactions_are_timed_from_when_the_simulator_sent_the_fault() -> None:
    """A simulator running late does not make the daemon look late, and a late daemon is still late."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        import soak
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    onset = soak.SIM_FAULTS["spike"][0]
    start = 1_700_000_000.0

    def judged(lag_s: float, reaction_after_send_s: float) -> float | None:
        report = soak.Report(1.0, [soak.Fault("spike", 10.0, "trip:/battery_state")])
        report.faults[0].wall = start + 10.0
        # the simulator's clock read at 5 Hz, lag_s behind the wall clock
        report.sim_clock = [(start + k / 5, max(0.0, k / 5 - lag_s)) for k in range(200)]
        sent = start + 10.0 + onset + lag_s
        soak.check(report, [{"t": sent + reaction_after_send_s, "event": "trip", "source": "/battery_state"}], 3.0)
        return report.faults[0].seen

    on_time, lagging, late = judged(0.0, 0.05), judged(20.0, 0.05), judged(20.0, 3.5)
    assert on_time is not None and abs(on_time - 0.05) < 1e-6
    assert lagging is not None and 0.05 <= lagging <= 0.25  # read from the clock's last reading before the send
    assert late is not None and late > 3.0
