"""canguard never guards nothing silently.

- ``canguard run`` under systemd (``NOTIFY_SOCKET`` set) refuses a config whose buses are
  all ``virtual`` unless the config says ``simulation: true``; STATUS= names what is guarded.
- ``canguard replay`` of a log that gave a configured source no sample says so on stderr
  and in the summary, and ``--fail-on-trip`` exits 3 for it.
- a state file that cannot be written (run) or read (replay --state) is exit 2 at start-up.
"""

from __future__ import annotations

import gzip
import json
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from canguard.config.loader import load_config
from checkout import REPO
from clikit import cli

ROBOT = REPO / "config" / "examples" / "robot_guard.yaml"
NORMAL = REPO / "examples" / "normal.log.gz"
OVERLOAD = REPO / "examples" / "overload.log.gz"




def robot_config(directory: Path, **changes: object) -> Path:
    """robot_guard.yaml with absolute paths, events and state in ``directory``, plus ``changes``."""
    doc = yaml.safe_load(ROBOT.read_text(encoding="utf-8"))
    doc["dbc"] = [str((ROBOT.parent / d).resolve()) for d in doc["dbc"]]
    doc["tree"]["file"] = str((ROBOT.parent / doc["tree"]["file"]).resolve())
    doc["events"] = str(directory / "events.jsonl")
    doc["state"]["file"] = str(directory / "i2t_state.json")
    doc.update(changes)
    path = directory / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


