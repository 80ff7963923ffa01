"""CLI conventions python-can / cantools / can-utils users bring with them.

Global options after the subcommand, ``-`` for stdin, a quiet end on a closed pipe,
exit codes in every ``-h``, and a generated shell completion.
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from canguard.cli.common import EXIT_CODES
from canguard.cli.main import build_parser, parse_args
from checkout import REPO
from clikit import cli

ROBOT = REPO / "config" / "examples" / "robot_guard.yaml"
NORMAL = REPO / "examples" / "normal.log.gz"
SUBCOMMANDS = ("run", "check", "tree", "replay", "simulate", "demo", "init", "unit", "completion")




def canguard(*argv: object, stdin: bytes | None = None, cwd: Path | None = None) -> subprocess.CompletedProcess[bytes]:
    """The real console entry (``python -m canguard``) as a child process."""
    env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    return subprocess.run([sys.executable, "-m", "canguard", *map(str, argv)], input=stdin,
                          capture_output=True, timeout=120, env=env, cwd=cwd)


class TestGlobalOptions:
    """-v is accepted before and after the subcommand name, and counts add up."""

    @pytest.mark.parametrize(("argv", "level"), [
        (["-v", "check"], 1), (["check", "-v"], 1), (["check", "-vv"], 2), (["-v", "replay", "x.log", "-v"], 2),
        (["replay", "x.log"], 0),
    ])
    def test_verbose_anywhere(self, argv: list[str], level: int) -> None:
        """The parsed verbosity is the same wherever -v stands."""
        assert parse_args(build_parser(), argv).verbose == level

    def test_check_with_verbose_after_subcommand_runs(self, capsys: pytest.CaptureFixture[str]) -> None:
        """`canguard check -c X -v` exits 0 (it was 'unrecognized arguments: -v', exit 2)."""
        code, out, err = cli(capsys, "check", "-c", ROBOT, "-v")
        assert code == 0, err
        assert "sources" in out


class TestExitCodesInHelp:
    """Every -h ends with the same exit-code table."""

    @pytest.mark.parametrize("command", ["", *SUBCOMMANDS])
    def test_help_lists_every_exit_code(self, capsys: pytest.CaptureFixture[str], command: str) -> None:
        """Each code of EXIT_CODES and its meaning are in the help."""
        code, out, _ = cli(capsys, *([command] if command else []), "-h")
        assert code == 0
        assert "exit codes:" in out
        for number, meaning in EXIT_CODES:
            assert f"{number:<4} {meaning}" in out


class TestStdin:
    """`canguard replay -` reads the log from stdin; --format names its format."""

    def test_stdin_gives_the_file_summary(self, short_log: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """candump -L piped in (plain or gzip) = the same summary as the file, logged as '-'.

        The example's first 600 frames: the spool reads stdin the same way whatever its length, and each
        piped replay is a process of its own."""
        plain = short_log.read_bytes()
        code, out, err = cli(capsys, "replay", short_log, "-c", ROBOT, "--json")  # the file: in-process is enough
        assert code == 0, err
        expected = json.loads(out)
        assert expected["frames"]["decoded"] > 0
        for data in (plain, gzip.compress(plain)):
            piped = canguard("replay", "-", "--format", "candump", "-c", ROBOT, "--json", stdin=data)
            assert piped.returncode == 0, piped.stderr
            got = json.loads(piped.stdout)
            assert got.pop("log") == "-"
            expected_wo_log = {k: v for k, v in expected.items() if k != "log"}
            assert got == expected_wo_log

    def test_stdin_without_format_is_exit_2(self) -> None:
        """A pipe has no suffix to tell the format by: exit 2 asking for --format."""
        proc = canguard("replay", "-", "-c", ROBOT, stdin=b"")
        assert proc.returncode == 2
        assert b"--format" in proc.stderr and b"Traceback" not in proc.stderr

    def test_format_overrides_the_suffix(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """A candump log named .dat replays with --format candump (and fails clearly without)."""
        log = tmp_path / "robot.dat"
        log.write_bytes(gzip.decompress(NORMAL.read_bytes()))
        code, _, err = cli(capsys, "replay", log, "-c", ROBOT)
        assert code == 2 and "unknown log format" in err
        code, out, err = cli(capsys, "replay", log, "-c", ROBOT, "--format", "candump", "--json")
        assert code == 0, err
        summary = json.loads(out)
        assert summary["log"] == str(log)
        assert summary["frames"]["decoded"] > 0


@pytest.fixture(scope="module")
def short_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 600 frames of the normal example (every message of the robot, some of each): a pipe closes as
    early on a short log as on a long one, stdin is spooled alike, and replaying it costs little."""
    path = tmp_path_factory.mktemp("short") / "normal_600.log"
    lines = gzip.decompress(NORMAL.read_bytes()).splitlines(keepends=True)[:600]
    path.write_bytes(b"".join(lines))
    return path


