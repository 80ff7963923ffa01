"""``canguard tune``: thresholds proposed from the simulator's healthy logs and faults, proven by replay."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest

from canguard.cli.tune import load_expect
from canguard.config.loader import load_config
from canguard.errors import ConfigError
from canguard.report.tune import histogram, nice_up, percentile, separate
from canguard.report.tunefiles import port_text, set_attributes, tuned_config
from clikit import cli

HEALTHY = ("normal", "load", "inrush")
FAULTS = ("overload", "spike", "dropout")


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def robot(repo: Path, tmp_path: Path) -> Path:
    """A copy of the example robot's config, tree and DBC (the originals' hashes are checked by the tests)."""
    for sub in ("config/examples", "config/trees", "dbc"):
        shutil.copytree(repo / sub, tmp_path / sub)
    return tmp_path / "config/examples/robot_guard.yaml"


def _logs(repo: Path, names: tuple[str, ...]) -> list[Path]:
    return [repo / "examples" / f"{n}.log.gz" for n in names]


class TestTune:
    """The whole command on the simulator's example logs."""

    def test_tuned_config_trips_every_fault_and_no_healthy_log(self, capsys: pytest.CaptureFixture[str], repo: Path,
                                                                robot: Path, tmp_path: Path) -> None:
        """The proposal separates the faults from the healthy logs; replaying the written config shows it."""
        tree = robot.parent.parent / "trees/robot_guard.xml"
        before = {p: _digest(p) for p in (robot, tree)}
        out = tmp_path / "tuned"
        args = ["tune", "-c", robot, *_logs(repo, HEALTHY), "--out", out, "--json"]
        for f in _logs(repo, FAULTS):
            args += ["--fault", f]
        code, stdout, _err = cli(capsys, *args)
        assert code == 0
        report = json.loads(stdout)
        assert report["result"] == "proven"
        assert {p.name for p in out.iterdir()} == {"robot_guard.yaml", "robot_guard.xml"}
        assert {p: _digest(p) for p in (robot, tree)} == before
        axis0 = next(g for g in report["guards"] if g["node"] == "Axis0Current")
        # guessed 25 A against a healthy day below 7 A: tuned down, and the overload fault now trips it
        assert axis0["status"] == "tuned" and axis0["new"] < 25.0
        assert axis0["healthy_ceiling"]["value"] * 1.1 <= axis0["new"] < axis0["faults"][0]["value"]
        axis1 = next(g for g in report["guards"] if g["node"] == "Axis1Current")
        # the inrush log's starts on axis1 last less than the 0.15 s window above the new threshold
        assert 0.0 < axis1["inrush"]["new"] < 0.15 and axis1["inrush"]["starts"] > 0
        text = (out / "robot_guard.xml").read_text(encoding="utf-8")
        assert f'inrush_time="{axis1["inrush"]["new"]:g}"' in text
        assert "<!-- The whole robot" in text  # comments and layout kept
        assert f'name="Axis0Current" topic_name="axis0" overcurrent_threshold="{axis0["new"]:g}"' in text
        for log in _logs(repo, HEALTHY):
            assert cli(capsys, "replay", log, "-c", out / "robot_guard.yaml", "--fail-on-trip")[0] == 0
        for log in _logs(repo, FAULTS):
            assert cli(capsys, "replay", log, "-c", out / "robot_guard.yaml", "--fail-on-trip")[0] == 1

    def test_a_healthy_log_as_bad_as_a_fault_is_named_and_nothing_written(
            self, capsys: pytest.CaptureFixture[str], repo: Path, robot: Path, tmp_path: Path) -> None:
        """The overload recorded again as a 'healthy' day: exit 1 naming both logs, no file written."""
        busy = tmp_path / "busy_day.log.gz"
        shutil.copy(repo / "examples/overload.log.gz", busy)
        expect = tmp_path / "expect.yaml"
        expect.write_text("- {log: overload.log.gz, trips: [{guard: Axis0Current, by: 6}]}\n", encoding="utf-8")
        out = tmp_path / "tuned"
        code, stdout, err = cli(capsys, "tune", "-c", robot, repo / "examples/normal.log.gz", busy,
                                "--fault", repo / "examples/overload.log.gz", "--expect", expect, "--out", out)
        assert code == 1
        line = next(x for x in stdout.splitlines() if x.startswith("  Axis0Current"))
        assert "conflict" in line and "busy_day.log.gz" in line and "overload.log.gz" in line
        assert "nothing written" in err
        assert not out.exists()

    def test_jobs_give_the_proposal_of_one_process(self, capsys: pytest.CaptureFixture[str], repo: Path,
                                                  robot: Path) -> None:
        """--jobs 2 replays in two processes and proposes exactly what one process does."""
        args = ["tune", "-c", robot, *_logs(repo, ("normal", "inrush")), "--fault", repo / "examples/spike.log.gz",
                "--json", "--tune-i2t"]
        one = json.loads(cli(capsys, *args)[1])
        two = json.loads(cli(capsys, *args, "--jobs", "2")[1])
        assert one["guards"] == two["guards"] and one["proof"] == two["proof"]
        i2t = next(g for g in one["guards"] if g["node"] == "Axis1I2t")
        assert i2t["status"] == "tuned" and i2t["rating_scale"]

    def test_out_over_the_originals_is_refused(self, capsys: pytest.CaptureFixture[str], repo: Path,
                                              robot: Path) -> None:
        """--out naming the config's own directory: exit 2 before any replay."""
        code, _out, err = cli(capsys, "tune", "-c", robot, repo / "examples/normal.log.gz", "--out", robot.parent)
        assert code == 2 and "never over" in err


