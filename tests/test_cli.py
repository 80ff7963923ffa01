"""The ``canguard`` command's basics: --version, help on every subcommand, ``check`` and ``tree``.

In-process through :func:`canguard.cli.main.main` with capsys; the real console entry
(``python -m canguard``) runs once, from a directory outside the repo.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

from canguard import __version__
from canguard.cli.main import build_parser, main
from checkout import REPO, SRC

BUNDLED = REPO / "config" / "canguard.yaml"
DBC = REPO / "dbc" / "robot.dbc"
SUBCOMMANDS = ("run", "check", "tree", "replay", "tune", "simulate", "demo", "init", "unit", "completion")
UUID = re.compile(r"[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}", re.IGNORECASE)


def cli(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    """Run ``canguard *argv`` in-process: (exit code, stdout, stderr); argparse's exits become codes."""
    capsys.readouterr()
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    out, err = capsys.readouterr()
    return code, out, err


def broken_config(directory: Path) -> Path:
    """A config with three independent mistakes: a misspelt key, an unknown signal, a period of 0."""
    doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
    doc["dbc"] = [str(DBC)]
    doc["tree"]["file"] = str((BUNDLED.parent / doc["tree"]["file"]).resolve())
    doc["sources"]["/battery_state"]["current"] = "Pack_Curent"
    doc["task"]["period"] = 0
    doc["evnts"] = "x.jsonl"
    path = directory / "broken.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


class TestVersionAndHelp:
    """--version, --help and -h on every subcommand exit 0 and print what they say."""

    def test_version(self, capsys: pytest.CaptureFixture[str]) -> None:
        """--version prints the package version and exits 0."""
        code, out, _ = cli(capsys, "--version")
        assert code == 0
        assert out.strip() == f"canguard {__version__}"

    def test_help_lists_subcommands(self, capsys: pytest.CaptureFixture[str]) -> None:
        """--help exits 0 and names every subcommand."""
        code, out, _ = cli(capsys, "--help")
        assert code == 0
        for name in SUBCOMMANDS:
            assert name in out

    def test_every_subcommand_is_known(self) -> None:
        """The parser has exactly the documented subcommands."""
        parser = build_parser()
        [sub] = [a for a in parser._actions if a.dest == "command"]
        assert set(sub.choices or ()) == set(SUBCOMMANDS)

    @pytest.mark.parametrize("command", SUBCOMMANDS)
    def test_subcommand_help(self, capsys: pytest.CaptureFixture[str], command: str) -> None:
        """-h on each subcommand exits 0 with a usage line naming it."""
        code, out, _ = cli(capsys, command, "-h")
        assert code == 0
        assert out.startswith(f"usage: canguard {command}")

    def test_no_subcommand(self, capsys: pytest.CaptureFixture[str]) -> None:
        """No subcommand prints the help and exits 2."""
        code, out, _ = cli(capsys)
        assert code == 2
        assert "usage: canguard" in out

    def test_unknown_option(self, capsys: pytest.CaptureFixture[str]) -> None:
        """An unknown option is argparse's usage error, exit 2."""
        code, _, err = cli(capsys, "check", "--bogus")
        assert code == 2
        assert "--bogus" in err

    def test_console_entry_outside_repo(self, tmp_path: Path) -> None:
        """``python -m canguard --version`` works from a directory outside the repo."""
        env = {**os.environ, "PYTHONPATH": str(SRC)}
        proc = subprocess.run(
            [sys.executable, "-m", "canguard", "--version"],
            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60, check=False,
        )
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.strip() == f"canguard {__version__}"


