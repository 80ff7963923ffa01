"""``canguard replay``: the daemon's engine over recorded logs, as a user runs it.

Everything goes through :func:`canguard.cli.main.main` in-process (stdout / stderr via
capsys), except one test per exit code of the real console entry
(``python -m canguard``). Logs are small simulator logs written once per session.
"""

from __future__ import annotations

import contextlib
import gzip
import io
import json
import os
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import cantools
import pytest
import yaml
from tests.feed import step

from canguard.cli.main import main
from canguard.report.summary import diff_baseline
from canguard.sim import write_log
from checkout import REPO, SRC

BUNDLED = REPO / "config" / "canguard.yaml"
DBC = REPO / "dbc" / "robot.dbc"
T0 = 1_700_000_000.0
"""The simulator's first timestamp (epoch seconds, as candump writes them)."""
DURATION_S = 3.0
SUBPROCESS_TIMEOUT_S = 60

Run = Callable[..., tuple[int, str, str]]
Data = dict[str, Path]


# --------------------------------------------------------------------------- helpers and fixtures


def make_config(directory: Path, *, extra_bus: bool = False) -> Path:
    """The bundled config with absolute paths, events and I²t state inside ``directory``.

    ``extra_bus`` adds a second bus ``aux`` (channel can1), so that frames on an
    unknown channel are no longer routed to the only bus.
    """
    doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
    doc["dbc"] = [str(DBC)]
    doc["tree"]["file"] = str((BUNDLED.parent / doc["tree"]["file"]).resolve())
    doc["events"] = str(directory / "events.jsonl")
    doc["state"]["file"] = str(directory / "i2t_state.json")
    if extra_bus:
        doc["buses"]["aux"] = {"interface": "virtual", "channel": "can1"}
        for source in doc["sources"].values():
            source["bus"] = "main"
        frame_lists = [doc["task"]["frames"], doc["stop"]["frames"], doc["stop"].get("escalate") or []]
        frame_lists += [a["frames"] for a in doc["actions"].values()]
        for frames in frame_lists:
            for frame in frames:
                frame["bus"] = "main"
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / ("canguard-2bus.yaml" if extra_bus else "canguard.yaml")
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