class TestExpect:
    """``--expect`` files."""

    def test_reads_healthy_and_trips(self, tmp_path: Path) -> None:
        """Each log's expectation as written."""
        f = tmp_path / "e.yaml"
        f.write_text("- {log: a.log, healthy: true}\n- {log: b.log, trips: [{guard: G, by: 2.5}, {guard: H}]}\n",
                     encoding="utf-8")
        assert load_expect(f) == {"a.log": {"healthy": True}, "b.log": {"trips": [("G", 2.5), ("H", None)]}}

    @pytest.mark.parametrize(("text", "words"), [
        ("a: 1\n", "expected a list"),
        ("- {log: a.log}\n", "item 1: expected `healthy: true`"),
        ("- {log: a.log, trips: [{guard: G, by: -1}]}\n", "by: expected seconds"),
        ("- {log: a.log, healthy: true, when: 3}\n", "unknown key 'when'"),
    ])
    def test_bad_file_named(self, tmp_path: Path, text: str, words: str) -> None:
        """A mistake names the file, the item and what was expected."""
        f = tmp_path / "e.yaml"
        f.write_text(text, encoding="utf-8")
        with pytest.raises(ConfigError, match=words) as exc:
            load_expect(f)
        assert str(f) in str(exc.value)


class TestFiles:
    """The tuned files are edits of the originals."""

    def test_attribute_changed_in_place_or_added(self) -> None:
        """An attribute keeps its place and quotes; a missing one is added; others untouched."""
        xml = "<!-- c -->\n<Seq>\n  <IsCurrentNormal name='A' max_current='5'/>\n  <X name=\"B\" v=\"1\">\n"
        out = set_attributes(xml, "A", {"max_current": 7.5}, "t.xml")
        assert "<IsCurrentNormal name='A' max_current='7.5'/>" in out and out.startswith("<!-- c -->")
        out = set_attributes(out, "B", {"w": 2.0}, "t.xml")
        assert '<X name="B" v="1" w="2">' in out
        with pytest.raises(ConfigError, match="found 0"):
            set_attributes(xml, "C", {"v": 1.0}, "t.xml")

    def test_unnamed_v3_element_found_by_its_id(self) -> None:
        """A BT.CPP v3 ``<Condition ID="X">`` without a name is the node named X (the bundled config's tree)."""
        xml = '<Sequence>\n  <Condition ID="IsCurrentSafe" topic_name="/b" overcurrent_threshold="35"/>\n'
        assert port_text(xml, "IsCurrentSafe", "overcurrent_threshold") == "35"
        out = set_attributes(xml, "IsCurrentSafe", {"overcurrent_threshold": 12.5}, "t.xml")
        assert '<Condition ID="IsCurrentSafe" topic_name="/b" overcurrent_threshold="12.5"/>' in out

    def test_config_max_age_paths_and_tree(self, tmp_path: Path) -> None:
        """max_age set in flow and block mappings; relative paths made absolute; the config loads."""
        (tmp_path / "dbc").mkdir()
        shutil.copy(Path(__file__).parent.parent / "dbc/robot.dbc", tmp_path / "dbc/robot.dbc")
        text = ("dbc: [dbc/robot.dbc]  # keep me\nbuses:\n  main: {interface: virtual, channel: c}\nsources:\n"
                "  axis0: {kind: current, message: Axis0_Get_Iq, signal: Iq_Measured}\n"
                "  axis1:\n    kind: current\n    message: Axis1_Get_Iq\n    signal: Iq_Measured  # amps\n"
                "  axis2: {kind: current, message: Axis2_Get_Iq, signal: Iq_Measured, max_age: 0.5}\n"
                "tree: {file: t.xml, main: M, tick_hz: 100}\n")
        out = tuned_config(text, tmp_path, "tuned.xml", {"axis0": 0.25, "axis1": 0.125, "axis2": 0.75})
        assert f'dbc: ["{tmp_path}/dbc/robot.dbc"]  # keep me' in out
        assert "signal: Iq_Measured, max_age: 0.25}" in out
        assert "    signal: Iq_Measured  # amps\n    max_age: 0.125\n" in out
        assert "signal: Iq_Measured, max_age: 0.75}" in out
        assert 'tree: {file: "tuned.xml"' in out
        other = tmp_path / "elsewhere"
        other.mkdir()
        (other / "c.yaml").write_text(out, encoding="utf-8")
        (other / "tuned.xml").write_text('<root BTCPP_format="4" main_tree_to_execute="M"><BehaviorTree ID="M">'
                                         '<IsCurrentNormal topic_name="axis0"/></BehaviorTree></root>',
                                         encoding="utf-8")
        cfg = load_config(other / "c.yaml")
        assert [cfg.sources[s].max_age_s for s in ("axis0", "axis1", "axis2")] == [0.25, 0.125, 0.75]


class TestMaths:
    """The small pieces the proposal is made of."""

    def test_separate(self) -> None:
        """Above the healthy ceiling by the margin, below every fault; the midpoint when only less fits."""
        assert separate(10.0, [20.0], 0.1) == (11.0, "")
        value, note = separate(10.0, [10.5], 0.1)
        assert value == 10.25 and "margin reduced" in note
        assert separate(10.0, [9.0], 0.1) == (None, "")

    def test_nice_up_stays_below_the_fault(self) -> None:
        """Three significant digits up, unless that reaches what a fault needs."""
        assert nice_up(6.8112) == 6.82
        assert nice_up(6.8112, below=6.815) == 6.8112

    def test_percentiles_merge(self) -> None:
        """Histogram percentiles land within a bin (1 %) of numpy's, and merge by adding counts."""
        import numpy as np

        a = np.abs(np.random.default_rng(1).normal(5.0, 2.0, 5000))
        h = histogram(a[:2500])
        for k, c in histogram(a[2500:]).items():
            h[k] = h.get(k, 0) + c
        assert percentile(h, 99.0) == pytest.approx(float(np.percentile(a, 99.0)), rel=0.011)