@pytest.fixture
def notify_socket(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[socket.socket]:
    """A unix datagram socket standing in for systemd's; NOTIFY_SOCKET points at it."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = tmp_path / "notify.sock"
    sock.bind(str(path))
    sock.settimeout(0.2)
    monkeypatch.setenv("NOTIFY_SOCKET", str(path))
    yield sock
    sock.close()


def received(sock: socket.socket) -> list[str]:
    """Every field of every datagram waiting on ``sock``."""
    fields: list[str] = []
    while True:
        try:
            fields.extend(sock.recv(65536).decode().split("\n"))
        except (TimeoutError, BlockingIOError):
            return fields


class TestRunUnderSystemd:
    """The service refuses to look healthy while it guards no real bus."""

    def test_all_virtual_buses_refused_under_systemd(self, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                     notify_socket: socket.socket) -> None:
        """Exit 2 before READY=1, naming the config, the virtual buses and both ways out."""
        cfg = robot_config(tmp_path)
        code, _, err = cli(capsys, "run", "-c", cfg, "--duration", "0.2")
        assert code == 2
        assert str(cfg) in err and "virtual" in err
        assert "simulation: true" in err and "socketcan" in err
        assert "READY=1" not in received(notify_socket)

    def test_simulation_true_runs_and_status_names_the_buses(
        self, tmp_path: Path, capsys: pytest.CaptureFixture[str], notify_socket: socket.socket
    ) -> None:
        """With simulation: true it runs; STATUS= says what it guards and that it is a simulation."""
        cfg = robot_config(tmp_path, simulation=True)
        code, _, err = cli(capsys, "run", "-c", cfg, "--duration", "0.3")
        assert code == 0, err
        fields = received(notify_socket)
        assert "READY=1" in fields
        status = [f for f in fields if f.startswith("STATUS=")]
        assert status, fields
        assert "guarding main (virtual can0)" in status[0]
        assert f"{len(load_config(cfg).sources)} sources" in status[0]
        assert "simulation" in status[0]

    def test_outside_systemd_a_virtual_bus_runs(self, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
        """A terminal run (no NOTIFY_SOCKET) on the virtual bus is a bench: no refusal."""
        monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
        code, _, err = cli(capsys, "run", "-c", robot_config(tmp_path), "--duration", "0.2")
        assert code == 0, err

    def test_simulation_must_be_a_bool(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """simulation: "yes" is a config error with its line, not a truthy string."""
        cfg = robot_config(tmp_path, simulation="yes")
        code, _, err = cli(capsys, "check", "-c", cfg)
        assert code == 2
        line = next(i for i, t in enumerate(cfg.read_text().splitlines(), 1) if t.startswith("simulation:"))
        assert f"{cfg}:{line}: simulation: found 'yes'" in err or f"{cfg}:{line}: simulation:" in err
        assert "true or false" in err


class TestStateFile:
    """A state path that cannot be used is exit 2 at start-up, naming it."""

    def test_run_with_unwritable_state_file(self, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                            monkeypatch: pytest.MonkeyPatch) -> None:
        """state.file below a regular file cannot be created: exit 2 naming state.file and the path."""
        monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
        blocker = tmp_path / "not_a_dir"
        blocker.write_text("x")
        cfg = robot_config(tmp_path)
        doc = yaml.safe_load(cfg.read_text())
        doc["state"]["file"] = str(blocker / "i2t_state.json")
        cfg.write_text(yaml.safe_dump(doc))
        code, _, err = cli(capsys, "run", "-c", cfg, "--duration", "0.2")
        assert code == 2
        assert f"state.file: {blocker / 'i2t_state.json'}: cannot be written" in err

    def test_run_with_state_file_a_directory(self, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                             monkeypatch: pytest.MonkeyPatch) -> None:
        """state.file naming a directory: exit 2 (the heat could never be saved)."""
        monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
        cfg = robot_config(tmp_path)
        doc = yaml.safe_load(cfg.read_text())
        doc["state"]["file"] = str(tmp_path)
        cfg.write_text(yaml.safe_dump(doc))
        code, _, err = cli(capsys, "run", "-c", cfg, "--duration", "0.2")
        assert code == 2
        assert "directory" in err and str(tmp_path) in err

    @pytest.mark.parametrize("kind", ["missing", "directory"])
    def test_replay_state_that_cannot_be_read(self, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              kind: str) -> None:
        """replay --state with a typo'd path is exit 2, not a silent cold start."""
        state = tmp_path / "nope.json" if kind == "missing" else tmp_path
        code, out, err = cli(capsys, "replay", NORMAL, "-c", ROBOT, "--state", state)
        assert code == 2
        assert f"--state {state}: cannot be read" in err
        assert out == ""


SHORT_LINES = 3000
"""The normal example's first 3,000 frames (1.2 s of the robot, every source's frames many times over): what
a log missing a source or on another channel shows does not depend on its length."""


def normal_lines() -> list[str]:
    """The first :data:`SHORT_LINES` lines of normal.log.gz."""
    with gzip.open(NORMAL, "rt", encoding="ascii") as src:
        return [line for _, line in zip(range(SHORT_LINES), src, strict=False)]


def without_source(directory: Path, source: str) -> Path:
    """The normal example's first frames without those of ``source``'s message (as if that driver were unplugged)."""
    cfg = load_config(ROBOT)
    ids = {f"{s.frame_id:08X}" if s.is_extended_id else f"{s.frame_id:03X}" for s in cfg.sources[source].signals}
    out = directory / f"no_{source}.log"
    out.write_text("".join(line for line in normal_lines() if line.split()[2].split("#")[0].upper() not in ids),
                   encoding="ascii")
    return out


class TestReplayThatGuardedNothing:
    """A source with no sample is reported; --fail-on-trip does not pass such a log."""

    def test_missing_source_warned_in_summary_and_exit_3(self, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
        """axis3's frames gone: stderr names the log and axis3, the summary lists it, exit 3."""
        log = without_source(tmp_path, "axis3")
        code, out, err = cli(capsys, "replay", log, "-c", ROBOT, "--json", "--fail-on-trip")
        assert code == 3
        assert json.loads(out)["unguarded_sources"] == ["axis3"]
        assert f"{log}: source 'axis3' got no sample" in err

    def test_without_fail_on_trip_it_is_a_warning(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """Without the gate the replay exits 0, and the text summary carries the warning too."""
        log = without_source(tmp_path, "axis1")
        code, out, err = cli(capsys, "replay", log, "-c", ROBOT)
        assert code == 0
        assert "warning: no sample of axis1" in out
        assert "axis1" in err

    def test_log_on_an_unmapped_channel_guards_nothing(self, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
        """The log's channel (can1) goes to no bus (the map names can7): every source unguarded, exit 3."""
        log = tmp_path / "can1.log"
        log.write_text("".join(normal_lines()).replace(" can0 ", " can1 "), encoding="ascii")
        code, out, _ = cli(capsys, "replay", log, "-c", ROBOT, "--json", "--fail-on-trip", "--map", "can7=main")
        summary = json.loads(out)
        assert code == 3
        assert summary["unguarded_sources"] == sorted(load_config(ROBOT).sources)
        assert summary["frames"]["unmapped"] > 0

    def test_complete_log_passes_and_a_trip_is_still_1(self, capsys: pytest.CaptureFixture[str]) -> None:
        """Every source present: exit 0 (no trip) or 1 (overload trips), unguarded list empty."""
        code, out, _ = cli(capsys, "replay", NORMAL, "-c", ROBOT, "--json", "--fail-on-trip")
        assert (code, json.loads(out)["unguarded_sources"]) == (0, [])
        code, out, _ = cli(capsys, "replay", OVERLOAD, "-c", ROBOT, "--json", "--fail-on-trip")
        assert code == 1