@pytest.fixture(scope="session")
def data(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Configs and simulator logs shared by the whole session (written once, never modified)."""
    d = tmp_path_factory.mktemp("replay_data")
    out = {"cfg": make_config(d / "cfg"), "cfg2": make_config(d / "cfg2", extra_bus=True)}
    for name, scenarios, seed in (("spike", ["spike"], 1), ("normal", ["normal"], 2)):
        out[name] = d / f"{name}.log"
        write_log(out[name], DURATION_S, db=cantools.database.load_file(DBC), scenarios=scenarios, seed=seed)
    return out


@pytest.fixture
def run(capsys: pytest.CaptureFixture[str]) -> Run:
    """``run(*argv)`` -> (exit code, stdout, stderr) of ``canguard replay *argv``, in-process."""

    def _run(*argv: Any) -> tuple[int, str, str]:
        capsys.readouterr()
        code = main(["replay", *map(str, argv)])
        out, err = capsys.readouterr()
        return code, out, err

    return _run


def summary_of(run: Run, *argv: Any) -> dict[str, Any]:
    """The --json summary of a replay that must exit 0."""
    code, out, err = run(*argv, "--json")
    assert code == 0, err
    result: dict[str, Any] = json.loads(out)
    return result


def console(*argv: Any, cwd: Path) -> subprocess.CompletedProcess[str]:
    """Run the real ``canguard`` entry point (``python -m canguard``) from ``cwd``."""
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    return subprocess.run(
        [sys.executable, "-m", "canguard", *map(str, argv)],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT_S, check=False,
    )


def _db() -> Any:
    return cantools.database.load_file(str(DBC))


def bms_line(t: float, current_a: float, channel: str = "can0") -> str:
    """A candump -L line of a BMS_Status frame carrying ``current_a``."""
    msg = _db().get_message_by_name("BMS_Status")
    data = msg.encode({"Pack_Current": current_a, "Pack_Voltage": 48.0, "State_Of_Charge": 80.0,
                       "Present": 1, "Fault": 0, "Alive_Counter": 0})
    return f"({t:.6f}) {channel} {msg.frame_id:08X}#{bytes(data).hex().upper()}"


def trip_keys(summary: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The trips of a summary as (node, source, reason), in order."""
    return [(t["node"], t["source"], t["reason"]) for t in summary["trips"]]


def no_traceback(err: str) -> None:
    """A user error is a message, never a Python traceback."""
    assert "Traceback" not in err


# --------------------------------------------------------------------------- the summary


class TestSummary:
    """The summary: counters, samples, trips with time / node / source / value / threshold, margins."""

    def test_spike_trips_once(self, run: Run, data: Data) -> None:
        """The 60 A BMS spike at 1.51 s is one trip of IsCurrentSafe on /battery_state at 35 A."""
        s = summary_of(run, data["spike"], "-c", data["cfg"])
        [trip] = s["trips"]
        assert "IsCurrentSafe" in trip["node"]
        assert trip["source"] == "/battery_state"
        assert abs(trip["value"]) == pytest.approx(60.0, abs=0.5)
        assert trip["threshold"] == pytest.approx(35.0)
        assert trip["t"] == pytest.approx(T0 + 1.51, abs=0.01)
        assert s["stops"] >= 1

    def test_counters_and_samples(self, run: Run, data: Data) -> None:
        """Frames read equal the log's lines; every configured source has samples; nothing is invalid."""
        s = summary_of(run, data["normal"], "-c", data["cfg"])
        n_lines = len(data["normal"].read_text(encoding="ascii").splitlines())
        f = s["frames"]
        assert f["read"] == n_lines
        assert 0 < f["decoded"] <= f["read"]
        assert f["invalid"] == 0 and f["bad_lines"] == 0 and f["unmapped"] == 0
        assert {"/battery_state", "axis0", "axis1", "axis2", "axis3"} <= set(s["samples"])
        assert s["first_t"] == pytest.approx(T0, abs=0.01)
        assert s["last_t"] == pytest.approx(T0 + DURATION_S, abs=0.05)

    def test_normal_log_never_trips_and_reports_margin(self, run: Run, data: Data) -> None:
        """A normal duty cycle has no trip, no stop, and a positive margin to the 35 A threshold."""
        s = summary_of(run, data["normal"], "-c", data["cfg"])
        assert s["trips"] == [] and s["stops"] == 0 and s["stopped_s"] == 0
        [margin] = [m for m in s["margins"] if m["source"] == "/battery_state"]
        assert margin["threshold"] == pytest.approx(35.0)
        assert 0 < margin["peak"] < 25.0
        assert margin["margin"] == pytest.approx(35.0 - margin["peak"], abs=1e-6)

    def test_spike_margin_is_negative(self, run: Run, data: Data) -> None:
        """A log that tripped shows a peak above the threshold: a negative margin."""
        s = summary_of(run, data["spike"], "-c", data["cfg"])
        [margin] = [m for m in s["margins"] if m["source"] == "/battery_state"]
        assert margin["peak"] == pytest.approx(60.0, abs=0.5)
        assert margin["margin"] < 0

    def test_text_summary_names_the_trip(self, run: Run, data: Data) -> None:
        """Without --json the human summary lists the trip with its source, value and threshold."""
        code, out, _ = run(data["spike"], "-c", data["cfg"])
        assert code == 0
        assert "trips: 1" in out
        [line] = [ln for ln in out.splitlines() if "source=/battery_state" in ln]
        assert "IsCurrentSafe" in line and "threshold=35" in line
        assert "lowest margin" in out

    def test_frames_canguard_would_send_are_counted(self, run: Run, data: Data) -> None:
        """A tripped log sends task frames before the trip and stop frames after it."""
        s = summary_of(run, data["spike"], "-c", data["cfg"])
        assert s["frames_sent"] > 0


class TestExitCodes:
    """--fail-on-trip makes replay a CI gate: 1 on a trip, 0 otherwise."""

    def test_fail_on_trip_with_a_trip(self, run: Run, data: Data) -> None:
        """A spike log with --fail-on-trip exits 1."""
        code, _, _ = run(data["spike"], "-c", data["cfg"], "--fail-on-trip")
        assert code == 1

    def test_fail_on_trip_without_a_trip(self, run: Run, data: Data) -> None:
        """A normal log with --fail-on-trip exits 0."""
        code, _, _ = run(data["normal"], "-c", data["cfg"], "--fail-on-trip")
        assert code == 0

    def test_trip_without_the_gate_exits_0(self, run: Run, data: Data) -> None:
        """Without --fail-on-trip a trip is reported, not an error."""
        code, _, _ = run(data["spike"], "-c", data["cfg"])
        assert code == 0

    def test_any_log_of_several_trips_the_gate(self, run: Run, data: Data) -> None:
        """Over a set of logs, one trip anywhere is exit 1."""
        code, _, _ = run(data["normal"], data["spike"], "-c", data["cfg"], "--fail-on-trip")
        assert code == 1

    def test_console_entry_exit_codes(self, data: Data, tmp_path: Path) -> None:
        """The real console entry, started away from the repo, exits 1 on a trip and 0 on a clean log."""
        both = console("replay", data["spike"], "-c", data["cfg"], "--fail-on-trip", cwd=tmp_path)
        assert both.returncode == 1, both.stderr
        assert "trips: 1" in both.stdout
        clean = console("replay", data["normal"], "-c", data["cfg"], "--fail-on-trip", cwd=tmp_path)
        assert clean.returncode == 0, clean.stderr


class TestDeterminism:
    """The same log and config always give byte-identical output."""

    def test_two_runs_identical_bytes(self, run: Run, data: Data, tmp_path: Path) -> None:
        """Text summary, --json summary, --events and --emit files are identical across two runs."""
        outputs = []
        for i in (1, 2):
            d = tmp_path / str(i)
            d.mkdir()
            _, text, _ = run(data["spike"], "-c", data["cfg"])
            _, js, _ = run(data["spike"], "-c", data["cfg"], "--json",
                           "--events", d / "events.jsonl", "--emit", d / "emit.log")
            outputs.append((text, js, (d / "events.jsonl").read_bytes(), (d / "emit.log").read_bytes()))
        assert outputs[0] == outputs[1]
        text, js, events, emit = outputs[0]
        assert text and js and events and emit

    def test_events_are_the_daemons_json_lines(self, run: Run, data: Data, tmp_path: Path) -> None:
        """--events writes one JSON object per line, with the trip at the log's time."""
        path = tmp_path / "events.jsonl"
        code, _, _ = run(data["spike"], "-c", data["cfg"], "--events", path)
        assert code == 0
        events = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines()]
        trips = [e for e in events if e["event"] == "trip"]
        assert len(trips) == 1
        assert trips[0]["source"] == "/battery_state"
        assert trips[0]["t"] == pytest.approx(T0 + 1.51, abs=0.01)
        assert [e["t"] for e in events] == sorted(e["t"] for e in events)


