"""The example logs: each simulator scenario gives the replay summary it promises.

``examples/regenerate.sh`` wrote one candump log per scenario and the summary
``canguard replay --json`` gave for it with ``config/examples/robot_guard.yaml``.
These tests replay the committed logs again, check the summaries still match,
check what each scenario promises (what trips, when, why), and check that the
simulator still writes the very same bytes.
"""

from __future__ import annotations

import gzip
import json
from pathlib import Path
from typing import Any

import pytest

from canguard.cli.replay import ReplayOptions, replay_one
from canguard.config.loader import load_config
from canguard.sim import write_log
from checkout import REPO

EXAMPLES = REPO / "examples"
CONFIG = REPO / "config" / "examples" / "robot_guard.yaml"
SCENARIOS = ("normal", "inrush", "spike", "overload", "dropout", "garbage", "errorburst", "load")
SAMPLE_PERIOD_S = 0.004  # Get_Iq at 250 Hz: trip times are checked within one sample period


def summary(name: str) -> dict[str, Any]:
    """A fresh replay of the committed example log (paths left out)."""
    s = replay_one(load_config(CONFIG), EXAMPLES / f"{name}.log.gz", ReplayOptions())
    return {k: v for k, v in s.items() if k not in ("log", "config")}


def stored(name: str) -> dict[str, Any]:
    """The committed summary (paths left out)."""
    s = json.loads((EXAMPLES / f"{name}.summary.json").read_text(encoding="utf-8"))
    return {k: v for k, v in s.items() if k not in ("log", "config")}


def trips(s: dict[str, Any]) -> list[tuple[str, str, float]]:
    """(node, reason, seconds after the first frame) of every trip."""
    return [(t["node"], t["reason"], t["t"] - s["first_t"]) for t in s["trips"]]


class TestExampleSummaries:
    """Replaying every example log gives exactly its committed summary."""

    @pytest.mark.parametrize("name", SCENARIOS)
    def test_summary_matches(self, name: str) -> None:
        """The replay summary of examples/NAME.log.gz equals examples/NAME.summary.json."""
        assert summary(name) == stored(name)


class TestScenarioPromises:
    """What each scenario promises, read off its summary."""

    @pytest.mark.parametrize("name", ["normal", "inrush", "errorburst", "load"])
    def test_no_trip(self, name: str) -> None:
        """Normal duty, a blanked motor start, an error-frame burst and background load never trip."""
        s = stored(name)
        assert s["trips"] == [] and s["stops"] == 0

    @pytest.mark.parametrize("name", ["normal", "errorburst", "load"])
    def test_margin_left_everywhere(self, name: str) -> None:
        """Without a motor start or a fault, every guard keeps a positive margin to its threshold."""
        assert all(m["margin"] is not None and m["margin"] > 0 for m in stored(name)["margins"])

    def test_inrush_is_blanked_not_ignored(self) -> None:
        """The motor start drives axis1 to 25 A, at the 25 A threshold: only the 40 A inrush window keeps it."""
        s = stored("inrush")
        peak = {(m["node"]): m["peak"] for m in s["margins"]}
        assert peak["Axis1Current"] >= 25.0

    def test_spike_trips_the_pack_guard_once(self) -> None:
        """The single 60 A BMS frame at 1.51 s trips PackCurrent (35 A) at that frame, and the task resumes."""
        s = stored("spike")
        [(node, reason, t)] = trips(s)
        assert (node, reason) == ("PackCurrent", "overcurrent")
        assert t == pytest.approx(1.51, abs=1e-3)
        assert s["trips"][0]["value"] == 60.0 and s["trips"][0]["threshold"] == 35.0
        # The task resumes at the recovering BMS frame (1.52 s), before any axis0 sample confirmed the stop.
        assert s["stops"] == 1 and s["stopped_s"] < 0.05 and s["confirmations"] == 0

    def test_overload_trips_i2t_at_the_closed_form_time(self) -> None:
        """20 A on a 10 A / 20 A-for-1 s motor from 2.0 s trips the leaky I²t S/(I²-Ic²) = 1.0 s later."""
        s = stored("overload")
        [(node, reason, t)] = trips(s)
        assert (node, reason) == ("Axis0I2t", "i2t")
        assert t == pytest.approx(2.0 + 300.0 / (20.0**2 - 10.0**2), abs=SAMPLE_PERIOD_S)

    def test_overload_stop_is_escalated_when_the_log_does_not_obey(self) -> None:
        """The recorded drive keeps drawing 20 A after the Estop, so the stop is not confirmed and escalates."""
        s = stored("overload")
        assert s["escalations"] == 1 and s["confirmations"] == 0

    def test_dropout_stops_on_stale_bms(self) -> None:
        """BMS frames stop at 1.98 s; with max_age 0.5 s the pack guard fails as stale about 2.48 s."""
        s = stored("dropout")
        [(node, reason, t)] = trips(s)
        assert (node, reason) == ("PackCurrent", "stale")
        assert 2.48 <= t <= 2.48 + 0.011  # within one 100 Hz tick of the staleness deadline
        assert s["stops"] == 1

    def test_garbage_payloads_fail_the_guards(self) -> None:
        """NaN, inf and short frames are invalid samples that fail their guards; unknown ids are skipped."""
        s = stored("garbage")
        assert [(n, r) for n, r, _ in trips(s)] == [
            ("Axis2Current", "nan"), ("Axis2Current", "inf"), ("Axis2Current", "bad_length"),
            ("PackCurrent", "bad_length"), ("JointEfforts", "nan"),
        ]
        assert s["frames"]["invalid"] == 5

    def test_error_frames_are_counted(self) -> None:
        """The burst's 32 error frames are counted, never decoded."""
        assert stored("errorburst")["frames"]["error_frames"] == 32


class TestExampleLogsRegenerate:
    """The simulator still writes the committed logs byte for byte (seed 0)."""

    @pytest.mark.parametrize("name", ["spike", "overload"])
    def test_same_bytes(self, name: str, tmp_path: Path) -> None:
        """write_log with the regenerate.sh arguments gives the committed file's content."""
        out = tmp_path / f"{name}.log"
        cfg = load_config(CONFIG)
        write_log(out, 6.0, db=cfg.database, scenarios=(name,), seed=0)
        with gzip.open(EXAMPLES / f"{name}.log.gz", "rb") as f:
            assert out.read_bytes() == f.read()


class TestReadmeCommands:
    """The README's two set-up commands are the ones CI runs (that `canguard demo` runs headless to its summary,
    its spike tripping PackCurrent, is shown where a user runs it: the installed wheel's smoke,
    tests/test_installed_wheel.py)."""

    def test_ci_runs_the_readme_test_command(self) -> None:
        """.ci/run calls scripts/test.sh, and the README gives that same command."""
        readme = (REPO / "README.md").read_text(encoding="utf-8")
        assert "bash scripts/test.sh" in readme
        assert "scripts/test.sh" in (REPO / ".ci" / "run").read_text(encoding="utf-8")
        assert "canguard demo" in readme
