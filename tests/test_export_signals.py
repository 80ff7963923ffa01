"""``canguard replay --export-signals FILE.parquet``: every decoded sample as a table, as a user reads it.

The command runs in-process (:func:`tests.clikit.cli`) over the shipped example logs and
``config/examples/robot_guard.yaml``, all by absolute path; the Parquet files are read
back with pyarrow (the ``fleet`` extra, installed with ``test``).
"""

from __future__ import annotations

import contextlib
import gzip
import io
import json
import math
import os
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import cantools
import pytest
from tests.clikit import cli

from checkout import REPO

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

CFG = REPO / "config" / "examples" / "robot_guard.yaml"
DBC = REPO / "dbc" / "robot.dbc"
OVERLOAD = REPO / "examples" / "overload.log.gz"
GARBAGE = REPO / "examples" / "garbage.log.gz"
COLUMNS = ["log", "t", "bus", "source", "signal", "value", "reason"]


def export(capsys: pytest.CaptureFixture[str], out: Path, *logs: Path, extra: tuple[Any, ...] = ()) -> tuple[
        list[dict[str, Any]], Any]:
    """Replay ``logs`` with ``--export-signals out --json``: (the summaries as a list, the table read back)."""
    code, stdout, err = cli(capsys, "replay", *logs, "-c", CFG, "--json", "--export-signals", out, *extra)
    assert code in (0, 1), err
    summaries = json.loads(stdout)
    return summaries if isinstance(summaries, list) else [summaries], pq.read_table(out)


def candump_frames(log: Path, frame_id: int, count: int) -> list[tuple[float, bytes]]:
    """The first ``count`` frames of ``frame_id`` in a candump -L log, read without canguard."""
    found: list[tuple[float, bytes]] = []
    with gzip.open(log, "rt", encoding="ascii") as lines:
        for line in lines:
            stamp, _, frame = line.split()
            ident, _, data = frame.partition("#")
            if int(ident, 16) == frame_id:
                found.append((float(stamp.strip("()")), bytes.fromhex(data)))
                if len(found) == count:
                    break
    return found


def listing(directory: Path) -> list[str]:
    """The file names in ``directory``, hidden ones included (no part file may be left behind)."""
    return sorted(os.listdir(directory))


def export_once(out: Path, *logs: Path) -> tuple[list[dict[str, Any]], Any]:
    """:func:`export` for a module's fixture (capsys is per test: the command's stdout is taken directly)."""
    from canguard.cli.main import main

    with contextlib.redirect_stdout(io.StringIO()) as stdout:
        code = main(["replay", *map(str, logs), "-c", str(CFG), "--json", "--export-signals", str(out)])
    assert code in (0, 1)
    summaries = json.loads(stdout.getvalue())
    return summaries if isinstance(summaries, list) else [summaries], pq.read_table(out)


@pytest.fixture(scope="module")
def overload_export(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Any]:
    """The summary and the table one export of the overload example gives (once for the module)."""
    (summary,), table = export_once(tmp_path_factory.mktemp("export") / "overload.parquet", OVERLOAD)
    return summary, table


@pytest.fixture(scope="module")
def overload(overload_export: tuple[dict[str, Any], Any]) -> Any:
    """The table one export of the overload example gives."""
    return overload_export[1]


@pytest.fixture(scope="module")
def two_logs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, Any]], Any]:
    """The garbage and overload examples exported in one run by one process (once for the module): its directory,
    the summaries and the table."""
    out = tmp_path_factory.mktemp("two") / "two.parquet"
    summaries, table = export_once(out, GARBAGE, OVERLOAD)
    return out.parent, summaries, table