class TestTimestamps:
    """Real logs have timestamps that go backwards or repeat: counted, handled, never a crash."""

    def test_backwards_and_repeated_counted(self, run: Run, data: Data, tmp_path: Path) -> None:
        """One backward and one repeated timestamp in a hand-written log are counted; exit 0."""
        log = tmp_path / "jumpy.log"
        times = [100.00, 100.02, 100.01, 100.01, 100.04, 100.06]
        log.write_text("".join(bms_line(t, 10.0) + "\n" for t in times), encoding="ascii")
        s = summary_of(run, log, "-c", data["cfg"])
        assert s["frames"]["read"] == len(times)
        assert s["frames"]["backward_timestamps"] == 1
        assert s["frames"]["repeated_timestamps"] == 1
        assert s["samples"]["/battery_state"] >= len(times)

    def test_clock_jumps_never_crash(self, run: Run, data: Data, tmp_path: Path) -> None:
        """A jump an hour back and a day forward are handled: the replay ends normally with a summary."""
        log = tmp_path / "jumps.log"
        times = [5000.0, 5000.02, 1400.0, 1400.02, 91400.0, 91400.02, 91400.04]
        log.write_text("".join(bms_line(t, 12.0) + "\n" for t in times), encoding="ascii")
        code, out, err = run(log, "-c", data["cfg"], "--json")
        assert code == 0, err
        s = json.loads(out)
        assert s["frames"]["read"] == len(times)
        assert s["frames"]["backward_timestamps"] == 1
        assert s["last_t"] == pytest.approx(91400.04)

    def test_spike_on_a_repeated_timestamp_still_trips(
        self, run: Run, data: Data, tmp_path: Path
    ) -> None:
        """A 60 A frame sharing its timestamp with the previous frame is not lost: every sample counts."""
        log = tmp_path / "repeat_spike.log"
        currents = [(100.0, 10.0), (100.02, 10.0), (100.02, 60.0), (100.04, 10.0)]
        lines = [bms_line(t, i) for t, i in currents]
        log.write_text("\n".join(lines) + "\n", encoding="ascii")
        s = summary_of(run, log, "-c", data["cfg"])
        assert [t["source"] for t in s["trips"]] == ["/battery_state"]
        assert s["frames"]["repeated_timestamps"] == 1


class TestBadInput:
    """Bad logs are clear errors (exit 2) or counted warnings, never a traceback."""

    @pytest.fixture
    def bad_log(self, tmp_path: Path) -> Path:
        """A candump -L log whose third line is malformed."""
        log = tmp_path / "bad.log"
        lines = [bms_line(100.0, 10.0), bms_line(100.02, 10.0), "(100.030000) can0 12G#00"]
        lines.append(bms_line(100.04, 10.0))
        log.write_text("\n".join(lines) + "\n", encoding="ascii")
        return log

    def test_malformed_line_names_file_line_and_text(self, run: Run, data: Data, bad_log: Path) -> None:
        """A malformed line stops the replay with exit 2 and an error naming file:line and the text."""
        code, _, err = run(bad_log, "-c", data["cfg"])
        assert code == 2
        assert f"{bad_log}:3" in err
        assert "12G#00" in err
        no_traceback(err)

    def test_skip_bad_counts_and_continues(self, run: Run, data: Data, bad_log: Path) -> None:
        """With --skip-bad the malformed line is counted in the summary and the replay exits 0."""
        s = summary_of(run, bad_log, "-c", data["cfg"], "--skip-bad")
        assert s["frames"]["bad_lines"] == 1
        assert s["frames"]["read"] == 3

    def test_skip_bad_shown_in_text(self, run: Run, data: Data, bad_log: Path) -> None:
        """The human summary says how many bad lines were skipped."""
        code, out, _ = run(bad_log, "-c", data["cfg"], "--skip-bad")
        assert code == 0
        assert "1 bad lines" in out

    def test_empty_log(self, run: Run, data: Data, tmp_path: Path) -> None:
        """An empty log is exit 2 with an error naming the file."""
        log = tmp_path / "empty.log"
        log.write_text("", encoding="ascii")
        code, _, err = run(log, "-c", data["cfg"])
        assert code == 2
        assert str(log) in err and "empty" in err
        no_traceback(err)

    def test_missing_file(self, run: Run, data: Data, tmp_path: Path) -> None:
        """A log that does not exist is exit 2 with an error naming it."""
        log = tmp_path / "nope.log"
        code, _, err = run(log, "-c", data["cfg"])
        assert code == 2
        assert str(log) in err and "no such file" in err
        no_traceback(err)

    def test_unknown_extension(self, run: Run, data: Data, tmp_path: Path) -> None:
        """A log with an unknown extension is exit 2 listing the known ones."""
        log = tmp_path / "capture.pcap"
        log.write_bytes(b"\0\0")
        code, _, err = run(log, "-c", data["cfg"])
        assert code == 2
        assert str(log) in err and ".asc" in err
        no_traceback(err)

    def test_frames_matching_no_message_warn(self, run: Run, data: Data, tmp_path: Path) -> None:
        """A log whose frames match no configured message replays with a warning, not an error."""
        log = tmp_path / "foreign.log"
        log.write_text("".join(f"({100 + i / 100:.6f}) can0 7AB#0102\n" for i in range(5)), encoding="ascii")
        code, out, err = run(log, "-c", data["cfg"])
        assert code == 0, err
        assert "no frame of this log matches a configured message" in out

    def test_one_bad_log_of_several(self, run: Run, data: Data, tmp_path: Path) -> None:
        """A missing log among good ones: the good ones are still reported, the exit code is 2."""
        code, out, err = run(data["normal"], tmp_path / "missing.log", "-c", data["cfg"])
        assert code == 2
        assert f"replay of {data['normal']}" in out
        assert "missing.log" in err


