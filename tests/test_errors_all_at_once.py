"""Every error at once: one ``canguard check`` lists every mistake of a config,
its DBC files and its tree, each as ``file:line: key: what was expected``, then exits 2.

In-process through :func:`canguard.cli.main.main`; every file is written under ``tmp_path``.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from canguard.cli.main import main
from canguard.config.loader import load_config_text
from canguard.errors import MAX_SHOWN, ConfigError, TreeError, render_problems
from checkout import REPO

DBC = REPO / "dbc" / "robot.dbc"

GOOD_TREE = """\
<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <ReactiveSequence>
      <IsCurrentSafe topic_name="/battery_state"/>
      <ExecuteTask/>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""

# Five independent mistakes, one per line 4..8.
FIVE_MISTAKES_TREE = """\
<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <ReactiveSequence>
      <IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="abc"/>
      <IsCurrentNormal max_current="30"/>
      <IsCurrentNormal topic_name="/nowhere"/>
      <IsCurrentSafe topic_name="axis0" max_curent="3"/>
      <IsCurentSafe topic_name="axis0"/>
      <ExecuteTask/>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""


def config_text(dbc: str = f"[{DBC}]", tree: str = "tree.xml", extra: str = "") -> str:
    """A valid config (robot DBC, one virtual bus, a battery and a current source, a tree) + ``extra``."""
    return f"""\
dbc: {dbc}
buses:
  main: {{interface: virtual, channel: can0}}
sources:
  /battery_state: {{kind: battery, message: BMS_Status, current: Pack_Current, present: Present}}
  axis0: {{kind: current, message: Axis0_Get_Iq, signal: Iq_Measured}}
