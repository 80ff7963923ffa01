"""``canguard replay``'s start-up: the config is read once, and nothing the run does not use is imported."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cantools
import pytest

import canguard.cli.replay as replay_cmd
from canguard.cli.main import main
from canguard.config.schema import Config
from canguard.sim import write_log
from checkout import REPO, SRC

BUNDLED = REPO / "config" / "canguard.yaml"
DBC = REPO / "dbc" / "robot.dbc"


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Two short simulator logs (candump -L)."""
    d = tmp_path_factory.mktemp("startup_logs")
    out = []
    for name, seed in (("a", 1), ("b", 2)):
        path = d / f"{name}.log"
        write_log(path, 0.5, db=cantools.database.load_file(DBC), scenarios=["normal"], seed=seed)
        out.append(path)
    return out


@pytest.mark.parametrize("argv", [["a"], ["a", "b"], ["a", "b", "--jobs", "1"], ["a", "--jobs", "4"]],
                         ids=["one-log", "two-logs", "two-logs-jobs-1", "one-log-jobs-4"])
def test_config_is_loaded_once_in_process(
    argv: list[str], logs: list[Path], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Without worker processes, the config (YAML, DBC files) is read and validated once for all logs."""
    calls: list[str] = []
    real = replay_cmd.load_config

    def counting(path: str | Path) -> Config:
        calls.append(str(path))
        return real(path)

    monkeypatch.setattr(replay_cmd, "load_config", counting)
    by_name = {"a": str(logs[0]), "b": str(logs[1])}
    code = main(["replay", *(by_name.get(a, a) for a in argv), "-c", str(BUNDLED), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    summaries = json.loads(out)
    assert len(summaries if isinstance(summaries, list) else [summaries]) == sum(a in by_name for a in argv)
    assert calls == [str(BUNDLED)]


def replay_loads(log: Path, modules: tuple[str, ...]) -> str:
    """``LOADED <exit code> <those of modules a replay of log imported>`` from a fresh interpreter."""
    probe = (
        "import sys\n"
        "from canguard.cli.main import main\n"
        f"code = main(['replay', {str(log)!r}, '-c', {str(BUNDLED)!r}, '--json'])\n"
        f"mods = {modules!r}\n"
        "print('LOADED', code, *[m for m in mods if m in sys.modules], file=sys.stderr)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    proc = subprocess.run([sys.executable, "-c", probe], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=60, check=False)
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("LOADED")]
    assert len(lines) == 1, proc.stderr
    return lines[0]


def test_plain_replay_imports_neither_process_pool_nor_matplotlib(logs: list[Path]) -> None:
    """A replay without --jobs N, --plot or --export-signals imports neither a process pool, matplotlib, the
    export writer."""
    modules = ("concurrent.futures.process", "matplotlib", "canguard.report.export")
    assert replay_loads(logs[0], modules) == "LOADED 0"


def test_tree_without_scripts_imports_neither(logs: list[Path]) -> None:
    """The bundled tree has no Script node and no pre/post condition: its replay imports neither the scripting
    language (~5 ms of classes at start-up) nor the node families it does not use (BT.CPP's built-ins: Script,
    Sleep, IfThenElse...)."""
    modules = ("canguard.bt.scripting.script", "canguard.bt.nodes.builtins")
    assert replay_loads(logs[0], modules) == "LOADED 0"


def test_process_exit_keeps_every_output_and_the_exit_code(logs: list[Path], tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """``python -m canguard`` (which skips the interpreter's last collections) writes what ``main`` writes:
    the same stdout, complete event and fleet-summary files, and main's exit code (0, then 2 for a missing log)."""
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    outputs = []
    for how in ("process", "main"):
        d = tmp_path / how
        d.mkdir()
        argv = ["replay", str(logs[0]), str(logs[1]), "-c", str(BUNDLED), "--json",
                "--events", str(d / "ev.jsonl"), "--fleet-summary", str(d / "fleet.jsonl")]
        if how == "process":
            proc = subprocess.run([sys.executable, "-m", "canguard", *argv], cwd=tmp_path, env=env,
                                  capture_output=True, text=True, timeout=60, check=False)
            code, out = proc.returncode, proc.stdout
        else:
            code = main(argv)
            out = capsys.readouterr().out
        assert code == 0
        files = sorted(p.name for p in d.iterdir())
        outputs.append((out, files, [(d / f).read_bytes() for f in files]))
    assert outputs[0] == outputs[1]
    assert len(outputs[0][1]) == 3  # two event journals (one per log) and the fleet summary
    missing = subprocess.run([sys.executable, "-m", "canguard", "replay", str(tmp_path / "nope.log"),
                              "-c", str(BUNDLED)], env=env, capture_output=True, text=True, timeout=60, check=False)
    assert missing.returncode == 2 and "nope.log" in missing.stderr