class TestEmit:
    """--emit writes the frames canguard would have sent as a candump -L log python-can reads."""

    def test_emit_read_back_with_python_can(self, run: Run, data: Data, tmp_path: Path) -> None:
        """python-can's CanutilsLogReader reads the task frames, then the Estop frames after the trip."""
        db = _db()
        estop = {db.get_message_by_name(f"Axis{n}_Estop").frame_id for n in range(4)}
        set_state = {db.get_message_by_name(f"Axis{n}_Set_Axis_State").frame_id for n in range(4)}
        emit = tmp_path / "emit.log"
        s = summary_of(run, data["spike"], "-c", data["cfg"], "--emit", emit)
        msgs = list(can.CanutilsLogReader(emit))
        assert len(msgs) == s["frames_sent"]
        ids = {m.arbitration_id for m in msgs}
        assert estop <= ids and set_state <= ids
        assert ids <= estop | set_state | {db.get_message_by_name(f"Axis{n}_Clear_Errors").frame_id
                                            for n in range(4)}
        trip_t = s["trips"][0]["t"]
        first_estop = min(m.timestamp for m in msgs if m.arbitration_id in estop)
        assert first_estop == pytest.approx(trip_t, abs=1e-3)
        before = [m for m in msgs if m.timestamp < trip_t]
        assert before and all(m.arbitration_id in set_state for m in before)
        for m in before:
            decoded = db.decode_message(m.arbitration_id, m.data)
            assert str(decoded["Axis_Requested_State"]) == "CLOSED_LOOP_CONTROL"
        assert all(m.channel == "can0" for m in msgs)

    def test_frames_sent_same_without_emit(self, run: Run, data: Data, tmp_path: Path) -> None:
        """The summary counts the frames canguard would send whether or not --emit writes them."""
        with_emit = summary_of(run, data["spike"], "-c", data["cfg"], "--emit", tmp_path / "emit.log")
        without = summary_of(run, data["spike"], "-c", data["cfg"])
        assert without == with_emit and without["frames_sent"] > 0

    def test_no_trip_sends_only_task_frames(self, run: Run, data: Data, tmp_path: Path) -> None:
        """A clean log emits only the task's Set_Axis_State heartbeat, about every 20 ms."""
        db = _db()
        set_state = {db.get_message_by_name(f"Axis{n}_Set_Axis_State").frame_id for n in range(4)}
        emit = tmp_path / "emit.log"
        run(data["normal"], "-c", data["cfg"], "--emit", emit)
        msgs = list(can.CanutilsLogReader(emit))
        assert {m.arbitration_id for m in msgs} == set_state
        per_axis = len(msgs) / 4
        assert per_axis == pytest.approx(DURATION_S / 0.02, rel=0.05)


@pytest.fixture(scope="module")
def saved(data: Data, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """--json summaries of the spike and normal logs saved to files (once: the tests only read them)."""
    directory = tmp_path_factory.mktemp("baselines")
    out = {}
    for name in ("spike", "normal"):
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed), contextlib.redirect_stderr(io.StringIO()):
            code = main(["replay", str(data[name]), "-c", str(data["cfg"]), "--json"])
        assert code == 0
        out[name] = directory / f"{name}.json"
        out[name].write_text(printed.getvalue(), encoding="utf-8")
    return out


class TestBaseline:
    """--baseline compares with a saved --json summary: new trips, lost trips, margins that shrank."""

    def test_new_trip_and_shrunk_margin(self, run: Run, data: Data, saved: dict[str, Path]) -> None:
        """Against a clean baseline, the spike log reports a new trip, a shrunk margin and more stops."""
        code, _, err = run(data["spike"], "-c", data["cfg"], "--baseline", saved["normal"])
        assert code == 0
        assert re.search(r"new trip: \S*IsCurrentSafe\S* on /battery_state .*0 -> 1", err), err
        assert "margin shrank" in err and "/battery_state" in err
        assert "stops: 0 -> " in err

    def test_lost_trip(self, run: Run, data: Data, saved: dict[str, Path]) -> None:
        """Against a tripped baseline, a clean log reports the trip as lost and no shrunk margin."""
        code, _, err = run(data["normal"], "-c", data["cfg"], "--baseline", saved["spike"])
        assert code == 0
        assert re.search(r"lost trip: \S*IsCurrentSafe\S* on /battery_state .*1 -> 0", err), err
        assert "margin shrank" not in err

    def test_same_log_no_change(self, run: Run, data: Data, saved: dict[str, Path]) -> None:
        """The same log against its own baseline reports no change."""
        code, _, err = run(data["spike"], "-c", data["cfg"], "--baseline", saved["spike"])
        assert code == 0
        assert "no change" in err

    def test_compare_baseline_counts_repeated_trips(self) -> None:
        """Two trips of a guard where the baseline had one are reported as a new trip (1 -> 2)."""
        trip = {"node": "G", "source": "s", "reason": "overcurrent"}
        old = {"trips": [trip], "margins": [], "stops": 1}
        new = {"trips": [trip, trip], "margins": [], "stops": 1}
        assert [c.text for c in diff_baseline(old, new)] == ["new trip: G on s (overcurrent): 1 -> 2"]
        assert diff_baseline(old, old) == []

    def test_baseline_not_json(self, run: Run, data: Data, tmp_path: Path) -> None:
        """A baseline that is not a --json summary is exit 2 naming it, not a traceback."""
        bad = tmp_path / "bad.json"
        bad.write_text("replay of x.log\n", encoding="utf-8")
        code, _, err = run(data["spike"], "-c", data["cfg"], "--baseline", bad)
        assert code == 2
        assert "bad.json" in err
        no_traceback(err)

    def test_missing_baseline_file(self, run: Run, data: Data, tmp_path: Path) -> None:
        """A baseline that does not exist is exit 2 naming it, not a traceback."""
        code, _, err = run(data["spike"], "-c", data["cfg"], "--baseline", tmp_path / "gone.json")
        assert code == 2
        assert "gone.json" in err
        no_traceback(err)


