"""Start-up: a ``canguard`` command imports what it runs, not every subcommand and library.

The import checks run in a fresh interpreter (a subprocess), so what this test process has
imported does not hide a heavy import coming back; none of them measures a time.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import pytest
from tests.clikit import cli

import canguard
from canguard.cli.common import COMMANDS
from canguard.cli.main import _command_in, build_parser, parse_args
from checkout import REPO, SRC

HEAVY = ("can", "cantools", "yaml", "py_trees", "numpy", "asyncio", "importlib.metadata", "canguard.cli.replay",
         "canguard.sim", "canguard.engine", "canguard.config")

HELP_AND_USAGE = (["--help"], [], ["-v"], ["run", "-h"], ["check", "-h"], ["tree", "-h"])


def loaded_after_each(*steps: str) -> list[list[str]]:
    """The modules of :data:`HEAVY` a fresh interpreter has imported after each of ``steps``, run in turn in it.

    Each list holds what every step so far loaded: a step that must load nothing is run after steps that
    load nothing (their own lists say so), and one fresh interpreter serves several checks.
    """
    probe = "import sys\n"
    for i, code in enumerate(steps):
        probe += (
            "try:\n"
            + "".join(f"    {line}\n" for line in code.splitlines())
            + "except SystemExit:\n    pass\n"
            f"print('LOADED{i}', *[m for m in {HEAVY!r} if m in sys.modules], file=sys.stderr)\n"
        )
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    proc = subprocess.run([sys.executable, "-c", probe], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=60, check=False)
    out = []
    for i in range(len(steps)):
        [line] = [ln for ln in proc.stderr.splitlines() if ln.startswith(f"LOADED{i}")]
        out.append(line.split()[1:])
    return out


def loaded_after(code: str) -> list[str]:
    """The modules of :data:`HEAVY` a fresh interpreter has imported after running ``code``."""
    [loaded] = loaded_after_each(code)
    return loaded


@pytest.fixture(scope="module")
def cli_start() -> list[list[str]]:
    """One fresh interpreter: ``import canguard.cli.main``, then every help and usage call, ``--version``,
    ``replay -h``; what was loaded after each (each check below reads its step)."""
    calls = "".join(f"try:\n    main({argv!r})\nexcept SystemExit:\n    pass\n" for argv in HELP_AND_USAGE)
    return loaded_after_each("import canguard.cli.main", f"from canguard.cli.main import main\n{calls}",
                             "main(['--version'])", "main(['replay', '-h'])")


def test_importing_the_cli_imports_no_library(cli_start: list[list[str]]) -> None:
    """``import canguard.cli.main`` (every command's first step) loads neither python-can nor cantools nor yaml."""
    assert cli_start[0] == []


def test_help_and_usage_import_no_subcommand_module(cli_start: list[list[str]]) -> None:
    """``canguard -h`` lists every subcommand without importing one; run/check/tree -h import nothing heavy.

    One interpreter runs them all: none of them loads anything if their union loads nothing."""
    assert cli_start[1] == []


def test_version_reads_the_metadata_only(cli_start: list[list[str]]) -> None:
    """``canguard --version`` (after the help calls, which load nothing) loads importlib.metadata and nothing else."""
    assert cli_start[2] == ["importlib.metadata"]


def test_replay_help_does_not_import_the_other_subcommands(cli_start: list[list[str]]) -> None:
    """``canguard replay -h`` does not load simulate's module (its scenarios import the simulator)."""
    assert "canguard.sim" not in cli_start[3]


def test_version_is_the_installed_one() -> None:
    try:
        expected = version("canguard")
    except PackageNotFoundError:
        expected = "0.0.0+unknown"
    assert canguard.__version__ == expected
    from canguard import __version__

    assert __version__ == expected
    with pytest.raises(AttributeError):
        _ = canguard.no_such_name


# -- the parser built for one command is the full parser for that command ------------------------------
def _sub(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    raise AssertionError("no subcommands")


def test_every_subcommand_is_listed_in_order() -> None:
    assert list(_sub(build_parser())) == list(COMMANDS)
    for name in COMMANDS:
        assert list(_sub(build_parser(name))) == list(COMMANDS)
    assert build_parser("").format_help() == build_parser().format_help()


@pytest.mark.parametrize("name", list(COMMANDS))
def test_one_command_parser_is_the_full_one_for_it(name: str) -> None:
    """Help, usage and options of the command being run are those of the full parser."""
    full, one = _sub(build_parser())[name], _sub(build_parser(name))[name]
    assert one.format_help() == full.format_help()
    assert [a.option_strings for a in one._actions] == [a.option_strings for a in full._actions]
    assert build_parser(name).format_help() == build_parser().format_help()


@pytest.mark.parametrize("argv", [
    ["replay", "a.log", "b.log", "-c", "x.yaml", "--jobs", "2", "--json"],
    ["-v", "check", "-v", "-c", "x.yaml"],
    ["tree", "t.xml", "--tick", "3"],
    ["simulate", "--out", "x.log", "--scenario", "spike@2"],
    ["init", "/tmp/x"],
])
def test_one_command_parser_parses_as_the_full_one(argv: list[str]) -> None:
    one = vars(parse_args(build_parser(_command_in(argv)), argv))
    full = vars(parse_args(build_parser(), argv))
    assert {k: v for k, v in one.items() if k != "func"} == {k: v for k, v in full.items() if k != "func"}
    assert one["func"] is full["func"]


@pytest.mark.parametrize(("argv", "expected"), [
    ([], ""), (["-h"], ""), (["--version"], ""), (["-v", "-v"], ""),
    (["replay", "x.log"], "replay"), (["-v", "check"], "check"), (["run"], "run"),
    (["completion", "bash"], None),  # prints every subcommand's options: all are built
    (["bogus"], None), (["--", "replay"], None),
])
def test_the_command_is_told_before_parsing(argv: list[str], expected: str | None) -> None:
    assert _command_in(argv) == expected


def test_completion_still_completes_every_subcommand_option(capsys: pytest.CaptureFixture[str]) -> None:
    """``completion bash`` builds every subcommand's parser: each one's options are in the script.

    In-process (the real ``canguard completion bash`` process runs in tests/test_cli_conventions.py)."""
    code, out, err = cli(capsys, "completion", "bash")
    assert code == 0, err
    assert "--fleet-summary" in out and "--nodes-model" in out and "--scenario" in out
    for name in COMMANDS:
        assert f"        {name}) opts=" in out


def test_unknown_command_error_names_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    """An unknown command exits 2 naming every command, in order (the parser built for no one command)."""
    code, _, err = cli(capsys, "bogus")
    assert code == 2
    assert "invalid choice: 'bogus' (choose from " + ", ".join(repr(c) for c in COMMANDS) + ")" in err


def test_candump_replay_imports_no_python_can(tmp_path: Path) -> None:
    """``canguard replay`` of a candump log never loads python-can (nor asyncio, nor pydot): cantools' bus test
    harness and py_trees' display are deferred to first use, and a config's built-in interface names are known
    without python-can (~35 ms of every replay's start; ~0.35 s where asammdf is installed)."""
    log = tmp_path / "short.log"
    log.write_text("(1700000000.000000) can0 009#0000204100000000\n", encoding="ascii")
    config = REPO / "config" / "canguard.yaml"
    run = (f"sys.argv = ['canguard', 'replay', '{log}', '-c', '{config}']\n"
           "from canguard.cli.main import console\nconsole()")
    loaded = loaded_after(run)
    assert "cantools" in loaded and "py_trees" in loaded  # it did replay
    assert "can" not in loaded and "asyncio" not in loaded


def test_a_deferred_module_loads_on_first_use() -> None:
    """What a deferred module holds is there at first use: the module's code runs then, once."""
    probe = (
        "import sys\nfrom canguard.cli.deferred import defer_unused\ndefer_unused()\n"
        "import cantools, py_trees\n"
        "assert 'can' not in sys.modules and 'pydot' not in sys.modules\n"
        "tester = cantools.tester\n"
        "assert tester.Tester.__module__ == 'cantools.tester' and 'can' in sys.modules\n"
        "assert cantools.tester is tester is sys.modules['cantools.tester']\n"
        "from cantools.tester import Tester\nassert Tester is tester.Tester\n"
        "try:\n    tester.no_such_name\nexcept AttributeError as e:\n    print(e)\n"
        "print(py_trees.display.unicode_tree(py_trees.behaviours.Success('ok')).rstrip())\n"
        "assert 'py_trees.demos.action' not in sys.modules\n"  # a deferred package: its submodules come with it
        "assert py_trees.demos.action.Action.__module__ == 'py_trees.demos.action'\n"
    )
    proc = subprocess.run([sys.executable, "-c", probe], env={**os.environ, "PYTHONPATH": str(SRC)},
                          capture_output=True, text=True, timeout=60, check=True)
    assert proc.stdout.splitlines() == ["module 'cantools.tester' has no attribute 'no_such_name'", "--> ok"]
