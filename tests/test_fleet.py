"""Fleet replay: directories, globs and @lists of logs; --jobs and --dask give the serial results.

The Dask case runs a real ``distributed.LocalCluster`` of two worker processes on loopback
and compares its ``--json`` output with a serial run of the same logs, byte for byte.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import pytest

from canguard.cli.fleet import expand_logs
from canguard.cli.main import main
from canguard.errors import ConfigError
from checkout import REPO

CONFIG = REPO / "config" / "examples" / "robot_guard.yaml"
EXAMPLES = sorted((REPO / "examples").glob("*.log.gz"))


def make_fleet(root: Path) -> Path:
    """Three example logs in a tree of directories under ``root``, plus a file that is not a log."""
    (root / "day1").mkdir(parents=True)
    (root / "day2").mkdir()
    shutil.copy(EXAMPLES[0], root / "day1" / EXAMPLES[0].name)
    shutil.copy(EXAMPLES[1], root / "day1" / EXAMPLES[1].name)
    shutil.copy(EXAMPLES[2], root / "day2" / EXAMPLES[2].name)
    (root / "day2" / "notes.md").write_text("not a log\n", encoding="utf-8")
    return root


@pytest.fixture
def fleet(tmp_path: Path) -> Path:
    """A fleet of this test's own (it may add files to it)."""
    return make_fleet(tmp_path / "fleet")


@dataclass(frozen=True)
class SerialRun:
    """``replay FLEET --json`` run once for the module, with ``--fleet-summary`` to Parquet where pyarrow is."""

    fleet: Path
    stdout: str
    parquet: Path | None


@pytest.fixture(scope="module")
def serial(tmp_path_factory: pytest.TempPathFactory) -> SerialRun:
    """The serial run every other way of running the fleet is compared with (its fleet is read only)."""
    root = make_fleet(tmp_path_factory.mktemp("serial") / "fleet")
    argv = ["replay", str(root), "-c", str(CONFIG), "--json"]
    parquet = root.parent / "fleet.parquet" if importlib.util.find_spec("pyarrow") is not None else None
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(argv if parquet is None else [*argv, "--fleet-summary", str(parquet)])
    assert code == 0 and len(json.loads(out.getvalue())) == 3
    return SerialRun(root, out.getvalue(), parquet)


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


class TestWhichLogs:
    def test_a_directory_is_every_log_in_it_sorted(self, fleet: Path) -> None:
        got = expand_logs([fleet])
        assert [p.relative_to(fleet).as_posix() for p in got] == [
            f"day1/{EXAMPLES[0].name}", f"day1/{EXAMPLES[1].name}", f"day2/{EXAMPLES[2].name}"]

    def test_a_glob_and_a_list(self, fleet: Path, tmp_path: Path) -> None:
        assert expand_logs([Path(f"{fleet}/**/*.log.gz")]) == expand_logs([fleet])
        listing = fleet / "logs.txt"
        listing.write_text(f"# the two of day 1\nday1/{EXAMPLES[1].name}\n\nday1/{EXAMPLES[0].name}  # first\n",
                           encoding="utf-8")
        assert expand_logs([Path(f"@{listing}")]) == [fleet / "day1" / EXAMPLES[1].name,
                                                      fleet / "day1" / EXAMPLES[0].name]

    @pytest.mark.parametrize(("what", "expected"), [
        ("empty_dir", "no log files in the directory"),
        ("no_match", "the pattern matches no file"),
        ("missing_list", "cannot read the list of logs"),
        ("empty_list", "the list names no log"),
    ])
    def test_what_names_nothing_is_an_error(self, tmp_path: Path, what: str, expected: str) -> None:
        (tmp_path / "empty").mkdir()
        (tmp_path / "empty.txt").write_text("# nothing\n", encoding="utf-8")
        arg = {"empty_dir": tmp_path / "empty", "no_match": tmp_path / "*.blf",
               "missing_list": Path(f"@{tmp_path / 'nope.txt'}"), "empty_list": Path(f"@{tmp_path / 'empty.txt'}")}
        with pytest.raises(ConfigError, match=expected):
            expand_logs([arg[what]])


class TestRuns:
    def test_jobs_and_a_broken_log_among_good_ones(self, serial: SerialRun, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
        """--jobs 2 gives the serial summaries; a corrupt log is reported, the others are not lost."""
        bad = tmp_path / "broken.log.gz"
        bad.write_bytes(b"this is not gzip")
        table = tmp_path / "fleet.jsonl"
        code, out, err = run(["replay", str(serial.fleet / "day1"), str(bad), str(serial.fleet / "day2"),
                              "-c", str(CONFIG), "--json", "--jobs", "2", "--fleet-summary", str(table)], capsys)
        assert code == 2 and "broken.log.gz: cannot read gzip log" in err
        assert out == serial.stdout  # the workers' summaries of the three good logs, byte for byte, in order
        rows = [json.loads(line) for line in table.read_text(encoding="utf-8").splitlines()]
        assert [r["status"] for r in rows] == ["ok", "ok", "failed", "ok"]
        failed = rows[2]
        assert failed["log"].endswith("broken.log.gz") and "cannot read gzip log" in failed["reason"]
        ok = rows[0]
        assert ok["frames"] > 1000 and ok["trips"] >= 0 and ok["worst_margin_pct"] is not None

    def test_parquet_summary(self, serial: SerialRun) -> None:
        """--fleet-summary FILE.parquet holds a row per log, as the --json summaries say."""
        pq = pytest.importorskip("pyarrow.parquet")
        assert serial.parquet is not None
        got = pq.read_table(serial.parquet).to_pylist()
        summaries = json.loads(serial.stdout)
        assert [r["log"] for r in got] == [s["log"] for s in summaries]
        assert [r["trips"] for r in got] == [s["trip_count"] for s in summaries]

    def test_dask_local_cluster_gives_the_serial_summaries(self, serial: SerialRun,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
        """--dask on a local cluster of two worker processes prints the serial run's summaries byte for byte."""
        distributed = pytest.importorskip("distributed")
        import dask

        # The workers forked from one server that imported distributed (as Dask's own tests start theirs), not
        # each spawned to import it anew (~1.5 CPU-s less): how a cluster starts its workers is its own business.
        with dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"}), \
                distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                         dashboard_address=None, host="127.0.0.1") as cluster:
            code, on_dask, err = run(["replay", str(serial.fleet), "-c", str(CONFIG), "--json",
                                      "--dask", cluster.scheduler_address], capsys)
        assert code == 0, err
        assert on_dask == serial.stdout

    def test_dask_without_a_scheduler_is_a_clear_error(self, fleet: Path, capsys: pytest.CaptureFixture[str],
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
        pytest.importorskip("distributed")
        import canguard.cli.fleet

        monkeypatch.setattr(canguard.cli.fleet, "CONNECT_TIMEOUT", "2s")  # the message, not the 10 s wait
        code, _, err = run(["replay", str(fleet), "-c", str(CONFIG), "--dask", "tcp://127.0.0.1:9"], capsys)
        assert code == 2 and "--dask tcp://127.0.0.1:9: cannot reach the scheduler" in err