class TestChannelMap:
    """Log channels reach the config's buses by channel name, by --map, or as the only bus."""

    @pytest.fixture(scope="class")
    @classmethod
    def renamed(cls, data: Data, tmp_path_factory: pytest.TempPathFactory) -> Path:
        """The spike log recorded on a channel called robot0 instead of can0."""
        log = tmp_path_factory.mktemp("renamed") / "robot0.log"
        text = data["spike"].read_text(encoding="ascii").replace(" can0 ", " robot0 ")
        log.write_text(text, encoding="ascii")
        return log

    def test_only_bus_takes_any_channel(self, run: Run, data: Data, renamed: Path) -> None:
        """With one configured bus no map is needed: a robot0 log still trips."""
        s = summary_of(run, renamed, "-c", data["cfg"])
        assert len(s["trips"]) == 1
        assert s["unmapped_channels"] == {}

    def test_unmapped_channel_warns(self, run: Run, data: Data, renamed: Path) -> None:
        """With two buses, robot0 matches neither: its frames are counted and a warning says --map."""
        code, out, err = run(renamed, "-c", data["cfg2"])
        assert code == 0, err
        assert "use --map" in out and "robot0" in out
        s = summary_of(run, renamed, "-c", data["cfg2"])
        n = len(renamed.read_text(encoding="ascii").splitlines())
        assert s["unmapped_channels"] == {"robot0": n}
        assert s["frames"]["unmapped"] == n
        assert s["frames"]["decoded"] == 0
        assert s["trips"] == []

    def test_map_routes_channel(self, run: Run, data: Data, renamed: Path) -> None:
        """--map robot0=main routes the frames and gives the same trips as the can0 log."""
        mapped = summary_of(run, renamed, "-c", data["cfg2"], "--map", "robot0=main")
        direct = summary_of(run, data["spike"], "-c", data["cfg2"])
        assert mapped["unmapped_channels"] == {}
        assert mapped["trips"] == direct["trips"] and len(mapped["trips"]) == 1

    def test_can0_is_main_by_channel_name(self, run: Run, data: Data) -> None:
        """With two buses, can0 frames go to the bus whose channel is can0; --map can0=main is the same."""
        plain = summary_of(run, data["spike"], "-c", data["cfg2"])
        mapped = summary_of(run, data["spike"], "-c", data["cfg2"], "--map", "can0=main")
        assert plain["unmapped_channels"] == {} and len(plain["trips"]) == 1
        assert plain == mapped

    @pytest.mark.parametrize("item", ["robot0=nowhere", "robot0", "=main"])
    def test_bad_map(self, run: Run, data: Data, renamed: Path, item: str) -> None:
        """A --map naming an unknown bus or missing '=' is exit 2 naming the item."""
        code, _, err = run(renamed, "-c", data["cfg2"], f"--map={item}")
        assert code == 2
        assert repr(item) in err
        no_traceback(err)


class TestFormats:
    """The same frames in another format give the same trips."""

    def test_gz_same_summary(self, run: Run, data: Data, tmp_path: Path) -> None:
        """A gzip'd copy of a candump log gives the same summary (but for the file name)."""
        gz = tmp_path / "spike.log.gz"
        gz.write_bytes(gzip.compress(data["spike"].read_bytes()))
        a = summary_of(run, data["spike"], "-c", data["cfg"])
        b = summary_of(run, gz, "-c", data["cfg"])
        assert a.pop("log") != b.pop("log")
        assert a == b

    def test_asc_same_trips(self, run: Run, data: Data, tmp_path: Path) -> None:
        """An ASC log of the same frames (written by python-can) gives the same trips at the same offsets."""
        asc = tmp_path / "spike.asc"
        with can.ASCWriter(asc) as writer:
            for msg in can.CanutilsLogReader(data["spike"]):
                writer.on_message_received(msg)
        a = summary_of(run, data["spike"], "-c", data["cfg"])
        b = summary_of(run, asc, "-c", data["cfg"])
        assert trip_keys(a) == trip_keys(b) and len(a["trips"]) == 1
        assert b["trips"][0]["t"] - b["first_t"] == pytest.approx(a["trips"][0]["t"] - a["first_t"], abs=1e-4)
        assert b["trips"][0]["value"] == a["trips"][0]["value"]
        assert b["samples"] == a["samples"]