class TestCheck:
    """``canguard check`` prints what a config resolves to, or every error with file and key."""

    def test_bundled_config(self, capsys: pytest.CaptureFixture[str]) -> None:
        """The bundled config checks clean: exit 0, sources with their frame ids printed."""
        code, out, err = cli(capsys, "check", "-c", BUNDLED)
        assert code == 0, err
        for source in ("/battery_state", "/joint_states", "axis0", "axis3"):
            assert source in out
        assert "0x18FF50E5" in out  # BMS_Status, extended
        assert "BMS_Status" in out and "Pack_Current" in out
        assert "Traceback" not in err

    def test_bundled_config_is_the_default(self, capsys: pytest.CaptureFixture[str],
                                            monkeypatch: pytest.MonkeyPatch) -> None:
        """With $CANGUARD_CONFIG pointing at the bundled config, check needs no -c."""
        monkeypatch.setenv("CANGUARD_CONFIG", str(BUNDLED))
        code, out, _ = cli(capsys, "check")
        assert code == 0
        assert str(BUNDLED.name) in out

    def test_broken_config_lists_every_error(
        self, capsys: pytest.CaptureFixture[str], tmp_path: Path
    ) -> None:
        """A config with three mistakes exits 2 and prints all three, each with the file, line and key path."""
        path = broken_config(tmp_path)
        code, _, err = cli(capsys, "check", "-c", path)
        assert code == 2
        for key in ("evnts", "sources./battery_state.current", "task.period"):
            assert re.search(rf"{re.escape(str(path))}:\d+: {re.escape(key)}: ", err), (key, err)
        assert "closest: events" in err and "Pack_Current" in err
        assert "Traceback" not in err

    def test_missing_config(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """A config file that does not exist exits 2 naming it."""
        code, _, err = cli(capsys, "check", "-c", tmp_path / "none.yaml")
        assert code == 2
        assert "none.yaml" in err and "Traceback" not in err

    def test_broken_tree(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """A tree that is not well-formed XML exits 2 naming the tree file and line."""
        tree = tmp_path / "bad.xml"
        xml = "<root main_tree_to_execute='M'>\n  <BehaviorTree ID='M'>\n</root>\n"
        tree.write_text(xml, encoding="utf-8")
        doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
        doc["dbc"] = [str(DBC)]
        doc["tree"] = {"file": str(tree), "main": "M", "tick_hz": 100}
        cfg = tmp_path / "cfg.yaml"
        cfg.write_text(yaml.safe_dump(doc), encoding="utf-8")
        code, _, err = cli(capsys, "check", "-c", cfg)
        assert code == 2
        assert f"{tree}:" in err and "Traceback" not in err


class TestTree:
    """``canguard tree`` prints the tree; ``--nodes-model`` writes a Groot2 nodes model."""

    def test_prints_tree_without_uuids(self, capsys: pytest.CaptureFixture[str]) -> None:
        """The bundled tree prints its nodes by readable name and no py_trees uuid."""
        code, out, err = cli(capsys, "tree", "-c", BUNDLED)
        assert code == 0, err
        assert "IsCurrentSafe" in out and "ExecuteTask" in out
        assert not UUID.search(out)
        assert out.index("IsCurrentSafe") < out.index("ExecuteTask")

    def test_nodes_model_is_groot2_xml(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """--nodes-model FILE writes <root><TreeNodesModel> with canguard's nodes and their typed ports."""
        path = tmp_path / "nodes.xml"
        code, out, err = cli(capsys, "tree", "--nodes-model", path)
        assert code == 0, err
        assert str(path) in out
        root = ET.parse(path).getroot()
        assert root.tag == "root"
        [model] = root.findall("TreeNodesModel")
        by_id = {n.get("ID"): n for n in model}
        safe = by_id["IsCurrentSafe"]
        assert safe.tag == "Condition"
        ports = {p.get("name"): p for p in safe.findall("input_port")}
        assert {"topic_name", "overcurrent_threshold", "recovery_threshold"} <= set(ports)
        assert ports["overcurrent_threshold"].get("type") == "double"
        assert by_id["ExecuteTask"].tag == "Action"
        assert not UUID.search(path.read_text(encoding="utf-8"))


class TestSimulateOut:
    """``canguard simulate --out`` writes only what replay reads back under that name."""

    @pytest.mark.parametrize(("name", "says"), [("o.asc", "as asc"), ("o.log.xz", "as candump + xz"),
                                                ("o.blf", "as blf")])
    def test_a_name_replay_would_read_as_another_format_is_refused(self, capsys: pytest.CaptureFixture[str],
                                                                   tmp_path: Path, name: str, says: str) -> None:
        """A candump log under an .asc, .blf or .xz name (replay would find no frames) is exit 2, nothing written."""
        code, _, err = cli(capsys, "simulate", "--duration", "0.1", "--out", tmp_path / name)
        assert code == 2
        assert f"--out {tmp_path / name}: simulate writes candump -L logs" in err and says in err
        assert "Traceback" not in err and not (tmp_path / name).exists()

    def test_a_candump_name_replays_what_was_written(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """A .log.gz is written and replay reads every frame of it."""
        code, out, _ = cli(capsys, "simulate", "--duration", "0.2", "--out", tmp_path / "o.log.gz")
        assert code == 0
        written = int(re.search(r"wrote (\d+) frames", out).group(1))  # type: ignore[union-attr]
        code, out, _ = cli(capsys, "replay", "--json", tmp_path / "o.log.gz")
        assert code in (0, 1) and json.loads(out)["frames"]["read"] == written