class TestOneLog:
    """The file one log gives: its columns, its rows and their values."""

    def test_columns_and_types(self, overload: Any) -> None:
        """The file has the documented columns in order, t and value as float64, the rest strings."""
        table = overload
        assert table.column_names == COLUMNS
        types = {f.name: f.type for f in table.schema}
        assert types["t"] == pa.float64() and types["value"] == pa.float64()
        assert all(types[c] == pa.string() for c in ("log", "bus", "source", "signal", "reason"))

    def test_rows_equal_the_summarys_sample_counts(self, capsys: pytest.CaptureFixture[str],
                                                   overload_export: tuple[dict[str, Any], Any]) -> None:
        """Per source, the rows equal the summary's sample counts; the summary is the same as without the flag."""
        summary, table = overload_export
        assert dict(Counter(table.column("source").to_pylist())) == summary["samples"]
        assert table.num_rows == sum(summary["samples"].values())
        code, plain, err = cli(capsys, "replay", OVERLOAD, "-c", CFG, "--json")
        assert code == 0, err
        assert json.loads(plain) == summary

    def test_values_equal_cantools(self, overload: Any) -> None:
        """The first Iq and pack-current rows hold exactly what cantools decodes from those frames."""
        rows = overload.to_pylist()
        db = cantools.database.load_file(str(DBC))
        for source, signal, message, field in (("axis0", "current", "Axis0_Get_Iq", "Iq_Measured"),
                                               ("/battery_state", "current", "BMS_Status", "Pack_Current")):
            msg = db.get_message_by_name(message)
            frames = candump_frames(OVERLOAD, msg.frame_id, 20)
            got = [(r["t"], r["value"]) for r in rows if r["source"] == source and r["signal"] == signal][:20]
            want = [(t, float(msg.decode(data)[field])) for t, data in frames]
            assert len(want) == 20
            assert got == want

    def test_log_bus_and_valid_reason(self, overload: Any) -> None:
        """Every row names the log as given and the source's bus, and valid samples have an empty reason."""
        table = overload
        assert set(table.column("log").to_pylist()) == {str(OVERLOAD)}
        assert set(table.column("bus").to_pylist()) == {"main"}
        assert set(table.column("reason").to_pylist()) == {""}
        assert {"present", "current", "axis0"} <= set(table.column("signal").to_pylist())

    def test_batches_become_row_groups(self, capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
        """Rows are written in batches (one Parquet row group each), not held for the whole log."""
        import canguard.report.export as export_mod

        monkeypatch.setattr(export_mod, "BATCH_ROWS", 1000)
        out = tmp_path / "b.parquet"
        (summary,), table = export(capsys, out, OVERLOAD)
        rows = sum(summary["samples"].values())
        assert pq.ParquetFile(out).num_row_groups == math.ceil(rows / 1000)
        assert table.num_rows == rows
        assert listing(tmp_path) == ["b.parquet"]


class TestInvalidSamples:
    """Samples the models rejected carry the reason."""

    def test_garbage_reasons(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """The garbage example's NaN, inf and wrong-length frames are NaN rows with their reason at the trip times."""
        (summary,), table = export(capsys, tmp_path / "g.parquet", GARBAGE)
        bad = [r for r in table.to_pylist() if r["reason"]]
        assert Counter(r["reason"] for r in bad) == {"nan": 2, "inf": 1, "bad_length": 3}
        assert all(math.isnan(r["value"]) for r in bad)
        for trip in summary["trips"]:
            assert any(r["t"] == trip["t"] and r["source"] == trip["source"] and r["reason"] == trip["reason"]
                       for r in bad), trip

    def test_out_of_range(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """A value outside the DBC's [min|max] keeps its value and carries reason out_of_range."""
        db = cantools.database.load_file(str(DBC))
        msg = db.get_message_by_name("Axis0_Get_Iq")
        log = tmp_path / "range.log"
        lines = []
        for i, iq in enumerate((5.0, 75.0, 6.0)):  # Iq_Measured is [-60|60] A in the DBC
            data = msg.encode({"Iq_Setpoint": 0.0, "Iq_Measured": iq}, strict=False)
            lines.append(f"({1_700_000_000 + 0.01 * i:.6f}) can0 {msg.frame_id:03X}#{data.hex().upper()}\n")
        log.write_text("".join(lines), encoding="ascii")
        _, table = export(capsys, tmp_path / "r.parquet", log)
        rows = [(r["value"], r["reason"]) for r in table.to_pylist() if r["source"] == "axis0"]
        assert rows == [(5.0, ""), (75.0, "out_of_range"), (6.0, "")]


class TestSeveralLogs:
    """Several logs in one run share one file; the log column tells them apart."""

    def test_two_logs_one_file_in_input_order(self, two_logs: tuple[Path, list[dict[str, Any]], Any]) -> None:
        """Both logs' names are in the log column, in input order, each with its own summary's sample count."""
        directory, summaries, table = two_logs
        logs = table.column("log").to_pylist()
        assert list(dict.fromkeys(logs)) == [str(GARBAGE), str(OVERLOAD)]
        counts = Counter(logs)
        for summary in summaries:
            assert counts[summary["log"]] == sum(summary["samples"].values())
        assert listing(directory) == ["two.parquet"]

    def test_jobs_2_gives_the_same_file(self, capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                        two_logs: tuple[Path, list[dict[str, Any]], Any]) -> None:
        """--jobs 2 writes the same rows in the same order as one process."""
        one = two_logs[2]
        _, two = export(capsys, tmp_path / "two.parquet", GARBAGE, OVERLOAD, extra=("--jobs", "2"))
        assert repr(two.to_pylist()) == repr(one.to_pylist())  # repr: NaN values compare equal
        assert listing(tmp_path) == ["two.parquet"]

    def test_a_failed_log_adds_no_rows(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """A log that cannot be replayed is exit 2; the file holds the other log's rows and no part is left."""
        (tmp_path / "logs").mkdir()
        broken = tmp_path / "logs" / "broken.log"
        broken.write_text("this is not a candump line\n", encoding="ascii")
        out = tmp_path / "f.parquet"
        code, _, err = cli(capsys, "replay", broken, OVERLOAD, "-c", CFG, "--export-signals", out)
        assert code == 2 and "broken.log" in err
        assert set(pq.read_table(out).column("log").to_pylist()) == {str(OVERLOAD)}
        assert listing(tmp_path) == ["f.parquet", "logs"]


class TestRefusals:
    """What cannot be exported is exit 2 with a message saying why, before any log is replayed."""

    def test_missing_pyarrow(self, capsys: pytest.CaptureFixture[str], tmp_path: Path,
                             monkeypatch: pytest.MonkeyPatch) -> None:
        """Without pyarrow the flag is exit 2 naming it and the extra to install; nothing is replayed or written."""
        monkeypatch.setitem(sys.modules, "pyarrow", None)
        monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)
        out = tmp_path / "x.parquet"
        code, stdout, err = cli(capsys, "replay", OVERLOAD, "-c", CFG, "--export-signals", out)
        assert code == 2
        assert "--export-signals" in err and "pip install 'canguard[fleet]'" in err
        assert stdout == "" and listing(tmp_path) == []

    def test_plain_replay_needs_no_pyarrow(self, capsys: pytest.CaptureFixture[str],
                                           monkeypatch: pytest.MonkeyPatch) -> None:
        """Without the flag a replay runs with pyarrow missing (it is imported only for the export)."""
        monkeypatch.setitem(sys.modules, "pyarrow", None)
        monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)
        code, _, err = cli(capsys, "replay", GARBAGE, "-c", CFG)
        assert code == 0, err

    @pytest.mark.parametrize("where", ["missing_dir", "a_directory"])
    def test_unwritable_path(self, capsys: pytest.CaptureFixture[str], tmp_path: Path, where: str) -> None:
        """A path in a missing directory, or a directory, is exit 2 naming it, with no summary printed."""
        out = tmp_path / "nowhere" / "x.parquet" if where == "missing_dir" else tmp_path
        code, stdout, err = cli(capsys, "replay", OVERLOAD, "-c", CFG, "--export-signals", out)
        assert code == 2 and str(out) in err and "--export-signals" in err
        assert stdout == ""
        assert not (tmp_path / "nowhere").exists()

    @pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes anywhere")
    def test_read_only_directory(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """A file in a read-only directory is exit 2 naming it."""
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        try:
            code, stdout, err = cli(capsys, "replay", OVERLOAD, "-c", CFG, "--export-signals", ro / "x.parquet")
        finally:
            ro.chmod(0o755)
        assert code == 2 and str(ro / "x.parquet") in err and stdout == ""

    def test_dask_refused(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """--dask with the flag is exit 2 saying to use --jobs, before any scheduler is contacted."""
        code, stdout, err = cli(capsys, "replay", OVERLOAD, GARBAGE, "-c", CFG, "--dask", "tcp://127.0.0.1:9",
                                "--export-signals", tmp_path / "x.parquet")
        assert code == 2 and "--dask" in err and "--jobs" in err and "scheduler" not in err
        assert stdout == "" and listing(tmp_path) == []

    def test_realtime_refused(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """--realtime with the flag is exit 2 naming it."""
        code, _, err = cli(capsys, "replay", OVERLOAD, "-c", CFG, "--realtime", "--export-signals",
                           tmp_path / "x.parquet")
        assert code == 2 and "--export-signals" in err