class TestJobs:
    """--jobs N replays logs in parallel processes; outputs stay in input order and identical."""

    def test_jobs_2_equals_jobs_1(self, run: Run, data: Data, tmp_path: Path) -> None:
        """--jobs 2 over two logs prints the same JSON list, in input order, as --jobs 1."""
        logs = [data["spike"], data["normal"]]
        one = run(*logs, "-c", data["cfg"], "--json", "--jobs", "1")
        two = run(*logs, "-c", data["cfg"], "--json", "--jobs", "2")
        assert one == two and one[0] == 0
        summaries = json.loads(one[1])
        assert [s["log"] for s in summaries] == [str(p) for p in logs]

    def test_jobs_write_one_events_file_per_log(self, run: Run, data: Data, tmp_path: Path) -> None:
        """With several logs, --events FILE becomes one file per log; files and text identical under --jobs 1 and 2."""
        logs = [data["spike"], data["normal"]]
        contents, texts = [], []
        for jobs in ("1", "2"):
            d = tmp_path / jobs
            d.mkdir()
            code, out, err = run(*logs, "-c", data["cfg"], "--jobs", jobs, "--events", d / "ev.jsonl")
            assert code == 0, err
            files = sorted(p.name for p in d.iterdir())
            assert files == ["ev.normal.log.jsonl", "ev.spike.log.jsonl"]
            contents.append([(d / f).read_bytes() for f in files])
            texts.append((out.replace(str(d), "DIR"), err.replace(str(d), "DIR")))
        assert contents[0] == contents[1]
        assert texts[0] == texts[1] and "spike" in texts[0][0]


