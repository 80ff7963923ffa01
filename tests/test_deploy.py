"""Deploying as docs/deploy.md says: init, the unit for this install, systemd's own checks.

- ``canguard init DIR`` writes a config that loads from any cwd, with SocketCAN and the
  unit's state directory, and never overwrites without --force;
- ``canguard unit`` prints the shipped unit with this install's ExecStart;
- (``systemd-analyze verify`` / ``security`` of the units: tests/test_systemd.py);
- the deploy guide names the unit's own paths (they cannot drift apart again).
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from canguard.config.loader import load_config
from checkout import REPO
from clikit import cli

UNIT = REPO / "systemd" / "canguard.service"
GUIDE = REPO / "docs" / "deploy.md"




def unit_value(text: str, key: str) -> list[str]:
    """Every value of ``key=`` in a unit file."""
    return re.findall(rf"^{key}=(.*)$", text, flags=re.M)


class TestInit:
    """`canguard init DIR`: the starter files of a deployment."""

    def test_writes_a_robot_config_that_loads_from_anywhere(self, tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str],
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
        """SocketCAN on the chosen channel, DBC and tree beside it, events and heat in the state dir."""
        target = tmp_path / "etc" / "canguard"
        code, _, err = cli(capsys, "init", target, "--channel", "can1")
        assert code == 0, err
        assert sorted(p.name for p in target.iterdir()) == ["canguard.yaml", "robot.dbc", "robot_guard.xml"]
        monkeypatch.chdir(tmp_path)  # another cwd: the config's paths are relative to itself
        cfg = load_config(target / "canguard.yaml")
        assert cfg.buses["main"].kwargs == {"interface": "socketcan", "channel": "can1"}
        assert cfg.events == Path("/var/lib/canguard/events.jsonl")
        assert cfg.state.file == Path("/var/lib/canguard/i2t_state.json")
        assert cfg.simulation is False
        assert cfg.tree is not None and cfg.tree.file == target / "robot_guard.xml"
        code, _, err = cli(capsys, "check", "-c", target / "canguard.yaml")
        assert code == 0, err

    def test_simulation_starter_runs_under_systemd(self, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
        """--simulation: virtual bus, 'simulation: true', state in DIR; `run` accepts it with NOTIFY_SOCKET set."""
        code, _, err = cli(capsys, "init", tmp_path, "--simulation")
        assert code == 0, err
        doc = yaml.safe_load((tmp_path / "canguard.yaml").read_text())
        assert doc["simulation"] is True and doc["buses"]["main"]["interface"] == "virtual"
        monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "no-listener.sock"))
        code, _, err = cli(capsys, "run", "-c", tmp_path / "canguard.yaml", "--duration", "0.2")
        assert code == 0, err
        assert (tmp_path / "events.jsonl").exists()

    def test_refuses_to_overwrite_without_force(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """An existing canguard.yaml is kept (exit 2 naming it) unless --force."""
        (tmp_path / "canguard.yaml").write_text("# mine\n")
        code, _, err = cli(capsys, "init", tmp_path)
        assert code == 2
        assert f"{tmp_path / 'canguard.yaml'}" in err and "--force" in err
        assert (tmp_path / "canguard.yaml").read_text() == "# mine\n"
        code, _, err = cli(capsys, "init", tmp_path, "--force")
        assert code == 0, err
        assert "socketcan" in (tmp_path / "canguard.yaml").read_text()


class TestUnit:
    """`canguard unit`: the shipped unit with this install's paths."""

    def test_exec_start_is_this_install(self, capsys: pytest.CaptureFixture[str]) -> None:
        """ExecStart runs an existing canguard (or this interpreter) and its --version works."""
        code, out, _ = cli(capsys, "unit", "--config", "/etc/canguard/robot.yaml")
        assert code == 0
        [exec_start] = unit_value(out, "ExecStart")
        argv = exec_start.split()
        assert argv[-3:] == ["run", "-c", "/etc/canguard/robot.yaml"]
        program = argv[:-3]
        assert Path(program[0]).exists()
        proc = subprocess.run([*program, "--version"], capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0 and proc.stdout.startswith("canguard ")
        shipped = UNIT.read_text()
        assert [line for line in out.splitlines() if not line.startswith("ExecStart=")] == \
            [line for line in shipped.splitlines() if not line.startswith("ExecStart=")]

    def test_channels_and_metrics(self, capsys: pytest.CaptureFixture[str]) -> None:
        """Two channels bind both devices; --metrics adds the flag and loopback IP only."""
        code, out, _ = cli(capsys, "unit", "--channel", "can0", "--channel", "can1", "--metrics", "127.0.0.1:9108")
        assert code == 0
        devices = "sys-subsystem-net-devices-can0.device sys-subsystem-net-devices-can1.device"
        assert unit_value(out, "BindsTo") == [devices]
        assert unit_value(out, "ExecStart")[0].endswith("--metrics 127.0.0.1:9108")
        assert unit_value(out, "IPAddressAllow") == ["localhost"]
        code, _, err = cli(capsys, "unit", "--metrics", "0.0.0.0:9108")
        assert code == 2 and "loopback" in err


class TestGuideMatchesUnit:
    """docs/deploy.md and the shipped files say the same paths."""

    def test_paths(self) -> None:
        """ExecStart's program and config, StateDirectory, ConfigurationDirectory appear in the guide."""
        unit = UNIT.read_text()
        guide = GUIDE.read_text()
        [exec_start] = unit_value(unit, "ExecStart")
        program, _, _, config = exec_start.split()[:4]
        assert program == "/opt/canguard/bin/canguard" and program in guide
        assert f"python3 -m venv {Path(program).parents[1]}" in guide
        assert f"check -c {config}" in guide
        assert unit_value(unit, "StateDirectory") == ["canguard"] and "/var/lib/canguard" in guide
        assert unit_value(unit, "ConfigurationDirectory") == ["canguard"] and f"init {Path(config).parent}" in guide
        for name in ("80-can0.network", "canguard.service", "metrics.conf", "monitor.conf"):
            assert (REPO / "systemd" / name).exists() and f"systemd/{name}" in guide

    def test_metrics_dropin_runs_the_same_program(self) -> None:
        """metrics.conf's ExecStart is the unit's plus --metrics, no `/usr/bin/env canguard`."""
        dropin = (REPO / "systemd" / "metrics.conf").read_text()
        [unit_exec] = unit_value(UNIT.read_text(), "ExecStart")
        assert unit_value(dropin, "ExecStart") == ["", f"{unit_exec} --metrics 127.0.0.1:9108"]
        assert "/usr/bin/env" not in dropin

    def test_init_writes_what_the_guide_promises(self, tmp_path: Path) -> None:
        """The guide's events and state paths are the ones `canguard init` writes."""
        proc = subprocess.run([sys.executable, "-m", "canguard", "init", str(tmp_path)], capture_output=True,
                              text=True, timeout=60, env={"PYTHONPATH": str(REPO / "src"), "PATH": "/usr/bin:/bin"})
        assert proc.returncode == 0, proc.stderr
        text = (tmp_path / "canguard.yaml").read_text()
        guide = GUIDE.read_text()
        for line in ("events: /var/lib/canguard/events.jsonl", "state: {file: /var/lib/canguard/i2t_state.json"):
            assert line in text and line in guide
