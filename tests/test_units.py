"""Values with their units: the replay summary, the margin report, the baseline diff and the demo's view.

Currents in A, efforts in the DBC's unit (Nm), a leaky I²t's heat and trip level in A²s,
an I²t guard's level in % of the I²t limit; one formatter (:func:`canguard.units.quantity`).
"""

from __future__ import annotations

import io
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from canguard.cli.demo import DEMO_CONFIG, LiveView, demo_config
from canguard.cli.main import main
from canguard.config.loader import load_config
from canguard.service.daemon import Daemon
from canguard.service.systemd import Notifier
from canguard.units import I2T_LIMIT_PCT, quantity


def replay(cwd: Path, repo: Path, *more: object) -> subprocess.CompletedProcess[str]:
    """``canguard replay examples/overload.log.gz -c robot_guard.yaml *more`` as a process started in ``cwd``."""
    return subprocess.run(
        [sys.executable, "-m", "canguard", "replay", str(repo / "examples" / "overload.log.gz"),
         "-c", str(repo / "config" / "examples" / "robot_guard.yaml"), *map(str, more)],
        cwd=cwd, capture_output=True, text=True, timeout=120, check=False,
    )


def replay_here(capsys: pytest.CaptureFixture[str], repo: Path, *more: object) -> tuple[int, str, str]:
    """The same replay through ``canguard.cli.main.main`` in this process: (exit code, stdout, stderr)."""
    argv = ["replay", str(repo / "examples" / "overload.log.gz"),
            "-c", str(repo / "config" / "examples" / "robot_guard.yaml"), *map(str, more)]
    capsys.readouterr()
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


class TestQuantity:
    """The one formatter."""

    def test_value_and_unit(self) -> None:
        """A number to 6 significant digits, a space, its unit; none for NaN; the number alone without a unit."""
        assert quantity(299.799009, I2T_LIMIT_PCT) == "299.799 % of the I²t limit"
        assert quantity(300.0, "A²s") == "300 A²s"
        assert quantity(20.09444, "A", 4) == "20.09 A"
        assert quantity(math.nan, "A") == quantity(None, "A") == "no data"
        assert quantity(1.5, "") == "1.5"


@pytest.mark.slow
class TestReplayReport:
    """What ``canguard replay`` prints, run from another directory."""

    def test_margins_and_trips_carry_units(self, tmp_path: Path, repo: Path) -> None:
        """Current margins in A, efforts in Nm, I²t margins in % of the limit, the I²t trip in A²s."""
        proc = replay(tmp_path, repo)
        out = proc.stdout
        assert proc.returncode == 0, proc.stderr
        assert "PackCurrent (/battery_state current): peak 31.6 A vs threshold 35 A: margin 3.4 A" in out
        assert "JointEfforts (/joint_states axis0): peak 1.66142 Nm vs threshold 150 Nm" in out
        # The I²t peak is the heat's highest at any sample (between ticks too), not the level seen at a tick.
        assert ("Axis0I2t (axis0 current): peak 300.034 % of the I²t limit vs threshold 100 % of the I²t limit: "
                "margin -200.034 % of the I²t limit") in out
        assert "Axis0I2t source=axis0 value=300.002 A²s threshold=300 A²s reason=i2t" in out



class TestReplayJson:
    """The same replay's --json and baseline diff, through the command's entry point in this process."""

    def test_json_and_baseline_diff(self, tmp_path: Path, repo: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """--json gives each margin and trip its unit; the baseline diff prints shrunk margins with theirs."""
        code, out, _err = replay_here(capsys, repo, "--json")
        assert code == 0
        summary = json.loads(out)
        units = {m["node"]: m["unit"] for m in summary["margins"]}
        assert units["PackCurrent"] == "A" and units["JointEfforts"] == "Nm" and units["Axis0I2t"] == I2T_LIMIT_PCT
        assert [t["unit"] for t in summary["trips"]] == ["A²s"]
        pack = next(m for m in summary["margins"] if m["node"] == "PackCurrent")
        pack["margin"] += 1.0
        base = tmp_path / "base.json"
        base.write_text(json.dumps(summary), encoding="utf-8")
        _code, _out, err = replay_here(capsys, repo, "--baseline", base)
        assert "margin shrank: PackCurrent (/battery_state current): 4.4 A -> 3.4 A" in err


class TestLiveView:
    """The demo's terminal view: the value in the signal's unit, the threshold in the model's, the level in %."""

    def test_table_units(self, tmp_path: Path) -> None:
        """An I²t row's threshold reads in A²s, a current guard's in A, levels in %; no sample yet: 'no data'."""
        cfg = demo_config(load_config(DEMO_CONFIG), tmp_path / "events.jsonl")
        daemon = Daemon(DEMO_CONFIG, cfg=cfg, notifier=Notifier(env={}))
        out = io.StringIO()
        try:
            LiveView(daemon, out, tty=True).draw()  # the daemon built, not run: no bus opened
        finally:
            daemon.journal.close()
        rows = {line.split()[0]: line for line in out.getvalue().splitlines() if line[:4] in ("Pack", "Axis")}
        assert "no data" in rows["PackCurrent"] and "35 A" in rows["PackCurrent"]
        assert "300 A²s" in rows["Axis0I2t"] and " 0 %" in rows["Axis0I2t"]