class TestPlot:
    """--plot draws the currents, thresholds, I²t levels and stops to .png / .svg / .html."""

    def test_plot_beside_an_export(self, run: Run, data: Data, tmp_path: Path) -> None:
        """--plot and --export-signals together: the figure is drawn and the export keeps every sample."""
        pytest.importorskip("matplotlib")
        pq = pytest.importorskip("pyarrow.parquet")
        png, table = tmp_path / "x.png", tmp_path / "s.parquet"
        code, out, err = run(data["spike"], "-c", data["cfg"], "--plot", png, "--export-signals", table, "--json")
        assert code == 0, err
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert pq.ParquetFile(table).metadata.num_rows == sum(json.loads(out)["samples"].values())

    def test_png(self, run: Run, data: Data, tmp_path: Path) -> None:
        """--plot x.png writes a PNG file."""
        pytest.importorskip("matplotlib")
        png = tmp_path / "x.png"
        code, _, err = run(data["spike"], "-c", data["cfg"], "--plot", png)
        assert code == 0, err
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    def test_html(self, run: Run, data: Data, tmp_path: Path) -> None:
        """--plot x.html writes one HTML page with the SVG inline."""
        pytest.importorskip("matplotlib")
        html = tmp_path / "x.html"
        code, _, err = run(data["spike"], "-c", data["cfg"], "--plot", html)
        assert code == 0, err
        text = html.read_text(encoding="utf-8")
        assert text.lower().startswith("<!doctype html") and "<svg" in text

    def test_unknown_plot_extension(self, run: Run, data: Data, tmp_path: Path) -> None:
        """--plot x.jpg is exit 2 listing the formats."""
        code, _, err = run(data["spike"], "-c", data["cfg"], "--plot", tmp_path / "x.jpg")
        assert code == 2
        assert ".png" in err and ".html" in err
        no_traceback(err)

    def test_without_matplotlib(
        self, run: Run, data: Data, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        """Without matplotlib, --plot is exit 2 saying how to install it."""
        monkeypatch.setitem(sys.modules, "matplotlib", None)
        monkeypatch.setitem(sys.modules, "matplotlib.pyplot", None)
        code, _, err = run(data["spike"], "-c", data["cfg"], "--plot", tmp_path / "x.png")
        assert code == 2
        assert "pip install" in err and "matplotlib" in err


class TestLiveParity:
    """Replay answers what the live daemon did: same trips on the same frames sent over a virtual bus."""

    def test_realtime_matches_offline(self, run: Run, data: Data) -> None:
        """--realtime (the daemon on python-can's virtual bus) trips the same guards as the offline replay."""
        offline = summary_of(run, data["spike"], "-c", data["cfg"])
        code, out, err = run(data["spike"], "-c", data["cfg"], "--realtime", "4", "--json")
        assert code == 0, err
        live = json.loads(out)
        assert live["realtime_speed"] == 4.0
        assert [(t["node"], t["source"]) for t in live["trips"]] == [
            (t["node"], t["source"]) for t in offline["trips"]
        ]
        assert live["trips"][0]["value"] == pytest.approx(offline["trips"][0]["value"])
        assert live["samples"]["/battery_state"] == offline["samples"]["/battery_state"]

    def test_daemon_start_before_first_frame_is_not_a_trip(self, data: Data) -> None:
        """A daemon whose first ticks precede the first frame (as live) counts no trip, like the replay."""
        from canguard.config.loader import load_config
        from canguard.engine.core import Engine
        from canguard.engine.gate import LogSink
        from canguard.io.block import one_block
        from canguard.io.clock import ManualClock
        from canguard.io.logs import read_log

        cfg = load_config(data["cfg"])
        clock = ManualClock(T0 - 0.05)
        engine = Engine(cfg, clock, LogSink(clock.now, cfg.buses))
        engine.start(T0 - 0.05)  # the daemon is up 50 ms before the first frame
        engine.advance(T0 - 0.001)
        for frame in read_log(data["normal"]):
            engine.take("main", one_block(frame))
        assert engine.stats.ticks > 0
        assert engine.stats.trips == []
        assert engine.gate.stops == 0

    def test_realtime_fail_on_trip(self, run: Run, data: Data) -> None:
        """--realtime with --fail-on-trip exits 1 on the spike log, like the offline replay."""
        code, _, err = run(data["spike"], "-c", data["cfg"], "--realtime", "8", "--fail-on-trip")
        assert code == 1, err

    def test_realtime_needs_bus_with_several(self, run: Run, data: Data) -> None:
        """With two buses, --realtime without --bus is exit 2 asking for --bus and listing the buses."""
        code, _, err = run(data["spike"], "-c", data["cfg2"], "--realtime", "8")
        assert code == 2
        assert "--bus" in err and "main" in err and "aux" in err
        assert "None" not in err

    def test_realtime_bad_speed(self, run: Run, data: Data) -> None:
        """--realtime 0 is exit 2 explaining the speed."""
        code, _, err = run(data["spike"], "-c", data["cfg"], "--realtime", "0")
        assert code == 2
        assert "speed" in err



class TestStateFile:
    """--state: the replay starts from saved I²t heat and never writes the file."""

    def test_warm_start_trips_earlier_and_file_is_untouched(self, run: Run, tmp_path: Path) -> None:
        """Axis0's bucket saved at 90 % trips the overload before the cold 3.0 s, and the file keeps its bytes."""
        from canguard.protect.i2t import LeakyI2t
        from canguard.protect.state import HeatStore

        config = REPO / "config" / "examples" / "robot_guard.yaml"
        log = REPO / "examples" / "overload.log.gz"
        t0 = 1_700_000_000.0
        model = LeakyI2t(10.0, 20.0, 1.0)
        step(model, 20.0, t0 - 0.9)
        step(model, 20.0, t0)  # 0.9 s at 20 A: 90 % of the 300 A²s trip level
        state = tmp_path / "i2t_state.json"
        HeatStore(state).save({"Axis0I2t": model}, t0)
        before = state.read_bytes()
        cold = summary_of(run, log, "-c", config)
        warm = summary_of(run, log, "-c", config, "--state", state)
        assert state.read_bytes() == before
        [cold_trip] = cold["trips"]
        [warm_trip] = warm["trips"]
        assert warm_trip["node"] == cold_trip["node"] == "Axis0I2t"
        assert warm_trip["t"] < cold_trip["t"] - 0.2


class TestRealtimeHonoursFlags:
    """--realtime runs the daemon on a copy of the config: replay's own flags, not the config's files."""

    def test_writes_neither_config_events_nor_state(self, run: Run, data: Data, tmp_path: Path) -> None:
        """Without --events / --state the config's events: and state.file stay untouched; --events is used."""
        cfg = make_config(tmp_path / "cfg")
        events = tmp_path / "ev.jsonl"
        code, out, err = run(data["spike"], "-c", cfg, "--realtime", "8", "--json", "--events", events)
        assert code == 0, err
        assert not (tmp_path / "cfg" / "events.jsonl").exists()
        assert not (tmp_path / "cfg" / "i2t_state.json").exists()
        lines = [json.loads(line) for line in events.read_text(encoding="utf-8").splitlines()]
        assert any(e["event"] == "trip" for e in lines)
        assert json.loads(out)["frames_sent"] > 0

    def test_state_is_only_read(self, run: Run, tmp_path: Path) -> None:
        """--state FILE is read, never written; the config's own state.file (I²t guards) is not written either."""
        from canguard.protect.i2t import LeakyI2t
        from canguard.protect.state import HeatStore

        example = REPO / "config" / "examples" / "robot_guard.yaml"
        doc = yaml.safe_load(example.read_text(encoding="utf-8"))
        doc["dbc"] = [str((example.parent / f).resolve()) for f in doc["dbc"]]
        doc["tree"]["file"] = str((example.parent / doc["tree"]["file"]).resolve())
        doc["events"] = str(tmp_path / "cfg_events.jsonl")
        doc["state"]["file"] = str(tmp_path / "cfg_state.json")
        cfg = tmp_path / "robot_guard.yaml"
        cfg.write_text(yaml.safe_dump(doc), encoding="utf-8")
        state = tmp_path / "saved_state.json"
        model = LeakyI2t(10.0, 20.0, 1.0)
        step(model, 20.0, T0)
        HeatStore(state).save({"Axis0I2t": model}, T0)
        before = state.read_bytes()
        code, _, err = run(REPO / "examples" / "overload.log.gz", "-c", cfg, "--realtime", "8", "--state", state)
        assert code == 0, err
        assert state.read_bytes() == before
        assert not (tmp_path / "cfg_state.json").exists()
        assert not (tmp_path / "cfg_events.jsonl").exists()

    def test_emit_records_the_frames_sent(self, run: Run, data: Data, tmp_path: Path) -> None:
        """--realtime --emit writes every frame the daemon sent, as a candump -L log python-can reads."""
        emit = tmp_path / "emit.log"
        code, out, err = run(data["spike"], "-c", data["cfg"], "--realtime", "8", "--json", "--emit", emit)
        assert code == 0, err
        s = json.loads(out)
        msgs = list(can.CanutilsLogReader(emit))
        assert s["frames_sent"] > 0 and len(msgs) == s["frames_sent"]
        db = _db()
        estop = {db.get_message_by_name(f"Axis{n}_Estop").frame_id for n in range(4)}
        assert estop & {m.arbitration_id for m in msgs}

    @pytest.mark.parametrize("flag", [["--plot", "x.png"], ["--baseline", "b.json"], ["--jobs", "2"],
                                      ["--map", "can0=main"]])
    def test_refuses_flags_it_cannot_honour(self, run: Run, data: Data, tmp_path: Path, flag: list[str]) -> None:
        """--plot, --baseline, --jobs > 1 and --map with --realtime are exit 2 naming the flag, before any run."""
        args = [tmp_path / a if a.endswith((".png", ".json")) else a for a in flag]
        code, out, err = run(data["spike"], data["normal"], "-c", data["cfg"], "--realtime", "8", *args)
        assert code == 2
        assert flag[0] in err and "--realtime" in err
        assert out == ""
        no_traceback(err)


class TestEmitStreams:
    """--emit writes each frame as it is sent: memory stays flat in the log's length."""

    def test_frames_are_not_kept_in_memory(
        self, run: Run, data: Data, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        """The replay's LogSink keeps no frame, and the file still has every frame counted in frames_sent."""
        import canguard.cli.replay as replay_cmd
        from canguard.engine.gate import LogSink

        sinks: list[LogSink] = []

        class Spy(LogSink):
            def __init__(self, *a: Any, **kw: Any) -> None:
                super().__init__(*a, **kw)
                sinks.append(self)

        monkeypatch.setattr(replay_cmd, "LogSink", Spy)
        emit = tmp_path / "emit.log"
        s = summary_of(run, data["spike"], "-c", data["cfg"], "--emit", emit)
        [sink] = sinks
        assert sink.frames == [] and sink.origins == []
        assert s["frames_sent"] > 0
        assert len(emit.read_text(encoding="ascii").splitlines()) == s["frames_sent"] == sink.sent

    def test_streamed_lines_equal_write_candump_of_kept_frames(self, run: Run, data: Data, tmp_path: Path) -> None:
        """The streamed --emit file has the bytes write_candump gives for the frames a keeping sink holds."""
        import io

        from canguard.config.loader import load_config
        from canguard.engine.core import Engine
        from canguard.engine.gate import LogSink
        from canguard.io.candump import write_candump
        from canguard.io.clock import ManualClock
        from canguard.io.logs import read_log

        emit = tmp_path / "emit.log"
        code, _, err = run(data["spike"], "-c", data["cfg"], "--emit", emit)
        assert code == 0, err
        cfg = load_config(data["cfg"])
        clock = ManualClock()
        sink = LogSink(clock.now, cfg.buses)
        engine = Engine(cfg, clock, sink, durable=False, save_heat=False)
        engine.run_log(read_log(data["spike"]).chunks(), {"can0": "main"}, "main", {})
        engine.advance(clock.now())
        engine.finish(reason="end of log", stop=False)
        buf = io.StringIO()
        write_candump(sink.frames, buf)
        assert sink.frames and emit.read_bytes() == buf.getvalue().encode("ascii")

    def test_logsink_writes_at_once(self) -> None:
        """LogSink(out=...) writes a candump -L line per frame as it is sent; keep=False keeps none."""
        import io

        from canguard.config.schema import BusConfig, FrameSpec
        from canguard.engine.gate import LogSink

        buf = io.StringIO()
        sink = LogSink(lambda: 12.5, {"main": BusConfig(name="main", kwargs={"channel": "can0"})},
                       out=buf, keep=False)
        spec = FrameSpec(bus="main", arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False, is_fd=False,
                         label="x")
        sink.send([spec, spec], "task")
        assert buf.getvalue() == "(12.500000) can0 123#0102\n" * 2
        assert sink.sent == 2 and sink.frames == []


class TestMergedChannels:
    """With one bus, the fallback still takes any single channel, but merging several is reported."""

    @pytest.fixture(scope="class")
    @classmethod
    def two_channels(cls, tmp_path_factory: pytest.TempPathFactory) -> Path:
        """A log with BMS frames on can0 and on can1 (can1 is what the only bus would merge in)."""
        log = tmp_path_factory.mktemp("merged") / "two.log"
        lines = [bms_line(100.0 + i / 50, 10.0, "can0" if i % 3 else "can1") for i in range(30)]
        log.write_text("\n".join(lines) + "\n", encoding="ascii")
        return log

    def test_counted_per_channel_and_warned(self, run: Run, data: Data, two_channels: Path) -> None:
        """can0 (the bus's channel) and can1 (the fallback) are counted per channel and named in a warning."""
        s = summary_of(run, two_channels, "-c", data["cfg"])
        assert s["merged_channels"] == {"can0": 20, "can1": 10}
        assert s["merged_into"] == "main"
        code, out, _ = run(two_channels, "-c", data["cfg"])
        assert code == 0
        [line] = [ln for ln in out.splitlines() if "merged into" in ln]
        assert "warning" in line and "can0 (20)" in line and "can1 (10)" in line
        assert "bus main" in line and "--map" in line

    def test_single_channel_needs_no_map_and_no_warning(self, run: Run, data: Data, tmp_path: Path) -> None:
        """A log on one channel of any name goes to the only bus with no merge reported."""
        log = tmp_path / "robot0.log"
        log.write_text("".join(bms_line(100.0 + i / 50, 10.0, "robot0") + "\n" for i in range(10)),
                       encoding="ascii")
        s = summary_of(run, log, "-c", data["cfg"])
        assert "merged_channels" not in s and "merged_into" not in s
        assert s["samples"]["/battery_state"] >= 10
        _, out, _ = run(log, "-c", data["cfg"])
        assert "merged into" not in out

    def test_map_chooses(self, run: Run, data: Data, two_channels: Path) -> None:
        """--map can0=main routes explicitly: can1 is left unmapped (and counted), nothing is merged."""
        s = summary_of(run, two_channels, "-c", data["cfg"], "--map", "can0=main")
        assert "merged_channels" not in s
        assert s["unmapped_channels"] == {"can1": 10}