tree: {{file: {tree}}}
{extra}"""


def write(tmp_path: Path, config: str, tree: str = GOOD_TREE) -> Path:
    (tmp_path / "tree.xml").write_text(tree, encoding="utf-8")
    path = tmp_path / "canguard.yaml"
    path.write_text(config, encoding="utf-8")
    return path


def cli(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    """``canguard *argv`` in-process: (exit code, stdout, stderr)."""
    capsys.readouterr()
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def error_lines(err: str) -> list[str]:
    """The problem lines of stderr (without the ``canguard CMD: N errors:`` header)."""
    return [line for line in err.splitlines() if not line.startswith("canguard ")]


class TestConfigErrorsAtOnce:
    """A config's mistakes are all listed by one run, each with the line of its key."""

    def test_five_mistakes_in_five_sections(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """Five mistakes in buses, sources, task, stop and state: one run prints all five with lines, exit 2."""
        text = """\
dbc: [DBC]
buses:
  main: {interface: virtal, channel: can0}
sources:
  axis0: {kind: current, message: Axis0_Get_Iq, signal: Iq_Measurd}
task:
  period: fast
stop:
  frames:
    - {message: Axis0_Estp}
state:
  on_corrupt: warm
""".replace("DBC", str(DBC))
        path = write(tmp_path, text)
        code, out, err = cli(capsys, "check", "-c", path)
        assert code == 2
        assert out == ""
        assert err.startswith("canguard check: 5 errors:\n")
        assert error_lines(err) == [
            f"{path}:3: buses.main.interface: found 'virtal', expected a python-can interface; closest: virtual",
            f"{path}:5: sources.axis0.signal: found 'Iq_Measurd', expected a signal of Axis0_Get_Iq; "
            "closest: Iq_Measured",
            f"{path}:7: task.period: found 'fast', expected a number > 0 in seconds",
            f"{path}:10: stop.frames[0].message: found 'Axis0_Estp', expected a DBC message name or frame id; "
            "closest: Axis0_Estop, Axis1_Estop, Axis2_Estop",
            f"{path}:12: state.on_corrupt: found 'warm', expected hot or cold",
        ]
        assert "Traceback" not in err

    def test_missing_key_is_located_at_its_parent(self, tmp_path: Path) -> None:
        """A required key that is left out is reported at the line of the mapping that lacks it."""
        text = config_text(extra="stop:\n  confirm: {source: axis0, below: 1}\n")
        write(tmp_path, text)
        with pytest.raises(ConfigError) as info:
            load_config_text(text, tmp_path / "c.yaml")
        assert info.value.located == [
            f"{tmp_path / 'c.yaml'}:9: stop.confirm.deadline: found nothing, expected a value (required key)"
        ]

    def test_dbc_problem_and_config_problem_in_one_run(
        self, capsys: pytest.CaptureFixture[str], tmp_path: Path
    ) -> None:
        """A DBC that does not parse and an independent config mistake are both reported by one check."""
        broken = tmp_path / "broken.dbc"
        broken.write_text('VERSION ""\nBO_ 1 X: 8 Y\nBO_ zz\n', encoding="utf-8")
        text = config_text(dbc=f"[{DBC}, {broken}]", extra="task: {period: -1}\n")
        path = write(tmp_path, text.replace("interface: virtual", "interface: virtul"))
        code, _, err = cli(capsys, "check", "-c", path)
        assert code == 2
        lines = error_lines(err)
        assert len(lines) == 3, err
        assert lines[0].startswith(f"{path}:1: dbc[1]: found {broken} which does not load")
        assert lines[1].startswith(f"{path}:3: buses.main.interface: found 'virtul'")
        assert lines[2] == f"{path}:8: task.period: found -1, expected a number > 0 in seconds"

    def test_one_mistake_keeps_its_message(self, tmp_path: Path) -> None:
        """One mistake: ``problems`` is the message it always was; str() adds only the line."""
        path = write(tmp_path, config_text(extra="task: {period: fast}\n"))
        with pytest.raises(ConfigError) as info:
            load_config_text(config_text(extra="task: {period: fast}\n"), path)
        assert info.value.problems == [f"{path}: task.period: found 'fast', expected a number > 0 in seconds"]
        assert str(info.value) == f"{path}:8: task.period: found 'fast', expected a number > 0 in seconds"

    def test_list_is_capped(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """150 mistakes print the first 100, then '... and 50 more'."""
        bad = "".join(f"    bogus{i}: 1\n" for i in range(150))
        path = write(tmp_path, config_text(extra=f"state:\n{bad}"))
        code, _, err = cli(capsys, "check", "-c", path)
        assert code == 2
        assert err.startswith("canguard check: 150 errors:\n")
        lines = error_lines(err)
        assert len(lines) == MAX_SHOWN + 1
        assert lines[0].startswith(f"{path}:9: state.bogus0: found unknown key 'bogus0'")
        assert lines[-2].startswith(f"{path}:108: state.bogus99: ")
        assert lines[-1] == "... and 50 more"
        assert render_problems(["a", "b"], limit=2) == "a\nb"


class TestTreeErrorsAtOnce:
    """A tree's mistakes are all listed by one run, each with its XML line."""

    def test_five_mistakes_in_one_tree(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """Bad number, missing port, unknown source, unknown port, unknown node: all five, lines 4..8, exit 2."""
        path = write(tmp_path, config_text(), FIVE_MISTAKES_TREE)
        tree = tmp_path / "tree.xml"
        code, _, err = cli(capsys, "check", "-c", path)
        assert code == 2
        assert err.startswith("canguard check: 5 errors:\n")
        lines = error_lines(err)
        assert [line.split(": ", 1)[0] for line in lines] == [f"{tree}:{n}" for n in (4, 5, 6, 7, 8)]
        assert "port overcurrent_threshold: 'abc' is not a valid float" in lines[0]
        assert "missing required port topic_name" in lines[1]
        assert "port topic_name: unknown source '/nowhere'; configured sources: /battery_state, axis0" in lines[2]
        assert "unknown port 'max_curent'" in lines[3]
        assert "unknown node ID 'IsCurentSafe'" in lines[4] and "closest first: IsCurrentSafe" in lines[4]
        assert "Traceback" not in err

    def test_every_unbindable_node_is_reported(self, tmp_path: Path) -> None:
        """A tree that is well formed but names two unknown sources reports both, not only the first."""
        tree = GOOD_TREE.replace(
            '<IsCurrentSafe topic_name="/battery_state"/>',
            '<IsCurrentSafe topic_name="/bms"/>\n      <IsCurrentNormal topic_name="axis9"/>',
        )
        path = write(tmp_path, config_text(), tree)
        from canguard.bt.checks import check_tree
        from canguard.config.loader import load_config

        with pytest.raises(TreeError) as info:
            check_tree(load_config(path))
        problems = info.value.problems
        assert len(problems) == 2
        assert re.match(rf"{re.escape(str(tmp_path / 'tree.xml'))}:4: .*unknown source '/bms'", problems[0])
        assert re.match(rf"{re.escape(str(tmp_path / 'tree.xml'))}:5: .*unknown source 'axis9'", problems[1])

    def test_broken_subtree_does_not_hide_other_trees(self, tmp_path: Path) -> None:
        """A BehaviorTree with two roots and an unknown node in another tree: both reported."""
        tree = """\
<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence><SubTree ID="Other"/><ExecuteTask/></Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Other">
    <AlwaysSuccess/>
    <AlwaysSuccess/>
  </BehaviorTree>
  <BehaviorTree ID="Third">
    <Nope/>
  </BehaviorTree>
</root>
"""
        path = write(tmp_path, config_text(), tree)
        from canguard.bt.checks import load_config_tree
        from canguard.config.loader import load_config

        with pytest.raises(TreeError) as info:
            load_config_tree(load_config(path))
        xml = tmp_path / "tree.xml"
        assert [p.split(": ", 1)[0] for p in info.value.problems] == [f"{xml}:5", f"{xml}:10"]
        assert "must have exactly one root node, found 2" in info.value.problems[0]
        assert "unknown node ID 'Nope'" in info.value.problems[1]

    def test_config_and_tree_mistakes_in_one_check(
        self, capsys: pytest.CaptureFixture[str], tmp_path: Path
    ) -> None:
        """Config mistakes and tree mistakes come in one check; a source or action the config got wrong
        is not reported again by the tree, an undeclared one is."""
        text = config_text(extra="actions:\n  Park: {frames: [{message: Nope}]}\n").replace(
            "kind: current", "kind: curent"
        )
        tree = GOOD_TREE.replace(
            "<ExecuteTask/>",
            '<IsCurrentNormal topic_name="axis0" max_current="x"/>\n'
            '      <IsCurrentNormal topic_name="/nowhere"/>\n'
            "      <Park/>\n"
            "      <ExecuteTask/>",
        )
        path = write(tmp_path, text, tree)
        code, _, err = cli(capsys, "check", "-c", path)
        assert code == 2
        xml = tmp_path / "tree.xml"
        lines = error_lines(err)
        assert [line.split(": ", 1)[0] for line in lines] == [f"{path}:6", f"{path}:9", f"{xml}:5", f"{xml}:6"]
        assert "sources.axis0.kind: found 'curent'" in lines[0]
        assert "actions.Park.frames[0].message: found 'Nope'" in lines[1]
        assert "port max_current: 'x' is not a valid float" in lines[2]
        assert "unknown source '/nowhere'" in lines[3]

    @pytest.mark.parametrize("command", ["tree", "replay"])
    def test_other_commands_print_every_tree_error(
        self, capsys: pytest.CaptureFixture[str], tmp_path: Path, command: str
    ) -> None:
        """``canguard tree`` and ``canguard replay`` list the same five tree errors and exit 2."""
        path = write(tmp_path, config_text(), FIVE_MISTAKES_TREE)
        log = tmp_path / "a.log"
        log.write_text("(0.000000) can0 123#00\n", encoding="utf-8")
        argv = ["tree", "-c", path] if command == "tree" else ["replay", str(log), "-c", path]
        code, _, err = cli(capsys, *argv)
        assert code == 2
        tree = tmp_path / "tree.xml"
        for n in (4, 5, 6, 7, 8):
            assert f"{tree}:{n}: " in err, (n, err)
        assert "Traceback" not in err