class TestClosedPipe:
    """`canguard replay ... | head` ends quietly."""

    def test_closed_stdout_is_141_without_traceback(self, short_log: Path) -> None:
        """The reader closes the pipe at once: exit 141 (like a SIGPIPE'd tool), nothing on stderr."""
        env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
        proc = subprocess.Popen([sys.executable, "-m", "canguard", "replay", short_log, short_log, "-c", ROBOT,
                                 "--json"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
        assert proc.stdout is not None and proc.stderr is not None
        proc.stdout.close()
        err = proc.stderr.read()
        assert proc.wait(timeout=120) == 141
        assert b"Traceback" not in err and b"BrokenPipe" not in err

    @pytest.mark.skipif(shutil.which("head") is None, reason="needs head(1)")
    def test_pipe_into_head(self, short_log: Path) -> None:
        """Through a shell pipe: head prints the first line, the pipeline's stderr stays clean."""
        logs = f"{short_log} {short_log} {short_log}"
        cmd = (f"{sys.executable} -m canguard replay {logs} -c {ROBOT} --json | head -n 1; "
               "echo \"rc=${PIPESTATUS[0]}\"")
        proc = subprocess.run(["bash", "-c", cmd], capture_output=True, timeout=120,
                              env={**os.environ, "PYTHONPATH": str(REPO / "src")})
        assert proc.stdout.startswith(b"[")
        assert proc.stdout.strip().endswith((b"rc=0", b"rc=141"))
        assert b"Traceback" not in proc.stderr


@pytest.fixture(scope="module")
def script() -> str:
    """The generated bash completion script."""
    proc = canguard("completion", "bash")
    assert proc.returncode == 0
    return proc.stdout.decode()


class TestCompletion:
    """`canguard completion bash` completes subcommands, options and choices."""

    def complete(self, script: str, *words: str) -> list[str]:
        """COMPREPLY for the command line ``words`` (the last is being completed)."""
        line = " ".join(f"'{w}'" for w in words)
        prog = (f"{script}\nCOMP_WORDS=({line}); COMP_CWORD={len(words) - 1}; _canguard; "
                'printf "%s\\n" "${COMPREPLY[@]}"')
        proc = subprocess.run(["bash", "-c", prog], capture_output=True, text=True, timeout=30)
        assert proc.returncode == 0, proc.stderr
        return [w for w in proc.stdout.splitlines() if w]

    @pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
    def test_bash(self, script: str) -> None:
        """re -> replay; replay --fail -> both gates; replay --format is an option; completion z -> zsh."""
        assert self.complete(script, "canguard", "re") == ["replay"]
        assert self.complete(script, "canguard", "-v", "replay", "--fail") == ["--fail-on-regression", "--fail-on-trip"]
        assert self.complete(script, "canguard", "replay", "--margin") == ["--margin-tolerance"]
        assert "--format" in self.complete(script, "canguard", "replay", "--")
        assert self.complete(script, "canguard", "completion", "z") == ["zsh"]

    def test_zsh_loads_the_bash_function(self, capsys: pytest.CaptureFixture[str]) -> None:
        """zsh's script goes through bashcompinit and registers the same function."""
        code, out, _ = cli(capsys, "completion", "zsh")  # the bash script above comes from a real process
        assert code == 0
        assert "bashcompinit" in out and "complete -o filenames -F _canguard canguard" in out
