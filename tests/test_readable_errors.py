"""Errors a person can read: run as a user runs canguard (a subprocess, from another directory).

The log-line errors and two config errors run as a separate process; the other ``check`` errors run
through the same entry point in this process (:func:`checked`): the words are the subject there.

A bad line is quoted capped, with its length; an unknown node ID gets the few closest
known IDs and a way to list them all; a file that is not a DBC is named as such, not
echoed; a log read from stdin is called ``-``.
"""

from __future__ import annotations

import difflib
import gzip
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from tests.clikit import cli

from canguard.errors import closest

pytestmark = pytest.mark.slow


def canguard(cwd: Path, *argv: object, stdin: bytes = b"") -> subprocess.CompletedProcess[bytes]:
    """``canguard *argv`` as a separate process started in ``cwd``."""
    return subprocess.run(
        [sys.executable, "-m", "canguard", *map(str, argv)], cwd=cwd, input=stdin, capture_output=True,
        timeout=120, check=False,
    )


def checked(capsys: pytest.CaptureFixture[str], config: Path) -> tuple[int, str]:
    """``canguard check -c config`` in this process: (exit code, stderr)."""
    code, _, err = cli(capsys, "check", "-c", config)
    return code, err


def text_of(proc: subprocess.CompletedProcess[bytes]) -> str:
    """stderr as text (it must be valid UTF-8 whatever the input was)."""
    return proc.stderr.decode("utf-8")


@pytest.fixture
def config(tmp_path: Path, repo: Path) -> Path:
    """The example robot's config and tree, copied into ``tmp_path`` (the DBC stays in the checkout)."""
    text = (repo / "config" / "examples" / "robot_guard.yaml").read_text(encoding="utf-8")
    text = text.replace("../../dbc/robot.dbc", str(repo / "dbc" / "robot.dbc"))
    text = text.replace("../trees/robot_guard.xml", "robot_guard.xml")
    (tmp_path / "robot_guard.xml").write_text(
        (repo / "config" / "trees" / "robot_guard.xml").read_text(encoding="utf-8"), encoding="utf-8"
    )
    path = tmp_path / "robot_guard.yaml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture
def good_lines(repo: Path) -> bytes:
    """The first 50 lines of a good candump log."""
    with gzip.open(repo / "examples" / "normal.log.gz") as f:
        return b"".join(f.readline() for _ in range(50))


class TestBadLogLine:
    """A log line that does not parse is quoted, not dumped."""

    def test_a_100k_line_gives_one_short_error(self, tmp_path: Path, config: Path, good_lines: bytes) -> None:
        """A 100 kB bad line gives an error under 600 characters that says the line's length."""
        bad = b"(1.0) can0 123#" + b"A" * 100_000
        (tmp_path / "long.log").write_bytes(good_lines + bad + b"\n")
        proc = canguard(tmp_path, "replay", "long.log", "-c", config)
        err = text_of(proc)
        assert proc.returncode == 2
        assert "long.log:51: " in err and f"({len(bad)} characters in all)" in err
        assert "'(1.0) can0 123#AAAA" in err and len(err) < 600

    def test_nul_bytes_are_escaped_and_capped(self, tmp_path: Path, config: Path, good_lines: bytes) -> None:
        """A line of NUL bytes shows as a few escapes on one line, with its length, not 33 kB of them."""
        (tmp_path / "nul.log").write_bytes(good_lines + b"\0" * 8000 + b"\n")
        proc = canguard(tmp_path, "replay", "nul.log", "-c", config)
        err = text_of(proc)
        assert proc.returncode == 2
        assert "nul.log:51: " in err and "\\x00\\x00" in err and "(8000 characters in all)" in err
        assert "\0" not in err and len(err) < 600 and len(err.splitlines()) == 2

    def test_stdin_is_named_dash(self, tmp_path: Path, config: Path, good_lines: bytes) -> None:
        """A bad line in a log piped to ``replay -`` is reported at ``-:LINE``, not in a temporary file."""
        proc = canguard(tmp_path, "replay", "-", "--format", "candump", "-c", config,
                        stdin=good_lines + b"(1.0) can0 XYZ\n")
        err = text_of(proc)
        assert proc.returncode == 2
        assert "\n-:51: expected '(secs) channel ID#DATA'" in err and "canguard-replay-" not in err

    def test_stdin_is_named_dash_in_realtime(self, tmp_path: Path, config: Path, good_lines: bytes) -> None:
        """``replay - --realtime`` names the log ``-`` in its summary and in the error of a bad line."""
        good = canguard(tmp_path, "replay", "-", "--format", "candump", "--realtime", "50", "-c", config,
                        stdin=good_lines)
        bad = canguard(tmp_path, "replay", "-", "--format", "candump", "--realtime", "50", "-c", config,
                       stdin=good_lines + b"(1.0) can0 XYZ\n")
        assert good.returncode == 0 and good.stdout.decode().startswith("replay of - with ")
        assert bad.returncode == 2 and "\n-:51: expected '(secs) channel ID#DATA'" in text_of(bad)
        assert "canguard-replay-" not in good.stdout.decode() + text_of(good) + text_of(bad)


