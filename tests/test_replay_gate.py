"""``replay --baseline B --fail-on-regression``: a CI gate on what changed, run as a user runs it.

Exit 1 when a log gains or loses a trip, or a margin shrinks by more than
``--margin-tolerance`` (% of the guard's threshold); 0 otherwise; without the flag
the comparison is only reported.

The exit codes 1 (a regression) and 2 (no baseline) come from a real process started
in another directory; the other cases call the same entry point in-process
(``canguard.cli.main.main``), which returns the code the process exits with.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from canguard.cli.main import main

pytestmark = pytest.mark.slow


def canguard(cwd: Path, *argv: object) -> subprocess.CompletedProcess[str]:
    """``canguard *argv`` as a separate process started in ``cwd``."""
    return subprocess.run([sys.executable, "-m", "canguard", *map(str, argv)], cwd=cwd, capture_output=True,
                          text=True, timeout=120, check=False)


@pytest.fixture
def replay(tmp_path: Path, repo: Path) -> Any:
    """``canguard replay examples/NAME.log.gz -c robot_guard.yaml *more`` from ``tmp_path``."""
    config = repo / "config" / "examples" / "robot_guard.yaml"

    def run(name: str, *more: object) -> subprocess.CompletedProcess[str]:
        return canguard(tmp_path, "replay", repo / "examples" / f"{name}.log.gz", "-c", config, *more)

    return run


@pytest.fixture
def replay_here(repo: Path, capsys: pytest.CaptureFixture[str]) -> Any:
    """The same replay through ``canguard.cli.main.main`` in this process: its exit code, stdout and stderr."""
    config = repo / "config" / "examples" / "robot_guard.yaml"

    def run(name: str, *more: object) -> subprocess.CompletedProcess[str]:
        argv = ["replay", str(repo / "examples" / f"{name}.log.gz"), "-c", str(config), *map(str, more)]
        capsys.readouterr()
        code = main(argv)
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(argv, code, out, err)

    return run


def saved(tmp_path: Path, repo: Path, name: str) -> Any:
    """The committed --json summary of an example log (what `--json > FILE` saved)."""
    return json.loads((repo / "examples" / f"{name}.summary.json").read_text(encoding="utf-8"))


def write(tmp_path: Path, summary: Any) -> Path:
    """``summary`` saved as a baseline file."""
    path = tmp_path / "base.json"
    path.write_text(json.dumps(summary), encoding="utf-8")
    return path


class TestFailOnRegression:
    """The gate's exit code follows trips gained or lost and margins lost."""

    def test_gained_trip_fails(self, tmp_path: Path, repo: Path, replay: Any) -> None:
        """The spike log against the clean log's baseline exits 1 and marks the new trip as the regression."""
        base = write(tmp_path, saved(tmp_path, repo, "normal"))
        proc = replay("spike", "--baseline", base, "--fail-on-regression")
        assert proc.returncode == 1, proc.stderr
        assert "new trip: PackCurrent on /battery_state (overcurrent): 0 -> 1 (regression)" in proc.stderr

    def test_report_only_without_the_flag(self, tmp_path: Path, repo: Path, replay_here: Any) -> None:
        """Without --fail-on-regression the same comparison is reported and the exit stays 0."""
        base = write(tmp_path, saved(tmp_path, repo, "normal"))
        proc = replay_here("spike", "--baseline", base)
        assert proc.returncode == 0 and "new trip: PackCurrent" in proc.stderr

    def test_lost_trip_fails(self, tmp_path: Path, repo: Path, replay_here: Any) -> None:
        """The clean log against the spike log's baseline exits 1: a trip that no longer happens counts."""
        base = write(tmp_path, saved(tmp_path, repo, "spike"))
        proc = replay_here("normal", "--baseline", base, "--fail-on-regression")
        assert proc.returncode == 1 and "lost trip: PackCurrent" in proc.stderr

    def test_unchanged_passes(self, tmp_path: Path, repo: Path, replay_here: Any) -> None:
        """A log against its own saved summary exits 0 with --fail-on-regression."""
        base = write(tmp_path, saved(tmp_path, repo, "spike"))
        proc = replay_here("spike", "--baseline", base, "--fail-on-regression")
        assert proc.returncode == 0, proc.stderr
        assert "no change" in proc.stderr

    @pytest.mark.parametrize(("tolerance", "code"), [(None, 1), ("0.5", 1), ("2", 0)])
    def test_margin_tolerance(self, tmp_path: Path, repo: Path, replay_here: Any, tolerance: str | None,
                              code: int) -> None:
        """A margin 1 % of its threshold below the baseline's fails at tolerance 0 and 0.5 %, passes at 2 %."""
        base = saved(tmp_path, repo, "normal")
        pack = next(m for m in base["margins"] if m["node"] == "PackCurrent")
        pack["margin"] += 0.01 * pack["threshold"]
        more = () if tolerance is None else ("--margin-tolerance", tolerance)
        proc = replay_here("normal", "--baseline", write(tmp_path, base), "--fail-on-regression", *more)
        assert proc.returncode == code, proc.stderr
        assert "margin shrank: PackCurrent (/battery_state current)" in proc.stderr
        assert "(1 % of the threshold)" in proc.stderr

    def test_baseline_of_other_length_fails(self, tmp_path: Path, repo: Path, replay_here: Any) -> None:
        """A baseline of two summaries for one log cannot vouch for it: exit 1, saying so."""
        one = saved(tmp_path, repo, "normal")
        proc = replay_here("normal", "--baseline", write(tmp_path, [one, one]), "--fail-on-regression")
        assert proc.returncode == 1 and "2 summaries, this run 1" in proc.stderr

    def test_needs_a_baseline(self, tmp_path: Path, replay: Any) -> None:
        """--fail-on-regression without --baseline is exit 2 saying what is missing."""
        proc = replay("normal", "--fail-on-regression")
        assert proc.returncode == 2 and "--fail-on-regression needs --baseline FILE" in proc.stderr
