"""Files canguard writes, where the user stands: a path that cannot be written is one line and exit 2.

The event journal, the I²t state file, ``--events``, ``--emit``, ``simulate --out``: each
is tried before the run (:mod:`canguard.io.outputs`), ``canguard check`` refuses what
``canguard run`` refuses, the bundled config keeps its files in the user's state
directory (not in the installed package), and the deploy guide's trial run works for a
normal user (``--state-dir``). These tests run as root here, and root ignores permission
bits: read-only cases use what refuses root too (a path that is a directory, a path below
a regular file), or run the command as ``nobody`` (when root) instead of chmod.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from tests.clikit import cli

from canguard.cli.main import main
from canguard.io.outputs import output_problem
from checkout import REPO

NORMAL = REPO / "examples" / "normal.log.gz"
ROBOT = REPO / "config" / "examples" / "robot_guard.yaml"
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
NOBODY = 65534


def canguard(exe: Path | str, *args: object, cwd: Path, env: dict[str, str] | None = None,
             **kwargs: Any) -> subprocess.CompletedProcess[str]:
    """``canguard *args`` as a user types it, from ``cwd``."""
    base = {"PATH": "/usr/bin:/bin", "HOME": str(cwd)}
    return subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True, timeout=120, cwd=cwd,
                          env={**base, **(env or {})}, **kwargs)


def bench_config(directory: Path, **changes: Any) -> Path:
    """``canguard init DIR --simulation`` (a virtual bus, events and state in DIR), then ``changes``.

    In-process: init is the setting here, not the subject (the wheel smoke runs the installed ``init``)."""
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["init", str(directory), "--simulation"]) == 0
    path = directory / "canguard.yaml"
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    doc.update(changes)
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def in_process(capsys: pytest.CaptureFixture[str], *args: object) -> subprocess.CompletedProcess[str]:
    """``canguard *args`` through the same entry point in this process, as a finished process would report it."""
    code, out, err = cli(capsys, *args)
    return subprocess.CompletedProcess([str(a) for a in args], code, out, err)


def one_line_error(proc: subprocess.CompletedProcess[str], command: str, *needles: str) -> str:
    """Exit 2, no traceback, and the line of stderr that names the path (returned)."""
    assert proc.returncode == 2, proc.stdout[-1000:] + proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr, proc.stderr
    assert re.match(rf"canguard {command}: (error|\d+ errors):\n", proc.stderr), proc.stderr
    lines = [line for line in proc.stderr.splitlines() if all(n in line for n in needles)]
    assert lines, proc.stderr
    return lines[0]


class TestOutputProblem:
    """What the one check says of a path, tried rather than read from permission bits."""

    def test_a_new_file_leaves_nothing_behind(self, tmp_path: Path) -> None:
        """A writable directory passes, and the probe file made to try it is gone again."""
        assert output_problem(tmp_path / "events.jsonl", beside=True) == ""
        assert list(tmp_path.iterdir()) == []

    def test_a_directory(self, tmp_path: Path) -> None:
        """A path that is a directory is refused, for root too."""
        assert output_problem(tmp_path) == "it is a directory, expected a file path"

    def test_below_a_regular_file(self, tmp_path: Path) -> None:
        """A path whose parent is a file names that file, for root too."""
        (tmp_path / "f").write_text("x")
        why = output_problem(tmp_path / "f" / "deeper" / "x.log", makes_dirs=True)
        assert why == f"{tmp_path / 'f'} is a file, expected a directory"

    def test_a_missing_directory(self, tmp_path: Path) -> None:
        """A missing directory is a problem unless the writer makes it; nothing is created by asking."""
        path = tmp_path / "a" / "b" / "x.log"
        assert output_problem(path) == f"its directory {path.parent} does not exist"
        assert output_problem(path, makes_dirs=True) == ""
        assert list(tmp_path.iterdir()) == []

    def test_an_existing_file_is_left_unchanged(self, tmp_path: Path) -> None:
        """An existing file is opened for appending to try it, never truncated."""
        path = tmp_path / "events.jsonl"
        path.write_text("kept\n")
        assert output_problem(path, beside=True) == ""
        assert path.read_text() == "kept\n"

    def test_a_device_is_writable(self) -> None:
        """/dev/null (as /dev/stdout would be) is taken as writable without writing to it."""
        assert output_problem(Path("/dev/null")) == ""

    @pytest.mark.skipif(IS_ROOT, reason="root ignores permission bits (TestOtherUser runs this as nobody)")
    def test_a_read_only_directory(self, tmp_path: Path) -> None:
        """A directory without write permission is refused, naming whose it is."""
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        try:
            why = output_problem(ro / "x.log")
        finally:
            ro.chmod(0o755)
        assert "cannot be written" in why and "belongs to" in why and "mode 0555" in why


class TestInProcess:
    """What needs no second process: a reload keeps --state-dir; an unforeseen OSError is still one line."""

    def test_a_reload_keeps_the_state_dir(self, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          monkeypatch: pytest.MonkeyPatch) -> None:
        """After SIGHUP's reload the journal and state file are still in --state-dir, not where the config says."""
        from canguard.service.daemon import Daemon

        monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
        assert cli(capsys, "init", tmp_path / "etc", "--simulation")[0] == 0
        trial = tmp_path / "trial"
        daemon = Daemon(tmp_path / "etc" / "canguard.yaml", state_dir=trial)
        try:
            assert daemon.reload()
            assert (daemon.cfg.events, daemon.cfg.state.file) == (trial / "events.jsonl", trial / "i2t_state.json")
        finally:
            daemon.reader.stop()
            daemon.journal.close()
        assert not (tmp_path / "etc" / "events.jsonl").exists()

    def test_an_unforeseen_os_error_is_one_line(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """A file no check tried (tree --nodes-model naming a directory) is exit 2 and one line, no traceback."""
        code, _, err = cli(capsys, "tree", "-c", ROBOT, "--nodes-model", tmp_path)
        assert code == 2
        assert err == f"canguard tree: error: {tmp_path}: Is a directory\n"


FLAGS = [
    ("replay", NORMAL, "-c", ROBOT, "--events"),
    ("replay", NORMAL, "-c", ROBOT, "--emit"),
    ("demo", "--duration", "1", "--events"),
    ("simulate", "--duration", "1", "--out"),
]
BAD_PATHS = {
    "a directory": lambda tmp: tmp,
    "below a regular file": lambda tmp: tmp / "file" / "x.out",
}


@pytest.mark.slow
class TestCommands:
    """Each command that writes a file, given one it cannot write, from the installed wheel."""

    @pytest.fixture
    def where(self, tmp_path: Path) -> Path:
        """The user's working directory, with a regular file in it (``file``)."""
        (tmp_path / "file").write_text("x")
        return tmp_path

    @pytest.mark.parametrize("bad", list(BAD_PATHS))
    def test_run_and_check_refuse_the_same_events_path(self, installed_canguard: Path, where: Path,
                                                       bad: str, capsys: pytest.CaptureFixture[str]) -> None:
        """`run` and `check` both exit 2 with the same line naming events: and the path (check passed before)."""
        target = BAD_PATHS[bad](where)
        cfg = bench_config(where / "etc", events=str(target))
        # each command and each bad path once from the installed wheel, the other pairs in-process
        run_argv, check_argv = ("run", "-c", cfg, "--duration", "0.5"), ("check", "-c", cfg)
        if bad == "a directory":
            run = canguard(installed_canguard, *run_argv, cwd=where)
            check = in_process(capsys, *check_argv)
        else:
            run = in_process(capsys, *run_argv)
            check = canguard(installed_canguard, *check_argv, cwd=where)
        line = one_line_error(run, "run", f"{cfg}: events: {target}: cannot be written")
        assert one_line_error(check, "check", f"{cfg}: events: {target}") == line

    @pytest.mark.parametrize("bad", list(BAD_PATHS))
    def test_check_refuses_a_state_file_run_refuses(self, installed_canguard: Path, where: Path, bad: str,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
        """state.file that cannot be written: `check` exits 2 naming the key, as `run` does at start."""
        target = BAD_PATHS[bad](where)
        cfg = bench_config(where / "etc")
        doc = yaml.safe_load(cfg.read_text())
        doc["state"]["file"] = str(target)
        cfg.write_text(yaml.safe_dump(doc))
        for command, *more in (("check",), ("run", "--duration", "0.5")):
            argv = (command, "-c", cfg, *more)
            # each command and each bad path once from the installed wheel, the other pairs in-process
            installed = (command == "check") == (bad == "a directory")
            proc = canguard(installed_canguard, *argv, cwd=where) if installed else in_process(capsys, *argv)
            one_line_error(proc, command, f"state.file: {target}: cannot be written")

    @pytest.mark.parametrize("bad", list(BAD_PATHS))
    @pytest.mark.parametrize("argv", FLAGS, ids=["replay --events", "replay --emit", "demo --events", "simulate --out"])
    def test_a_flag(self, installed_canguard: Path, where: Path, argv: tuple[object, ...], bad: str,
                    capsys: pytest.CaptureFixture[str]) -> None:
        """The flag and the path in one line, exit 2, before anything ran (no summary on stdout)."""
        target = BAD_PATHS[bad](where)
        # each flag and each bad path from the installed wheel, alternately; the other half in-process
        installed = (FLAGS.index(argv) + list(BAD_PATHS).index(bad)) % 2 == 0
        proc = canguard(installed_canguard, *argv, target, cwd=where) if installed else \
            in_process(capsys, *argv, target)
        line = one_line_error(proc, str(argv[0]), f"{argv[-1]} {target}: cannot be written")
        assert ("is a directory" in line) if bad == "a directory" else (f"{where / 'file'} is a file" in line)
        assert proc.stdout == ""


@pytest.fixture
def shared_dir() -> Iterator[Path]:
    """A directory of root's (mode 0755) that another user can read but not write (tmp_path is 0700)."""
    path = Path(tempfile.mkdtemp(prefix="canguard-other-user-"))
    path.chmod(0o755)
    yield path
    shutil.rmtree(path, ignore_errors=True)


def as_nobody(*args: object, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``canguard *args`` run by user nobody, through util-linux's setpriv (this checkout's canguard)."""
    drop = ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups"]
    return subprocess.run([*drop, sys.executable, "-m", "canguard", *map(str, args)], capture_output=True, text=True,
                          timeout=120, cwd=cwd, env={"PATH": "/usr/bin:/bin", "HOME": str(cwd)})


@pytest.fixture(scope="module")
def nobody_runs_this_checkout() -> None:
    """Skip, saying why, where user nobody cannot run this checkout's canguard (a clone below a 0700 directory,
    such as ``mktemp -d``'s): what these tests check needs another user, not root, to run it."""
    drop = ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups"]
    proc = subprocess.run([*drop, sys.executable, "-c", "import canguard"], capture_output=True, text=True,
                          timeout=60, cwd="/", env={"PATH": "/usr/bin:/bin"})
    if proc.returncode != 0:
        pytest.skip(f"user nobody cannot run this checkout's canguard ({proc.stderr.strip()[-200:]}): "
                    "clone it where other users can read it to run these tests")


@pytest.mark.slow
@pytest.mark.skipif(not IS_ROOT or shutil.which("setpriv") is None,
                    reason="runs commands as user nobody, which needs root and setpriv")
@pytest.mark.usefixtures("nobody_runs_this_checkout")
class TestOtherUser:
    """Permission refusals, as a user they apply to: nobody, against root's files (root would pass them)."""

    def test_a_journal_someone_else_owns(self, shared_dir: Path) -> None:
        """The daemon's error says whose the journal is, its mode, and how to fix it (mv aside or chown)."""
        cfg = bench_config(shared_dir / "etc")
        cfg.chmod(0o644)
        os.chown(cfg.parent, NOBODY, NOBODY)  # nobody's directory; only the journal in it is root's
        journal = shared_dir / "etc" / "events.jsonl"
        journal.write_text('{"t":1}\n')
        journal.chmod(0o640)
        proc = as_nobody("run", "-c", cfg, "--duration", "0.5", cwd=shared_dir)
        line = one_line_error(proc, "run", f"events: {journal}: cannot be written")
        assert f"{journal} belongs to root (mode 0640) and canguard runs as nobody" in line
        assert f"sudo mv {journal} {journal}.old" in line and f"sudo chown nobody {journal}" in line
        assert journal.read_text() == '{"t":1}\n'

    def test_emit_into_a_read_only_directory(self, shared_dir: Path) -> None:
        """--emit into a directory nobody may not write: 'cannot be written', whose it is; not 'no such file'."""
        target = shared_dir / "emitted.log"
        proc = as_nobody("replay", NORMAL, "-c", ROBOT, "--emit", target, cwd=shared_dir)
        line = one_line_error(proc, "replay", f"--emit {target}: cannot be written")
        assert "Permission denied" in line and f"{shared_dir} belongs to root (mode 0755)" in line
        assert "no such file" not in proc.stderr

    def test_the_guides_trial_run(self, shared_dir: Path) -> None:
        """docs/deploy.md step 4 as a normal user: refused without --state-dir, runs with it, root's dir untouched."""
        guide = (REPO / "docs" / "deploy.md").read_text(encoding="utf-8")
        [trial] = re.findall(r"^/opt/canguard/bin/canguard (run -c /etc/canguard/canguard\.yaml .*)$", guide, re.M)
        assert "--state-dir" in trial and "sudo" not in trial
        cfg = bench_config(shared_dir / "etc")
        cfg.chmod(0o644)
        trial_dir = shared_dir / "trial"
        trial_dir.mkdir()
        os.chown(trial_dir, NOBODY, NOBODY)
        argv = trial.replace("/etc/canguard/canguard.yaml", str(cfg)).replace("/tmp/canguard-trial", str(trial_dir))
        argv = argv.replace("--duration 10", "--duration 1").split()
        before = sorted(p.name for p in cfg.parent.iterdir())
        refused = as_nobody(*[a for i, a in enumerate(argv) if a != "--state-dir" and argv[i - 1] != "--state-dir"],
                            cwd=shared_dir)
        one_line_error(refused, "run", "cannot be written", "--state-dir DIR")
        proc = as_nobody(*argv, cwd=shared_dir)
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert f"events {trial_dir / 'events.jsonl'}, I²t state {trial_dir / 'i2t_state.json'}" in proc.stderr
        assert (trial_dir / "events.jsonl").stat().st_size > 0
        assert sorted(p.name for p in cfg.parent.iterdir()) == before


@pytest.mark.slow
class TestBundledConfig:
    """`canguard run` without -c, from the installed wheel: its files go to the user's state directory."""

    @pytest.mark.parametrize("xdg", [True, False], ids=["XDG_STATE_HOME", "~/.local/state"])
    def test_run_without_config_writes_to_the_state_directory(self, installed_canguard: Path, tmp_path: Path,
                                                              xdg: bool) -> None:
        """The journal lands in $XDG_STATE_HOME/canguard (or ~/.local/state/canguard), stderr says so at
        start, and the installed package gains no file."""
        home = tmp_path / "home"
        home.mkdir()
        state = (tmp_path / "xdg" if xdg else home / ".local" / "state") / "canguard"
        env = {"HOME": str(home), **({"XDG_STATE_HOME": str(tmp_path / "xdg")} if xdg else {})}
        package = next(installed_canguard.parents[1].glob("lib/python*/site-packages/canguard"))
        before = sorted(str(p) for p in package.rglob("*") if "__pycache__" not in str(p))
        check = canguard(installed_canguard, "check", cwd=tmp_path, env=env)
        assert check.returncode == 0, check.stderr
        assert f"events: {state / 'events.jsonl'}" in check.stdout
        proc = canguard(installed_canguard, "run", "--duration", "1", cwd=tmp_path, env=env)
        assert proc.returncode == 0, proc.stderr[-2000:]
        first = proc.stderr.splitlines()[0]
        assert first.startswith(f"canguard run: events {state / 'events.jsonl'}, I²t state {state / 'i2t_state.json'}")
        assert "bundled config" in first
        assert (state / "events.jsonl").stat().st_size > 0
        assert sorted(str(p) for p in package.rglob("*") if "__pycache__" not in str(p)) == before
        assert list(tmp_path.glob("*.jsonl")) == []


@pytest.mark.slow
class TestUnitFiles:
    """`canguard unit` gives a wheel user both systemd files, which otherwise sit inside site-packages."""

    def test_network_and_write(self, installed_canguard: Path, tmp_path: Path,
                               capsys: pytest.CaptureFixture[str]) -> None:
        """--network prints the shipped 80-can0.network; --write DIR writes it and the unit `unit` prints.

        `unit` and `--write` from the installed wheel (the files it ships, the unit naming the installed
        command); the --network variants through the same entry point in-process."""
        shipped = (REPO / "systemd" / "80-can0.network").read_text(encoding="utf-8")
        network = in_process(capsys, "unit", "--network")
        assert network.returncode == 0 and network.stdout == shipped
        can1 = in_process(capsys, "unit", "--network", "--channel", "can1")
        assert can1.stdout == shipped.replace("Name=can0\n", "Name=can1\n")
        unit = canguard(installed_canguard, "unit", cwd=tmp_path)
        assert unit.returncode == 0
        assert f"ExecStart={installed_canguard} run -c /etc/canguard/canguard.yaml\n" in unit.stdout
        wrote = canguard(installed_canguard, "unit", "--write", "systemd", cwd=tmp_path)
        assert wrote.returncode == 0, wrote.stderr
        assert (tmp_path / "systemd" / "80-can0.network").read_text() == shipped
        assert (tmp_path / "systemd" / "canguard.service").read_text() == unit.stdout

    def test_the_guide_writes_what_it_installs(self) -> None:
        """The guide and the README write the systemd files before their install lines use them."""
        for doc in (REPO / "docs" / "deploy.md", REPO / "README.md"):
            text = doc.read_text(encoding="utf-8")
            assert text.index("canguard unit --write systemd") < text.index("install -m 0644 systemd/80-can0.network")