class TestUnknownNodeId:
    """A typo in a node ID is answered with the few closest IDs, not all of them."""

    def test_few_closest_and_how_to_list_all(self, tmp_path: Path, config: Path) -> None:
        """``IsCurentSafe`` gets IsCurrentSafe first, at most five IDs, their number and how to list them."""
        tree = tmp_path / "robot_guard.xml"
        tree.write_text(tree.read_text(encoding="utf-8").replace("<IsCurrentSafe", "<IsCurentSafe", 1),
                        encoding="utf-8")
        proc = canguard(tmp_path, "check", "-c", config)
        line = next(x for x in text_of(proc).splitlines() if "unknown node ID" in x)
        assert proc.returncode == 2
        listed = line.split("closest first: ")[1].split(" (")[0].split(", ")
        assert listed[0] == "IsCurrentSafe" and len(listed) <= 5
        assert "in all: `canguard tree --nodes-model FILE` writes every one" in line


class TestNotADbc:
    """A binary file given as a DBC is named as not a DBC, in printable text."""

    def test_binary_dbc(self, tmp_path: Path, config: Path) -> None:
        """Random bytes as robot.dbc: the error names the file, says binary, and stays short and printable."""
        junk = tmp_path / "junk.dbc"
        junk.write_bytes(bytes(range(256)) * 40)
        text = config.read_text(encoding="utf-8")
        config.write_text("dbc: [junk.dbc]\n" + text.split("\n", 4)[4], encoding="utf-8")
        proc = canguard(tmp_path, "check", "-c", config)
        err = text_of(proc)
        assert proc.returncode == 2
        line = next(x for x in err.splitlines() if "junk.dbc" in x)
        assert f"{junk} which is not a DBC file: binary data, not text" in line
        # short whatever the test's own directory: the paths are the user's, the rest is canguard's
        assert line.isprintable() and len(line.replace(str(tmp_path), "")) < 220

    def test_text_with_a_huge_bad_line(self, config: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """A text DBC with a 50 kB bad line gives the parser's complaint capped, with its length."""
        (config.parent / "junk.dbc").write_text('VERSION ""\nBO_ x' + "Z" * 50_000 + "\n", encoding="utf-8")
        text = config.read_text(encoding="utf-8")
        config.write_text("dbc: [junk.dbc]\n" + text.split("\n", 4)[4], encoding="utf-8")
        code, err = checked(capsys, config)
        line = next(x for x in err.splitlines() if "junk.dbc" in x)
        assert code == 2
        assert "which does not load (" in line and "characters in all)" in line and len(line) < 400


class TestBadConfigValue:
    """A config value that is wrong is quoted capped too."""

    def test_a_100k_value(self, config: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """A 100 kB bus interface name gives one short error line naming the file, line and key."""
        text = config.read_text(encoding="utf-8").replace("interface: virtual", "interface: " + "v" * 100_000)
        config.write_text(text, encoding="utf-8")
        code, err = checked(capsys, config)
        line = next(x for x in err.splitlines() if "buses.main.interface" in x)
        assert code == 2
        assert line.startswith(f"{config}:7: buses.main.interface: found 'vvvv")
        assert "(100000 characters in all)" in line and len(line) < 500


class TestBadTreeValue:
    """A tree's attribute that is wrong is quoted capped too."""

    @pytest.mark.parametrize("attr", ['overcurrent_threshold="35.0"', 'topic_name="/battery_state"'])
    def test_a_100k_attribute(self, tmp_path: Path, config: Path, attr: str,
                              capsys: pytest.CaptureFixture[str]) -> None:
        """A 100 kB port value (a number, a source name) gives one short error naming the file, line and port."""
        tree = tmp_path / "robot_guard.xml"
        name = attr.split("=")[0]
        tree.write_text(tree.read_text(encoding="utf-8").replace(attr, f'{name}="{"9/" * 50_000}"', 1),
                        encoding="utf-8")
        code, err = checked(capsys, config)
        line = next(x for x in err.splitlines() if f"port {name}" in x)
        assert code == 2
        assert line.startswith(f"{tree}:15: ") and "(100000 characters in all)" in line and len(line) < 500


@given(word=st.text("abcdeXY_", max_size=40), names=st.lists(st.text("abcdeXY_", min_size=1, max_size=12), max_size=8),
       cutoff=st.sampled_from([0.0, 0.5, 0.8]), spread=st.sampled_from([0.05, 1.0]))
def test_closest_names_are_the_ones_a_full_comparison_gives(word: str, names: list[str], cutoff: float,
                                                             spread: float) -> None:
    """The suggestions for a wrong name skip the names that cannot be close and are still the full comparison's."""
    scored = sorted((-difflib.SequenceMatcher(None, word.lower(), n.lower()).ratio(), n) for n in set(names))
    best = -scored[0][0] if scored else 0.0
    want = [n for r, n in scored[:5] if -r >= cutoff and -r >= best - spread]
    assert closest(word, names, cutoff=cutoff, spread=spread) == want
