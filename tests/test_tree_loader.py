"""load_tree: BT.CPP v3/v4 spellings, SubTree, names, load-time errors, registry, tools."""

from __future__ import annotations

import importlib.metadata
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any, ClassVar

import py_trees
import pytest

import canguard.bt.checks as display_module
import canguard.bt.loader as tree_module
from canguard.bt.checks import nodes_model_xml, render_dot, render_text
from canguard.bt.loader import build_registry, load_tree
from canguard.bt.nodes import BUILTIN_NODES, CanguardNode, port_info
from canguard.config.schema import ActionConfig
from canguard.errors import TreeError
from treekit import TREES, F, FakeEntryPoint, R, Rig, S, find, xml_tree

UUID = re.compile(r"[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}")

V3 = """<root main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <ReactiveSequence name="guarded">
      <Condition ID="IsCurrentSafe" topic_name="/battery_state" overcurrent_threshold="35.0"
                 recovery_threshold="25.0"/>
      <Decorator ID="Inverter">
        <Condition ID="IsValueAbove" value="{load}" threshold="3"/>
      </Decorator>
      <Control ID="SequenceStar">
        <Action ID="PerformRecovery" output_time="{t}"/>
        <Action ID="ExecuteTask"/>
      </Control>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""

V4 = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <ReactiveSequence name="guarded">
      <IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="35.0" recovery_threshold="25.0"/>
      <Inverter>
        <IsValueAbove value="{load}" threshold="3"/>
      </Inverter>
      <SequenceWithMemory>
        <PerformRecovery output_time="{t}"/>
        <ExecuteTask/>
      </SequenceWithMemory>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""


def shape(node: py_trees.behaviour.Behaviour) -> list[tuple[str, str, int]]:
    """(class, name, depth) of every node in pre-order."""
    out: list[tuple[str, str, int]] = []

    def walk(n: py_trees.behaviour.Behaviour, depth: int) -> None:
        out.append((type(n).__name__, n.name, depth))
        for c in n.children:
            walk(c, depth + 1)

    walk(node, 0)
    return out


def load_error(tmp_path: Path, xml: str, rig: Rig | None = None, main: str | None = None) -> str:
    """The TreeError text loading ``xml`` gives."""
    rig = rig or Rig()
    with pytest.raises(TreeError) as info:
        rig.load_text(tmp_path, xml, main)
    text = str(info.value)
    assert "Traceback" not in text and "@" not in text.split(":", 2)[-1].replace("{@", "")
    return text


class TestSpellings:
    """BT.CPP v3 and v4 spellings build the same tree."""

    def test_v3_and_v4_give_the_same_tree(self, tmp_path: Path) -> None:
        """Same classes, names and structure; the text drawing is identical."""
        a = Rig().load_text(tmp_path, V3, name="v3.xml")
        py_trees.blackboard.Blackboard.clear()
        b = Rig().load_text(tmp_path, V4, name="v4.xml")
        assert shape(a.root) == shape(b.root)
        assert render_text(a.root) == render_text(b.root)
        assert (a.format_version, b.format_version) == (3, 4)

    def test_v3_wrappers_in_a_v4_file_and_v4_tags_without_format(self, tmp_path: Path) -> None:
        """BT.CPP 4 also reads <Action ID=".."/>; a root without BTCPP_format takes v4 tags."""
        mixed = V4.replace("<PerformRecovery", '<Action ID="PerformRecovery"')
        plain = V4.replace(' BTCPP_format="4"', "")
        a = Rig().load_text(tmp_path, mixed, name="a.xml")
        py_trees.blackboard.Blackboard.clear()
        b = Rig().load_text(tmp_path, plain, name="b.xml")
        assert shape(a.root) == shape(b.root)

    def test_v3_aliases(self, tmp_path: Path) -> None:
        """RetryUntilSuccesful (v3's spelling), SubTreePlus and Parallel thresholds are v3 names too."""
        xml = """<root main_tree_to_execute="A">
          <BehaviorTree ID="A">
            <Parallel success_threshold="1" failure_threshold="2">
              <Decorator ID="RetryUntilSuccesful" num_attempts="2">
                <Action ID="PerformDiagnostics"/>
              </Decorator>
              <SubTreePlus ID="B" __autoremap="false"/>
            </Parallel>
          </BehaviorTree>
          <BehaviorTree ID="B"><Action ID="ContinueOperation"/></BehaviorTree>
        </root>"""
        loaded = Rig().load_text(tmp_path, xml)
        kinds = [type(n).__name__ for n in loaded.root.iterate()]
        assert "RetryUntilSuccessful" in kinds
        par = loaded.root
        assert par.thresholds() == (1, 2)  # type: ignore[attr-defined]

    def test_groot_palette_in_the_file_is_ignored(self, tmp_path: Path) -> None:
        """A <TreeNodesModel> saved by Groot next to the trees is informative only."""
        xml = V4.replace("</root>", '<TreeNodesModel><Action ID="Other"/></TreeNodesModel></root>')
        assert Rig().load_text(tmp_path, xml).main_id == "Main"

    def test_equals_shortcut(self, tmp_path: Path) -> None:
        """{=} means the key named like the port (BT.CPP 4)."""
        rig = Rig()
        rig.load_text(
            tmp_path,
            xml_tree(
                '<Sequence><RecordTime output_time="{=}"/>'
                '<IsValueAbove value="{output_time}" threshold="1"/></Sequence>'
            ),
        )
        assert rig.tick() == S
        assert py_trees.blackboard.Blackboard.get("/output_time") == rig.now()


class TestMainAndNames:
    """main_tree_to_execute, names, no uuids."""

    def test_main_argument_overrides_the_attribute(self, tmp_path: Path) -> None:
        """load_tree(main=...) picks another tree of the file."""
        loaded = Rig().load(TREES / "profiling.xml", main="LatencyWarning")
        assert loaded.main_id == "LatencyWarning"

    def test_single_tree_needs_no_main(self, tmp_path: Path) -> None:
        """A file with one tree and no main_tree_to_execute runs that tree."""
        loaded = Rig().load_text(tmp_path, "<root><BehaviorTree ID='Only'><ExecuteTask/></BehaviorTree></root>")
        assert loaded.main_id == "Only"

    def test_several_trees_without_main(self, tmp_path: Path) -> None:
        """Several trees and no main: an error naming them."""
        text = load_error(
            tmp_path,
            "<root><BehaviorTree ID='A'><ExecuteTask/></BehaviorTree>"
            "<BehaviorTree ID='B'><ExecuteTask/></BehaviorTree></root>",
        )
        assert "several BehaviorTrees (A, B)" in text

    def test_unknown_main(self, tmp_path: Path) -> None:
        """An unknown main tree lists the trees, closest first."""
        text = load_error(tmp_path, xml_tree("<ExecuteTask/>", "Protected"), main="Protect")
        assert "no BehaviorTree with ID 'Protect'; trees in the file: Protected" in text

    def test_readable_unique_names_without_uuids(self, tmp_path: Path) -> None:
        """Names are the name attribute or the ID, '#2' for repeats; the drawing has no uuid."""
        rig = Rig()
        loaded = rig.load_text(
            tmp_path,
            xml_tree(
                '<Sequence><IsCurrentNormal topic_name="axis0"/>'
                '<IsCurrentNormal topic_name="/battery_state"/>'
                '<IsCurrentNormal name="battery guard" topic_name="/battery_state"/>'
                "<Sequence><ExecuteTask/></Sequence>"
                "</Sequence>"
            ),
        )
        names = [n.name for n in _preorder(loaded.root)]
        assert names == [
            "Sequence",
            "IsCurrentNormal",
            "IsCurrentNormal#2",
            "battery guard",
            "Sequence#2",
            "ExecuteTask",
        ]
        assert not UUID.search(render_text(loaded.root))
        info = loaded.nodes[find(loaded, "battery guard").id]
        assert (info.node_id, info.line, info.tree) == ("IsCurrentNormal", 3, "T")

    def test_events_name_the_node(self, tmp_path: Path) -> None:
        """Events carry the readable name."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree('<IsCurrentSafe name="pack" topic_name="/battery_state"/>'))
        rig.battery(50.0)
        rig.tick()
        assert rig.events[-1]["node"] == "pack"


def _preorder(node: py_trees.behaviour.Behaviour) -> list[py_trees.behaviour.Behaviour]:
    out = [node]
    for c in node.children:
        out.extend(_preorder(c))
    return out


class TestSubTree:
    """SubTree with port remapping and separate namespaces."""

    XML = """<root BTCPP_format="4" main_tree_to_execute="Main">
      <BehaviorTree ID="Main">
        <Sequence>
          <RecordTime output_time="{start}"/>
          <SubTree ID="Guard" name="Left" topic="axis0" limit="{left_limit}" stamp="{start}"/>
          <SubTree ID="Guard" name="Right" topic="/battery_state" limit="{right_limit}" stamp="{start}"/>
        </Sequence>
      </BehaviorTree>
      <BehaviorTree ID="Guard">
        <Sequence>
          <IsElapsedSinceEvent event_timestamp="{stamp}" max_elapsed_sec="5"/>
          <RecordTime output_time="{local}"/>
          <IsValueAbove value="{local}" threshold="0"/>
          <IsCurrentNormal topic_name="axis0" max_current="{limit}"/>
        </Sequence>
      </BehaviorTree>
    </root>"""

    def test_remapping_and_namespaces(self, tmp_path: Path) -> None:
        """Ports map to the parent's keys; unmapped keys stay inside each instance's namespace."""
        rig = Rig()
        loaded = rig.load_text(tmp_path, self.XML)
        bb = py_trees.blackboard.Blackboard
        bb.set("/left_limit", 10.0)
        bb.set("/right_limit", 30.0)
        rig.feed("axis0", "current", 20.0)
        assert rig.tick() == F  # Left: 20 A > 10 A
        assert bb.get("/start") == rig.now()
        bb.set("/left_limit", 25.0)  # read at the next tick, which judges the latest sample again
        rig.advance(0.1)
        rig.feed("axis0", "current", 20.0)  # judged against 10 A: the trip goes on
        assert rig.tick() == S  # 20 A <= 25 A: recovered at this tick (the trip was reported already)
        rig.advance(0.1)
        rig.feed("axis0", "current", 20.0)
        assert rig.tick() == S
        assert bb.exists("/Left/local") and bb.exists("/Right/local") and not bb.exists("/local")
        names = [n.name for n in loaded.root.iterate()]
        assert "Left/IsCurrentNormal" in names and "Right/IsCurrentNormal" in names

    def test_constant_through_a_subtree_port(self, tmp_path: Path) -> None:
        """A constant given to a SubTree port reaches the node inside as that constant."""
        xml = self.XML.replace('limit="{left_limit}"', 'limit="15"').replace('limit="{right_limit}"', 'limit="50"')
        rig = Rig()
        loaded = rig.load_text(tmp_path, xml)
        assert find(loaded, "Left/IsCurrentNormal").model.max_value == 15.0
        assert find(loaded, "Right/IsCurrentNormal").model.max_value == 50.0

    def test_unnamed_subtrees_get_distinct_namespaces(self, tmp_path: Path) -> None:
        """Two unnamed instances of one tree are Guard and Guard_2."""
        xml = self.XML.replace(' name="Left"', "").replace(' name="Right"', "")
        loaded = Rig().load_text(tmp_path, xml)
        names = [n.name for n in loaded.root.iterate()]
        assert "Guard/RecordTime" in names and "Guard_2/RecordTime" in names


class TestLoadErrors:
    """Every load-time error is a TreeError naming file, line, node and port."""

    def test_unknown_node_lists_known_ids_closest_first(self, tmp_path: Path) -> None:
        """A typo names the file and line, and the few closest known IDs come first, not all of them."""
        text = load_error(tmp_path, xml_tree('\n<Condition ID="IsCurentSafe" topic_name="/battery_state"/>'))
        assert text.startswith(f"{tmp_path / 'tree.xml'}:4: unknown node ID 'IsCurentSafe' (BehaviorTree T)")
        known = text.split("closest first: ")[1].split(" (")[0].split(", ")
        assert known[0] == "IsCurrentSafe" and "IsCurrentNormal" in known
        assert len(known) <= 5 and "ExecuteTask" not in known

    def test_unknown_port_lists_the_ports(self, tmp_path: Path) -> None:
        """An unknown port lists the node's ports, closest first."""
        text = load_error(tmp_path, xml_tree('<IsCurrentSafe topic_name="/battery_state" overcurrent="35"/>'))
        assert (
            ":3: node IsCurrentSafe (BehaviorTree T): unknown port 'overcurrent'; ports of IsCurrentSafe: "
            "overcurrent_threshold, " in text
        )
        assert "recovery_threshold" in text and "inrush_time" in text

    @pytest.mark.parametrize(
        ("body", "expected"),
        [
            (
                '<IsCurrentNormal topic_name="/battery_state" max_current="abc"/>',
                "node IsCurrentNormal (BehaviorTree T), port max_current: 'abc' is not a valid float",
            ),
            (
                '<Repeat num_cycles="1.5"><ExecuteTask/></Repeat>',
                "node Repeat (BehaviorTree T), port num_cycles: '1.5' is not a valid int",
            ),
            (
                '<IsCurrentNormal topic_name="/battery_state" max_current="nan"/>',
                "port max_current: 'nan' is not a number",
            ),
            (
                '<IsElapsedTimeCompare reference_sec="60" operator="GE"/>',
                "node IsElapsedTimeCompare (BehaviorTree T), port operator: unknown value 'GE'; "
                "expected one of GT, LT, GTE, LTE, EQ",
            ),
            (
                '<IsElapsedTimeCompare reference_sec="60" reference="boot"/>',
                "port reference: unknown value 'boot'; expected one of first_tick, tree_start, last_reset, blackboard",
            ),
            (
                '<IsI2tSafe topic_name="axis0" model="cubic" continuous_current="5"/>',
                "port model: unknown value 'cubic'; expected one of leaky, thermal",
            ),
            (
                "<IsCurrentNormal/>",
                "node IsCurrentNormal (BehaviorTree T): missing required port topic_name "
                "(ports of IsCurrentNormal: "
                "topic_name, max_current)",
            ),
            (
                '<IsCurrentNormal topic_name="{src}"/>',
                "port topic_name: takes a constant (it configures the node at load time), not {src}",
            ),
            (
                '<PerformRecovery output_time="12"/>',
                "port output_time: an output port takes a blackboard key like {output_time}, not '12'",
            ),
            ('<ResetTimer timer="12"/>', "port timer: an output port takes a blackboard key"),
            (
                '<IsElapsedTimeCompare reference_sec="1" timer="7"/>',
                "port timer: takes a blackboard key like {timer}",
            ),
            ('<IsValueBelow value="{a" threshold="1"/>', "port value: malformed blackboard reference '{a'"),
            ('<ExecuteTask _skipIf="x =="/>', "_skipIf: script 'x =='"),
            ('<ExecuteTask _onSucess="x := 1"/>', "attribute _onSucess (BT.CPP pre/post-conditions) is not supported"),
            (
                "<Inverter><ExecuteTask/><ExecuteTask/></Inverter>",
                "node Inverter (BehaviorTree T): a decorator takes exactly one child, found 2",
            ),
            ("<ExecuteTask><ExecuteTask/></ExecuteTask>", "action nodes take no children, found 1"),
            ("<Sequence/>", "node Sequence (BehaviorTree T): a control node needs at least one child"),
            ('<Action ID="ExecuteTask" name="x"><x/></Action>'.replace("<x/>", ""), None),
        ],
    )
    def test_port_and_structure_errors(self, tmp_path: Path, body: str, expected: str | None) -> None:
        """Ill-typed constants, unknown choices, missing ports, wrong children: named precisely."""
        if expected is None:
            Rig().load_text(tmp_path, xml_tree(body))
            return
        text = load_error(tmp_path, xml_tree(body))
        assert text.startswith(f"{tmp_path / 'tree.xml'}:3: ")
        assert expected in text

    @pytest.mark.parametrize(
        ("body", "expected"),
        [
            (
                '<IsCurrentNormal topic_name="/nope"/>',
                "node IsCurrentNormal (BehaviorTree T), port topic_name: unknown source '/nope'; "
                "configured sources: /battery_state, /joint_states, axis0",
            ),
            (
                '<IsJointEffortNormal topic_name="/battery_state"/>',
                "port topic_name: source '/battery_state' is of kind 'battery', expected joints",
            ),
            (
                '<IsCurrentSafe topic_name="axis0" overcurrent_threshold="20" recovery_threshold="30"/>',
                "port recovery_threshold: recovery_threshold (30.0 A) must not exceed overcurrent_threshold",
            ),
            (
                '<IsCurrentSafe topic_name="axis0" overcurrent_threshold="-1"/>',
                "port overcurrent_threshold: overcurrent_threshold must be a finite number >= 0",
            ),
            (
                '<IsCurrentSafe topic_name="axis0" inrush_time="0.3"/>',
                "port start_current: required when inrush_time > 0",
            ),
            (
                '<IsI2tSafe topic_name="axis0" continuous_current="5" peak_current="9"/>',
                "port peak_time: required with peak_current",
            ),
            (
                '<IsI2tSafe topic_name="axis0" continuous_current="5" peak_current="4" peak_time="1"/>',
                "port peak_current: peak_current (4.0 A) must exceed continuous_current",
            ),
            (
                '<IsI2tSafe topic_name="axis0" model="thermal" continuous_current="5" k="2"/>',
                "port peak_current: required when k >= 1.5",
            ),
            (
                '<IsElapsedTimeCompare reference_sec="1" reference="blackboard"/>',
                'port timer: required with reference="blackboard"',
            ),
            (
                '<Parallel success_count="3"><ExecuteTask/><ExecuteTask/></Parallel>',
                "port success_count: 3 successes needed but only 2 children: can never succeed",
            ),
        ],
    )
    def test_bind_errors(self, tmp_path: Path, body: str, expected: str) -> None:
        """Values only the node can judge (sources, model parameters) fail at load time too."""
        text = load_error(tmp_path, xml_tree(body))
        assert text.startswith(f"{tmp_path / 'tree.xml'}:3: ")
        assert expected in text

    def test_document_errors(self, tmp_path: Path) -> None:
        """Malformed XML, wrong root, missing file, duplicate trees, bad BTCPP_format."""
        assert ":3: not well-formed XML: mismatched tag" in load_error(
            tmp_path, "<root>\n<BehaviorTree ID='T'>\n</root>"
        )
        assert "the document element is <tree>, expected <root>" in load_error(tmp_path, "<tree/>")
        assert 'BTCPP_format="5" is not supported' in load_error(tmp_path, '<root BTCPP_format="5"/>')
        assert "no <BehaviorTree> in the file" in load_error(tmp_path, "<root/>")
        tree_a = "<BehaviorTree ID='A'><ExecuteTask/></BehaviorTree>"
        dup = f"<root>\n{tree_a}\n{tree_a}</root>"
        assert f":3: BehaviorTree A is defined twice (first at {tmp_path / 'tree.xml'}:2)" in load_error(tmp_path, dup)
        two = "<root><BehaviorTree ID='A'><ExecuteTask/><ExecuteTask/></BehaviorTree></root>"
        assert "BehaviorTree A must have exactly one root node, found 2" in load_error(tmp_path, two)
        with pytest.raises(TreeError, match="cannot read the tree file"):
            load_tree(tmp_path / "missing.xml", Rig().ctx)

    def test_subtree_errors(self, tmp_path: Path) -> None:
        """Unknown SubTree IDs list the trees; cycles are found before py_trees recurses forever."""
        unknown = xml_tree('<SubTree ID="Gaurd"/>').replace(
            "</root>", "<BehaviorTree ID='Guard'><ExecuteTask/></BehaviorTree></root>"
        )
        assert (
            "node SubTree Gaurd (BehaviorTree T): unknown BehaviorTree 'Gaurd'; trees in the file: Guard, T"
            in load_error(tmp_path, unknown)
        )
        cycle = """<root main_tree_to_execute="A">
          <BehaviorTree ID="A"><SubTree ID="B"/></BehaviorTree>
          <BehaviorTree ID="B"><Sequence><ExecuteTask/><SubTree ID="A"/></Sequence></BehaviorTree>
        </root>"""
        assert ":3: node SubTree A (BehaviorTree B): SubTree cycle: A -> B -> A" in load_error(tmp_path, cycle)
        auto = xml_tree('<SubTree ID="T" _autoremap="true"/>')
        assert 'SubTree cycle: T -> T' in load_error(tmp_path, auto)  # an autoremapped SubTree of itself

    def test_errors_in_included_files_name_that_file(self, tmp_path: Path) -> None:
        """<include path=...> inlines trees; their errors name the included file and its lines."""
        (tmp_path / "lib.xml").write_text(
            '<root BTCPP_format="4">\n<BehaviorTree ID="Lib">\n'
            '<IsCurrentNormal topic_name="axis0" max_current="x"/>'
            "\n</BehaviorTree>\n</root>"
        )
        main = (
            '<root BTCPP_format="4" main_tree_to_execute="T"><include path="lib.xml"/>'
            '<BehaviorTree ID="T"><SubTree ID="Lib"/></BehaviorTree></root>'
        )
        text = load_error(tmp_path, main)
        assert text.startswith(f"{tmp_path / 'lib.xml'}:3: node IsCurrentNormal (BehaviorTree Lib), port max_current")

    def test_include_works(self, tmp_path: Path) -> None:
        """An included tree is usable as a SubTree."""
        (tmp_path / "lib.xml").write_text('<root><BehaviorTree ID="Lib"><ExecuteTask/></BehaviorTree></root>')
        rig = Rig()
        rig.load_text(
            tmp_path,
            '<root main_tree_to_execute="T"><include path="lib.xml"/>'
            '<BehaviorTree ID="T"><SubTree ID="Lib"/></BehaviorTree></root>',
        )
        assert rig.tick() == R

    def test_action_clashing_with_a_builtin(self, tmp_path: Path) -> None:
        """An actions: entry named like a built-in node is refused."""
        rig = Rig(actions=("Sequence",))
        assert "actions: 'Sequence' is the ID of a built-in node type" in load_error(
            tmp_path, xml_tree("<ExecuteTask/>"), rig
        )

    def test_parser_errors_become_tree_errors(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """A node constructor that raises inside py_trees' parser gives a TreeError, not a traceback."""
        monkeypatch.setattr(tree_module, "plugin_entry_points", lambda: {"Broken": FakeEntryPoint("Broken", Broken)})
        text = load_error(tmp_path, xml_tree("<Broken/>"))
        assert text.startswith(f"{tmp_path / 'tree.xml'}: BehaviorTree T: ")
        assert "Failed to instantiate 'Broken'" in text and "boom" in text and "(Broken at tree.xml:3)" in text


class Broken(py_trees.ports.PortsMixin, py_trees.behaviour.Behaviour, register=False):
    """A plug-in whose constructor fails."""

    INPUT_PORTS: ClassVar[dict[str, Any]] = {}
    OUTPUT_PORTS: ClassVar[dict[str, Any]] = {}

    def __init__(self, name: str, **kwargs: Any) -> None:
        raise RuntimeError("boom")

    def update(self) -> py_trees.common.Status:
        return S


class Blink(CanguardNode, py_trees.behaviour.Behaviour):
    """A plug-in condition: SUCCESS every other tick."""

    KIND = "Condition"
    INPUT_PORTS: ClassVar[dict[str, Any]] = {"period": port_info(int, "ticks per phase", 1)}
    OUTPUT_PORTS: ClassVar[dict[str, Any]] = {}

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name=name, **kwargs)
        self.n = 0

    def update(self) -> py_trees.common.Status:
        self.n += 1
        return S if self.n % 2 else F


class TestRegistry:
    """The registry is closed, explicit, and extended by entry points lazily."""

    def test_no_global_auto_registration(self) -> None:
        """Importing canguard's nodes leaves py_trees' global ports registry alone."""
        assert not set(BUILTIN_NODES) & set(py_trees.ports.get_ports_registry())

    def test_node_classes_keep_py_trees_port_rules(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """A node class skips py_trees' subclass hook only where it would do nothing: a port both
        input and output is still rejected, and ``register=True`` / ``tag=`` still register."""
        both: ClassVar[dict[str, Any]] = {"x": port_info(int, "x", 1)}
        with pytest.raises(ValueError, match="Port 'x' appears in both input and output ports"):
            type("Twice", (CanguardNode, py_trees.behaviour.Behaviour),
                 {"INPUT_PORTS": both, "OUTPUT_PORTS": both, "update": lambda self: S})
        monkeypatch.setattr(py_trees.ports, "_REGISTRY", {})  # the classes below leave no trace
        ports = {"INPUT_PORTS": {}, "OUTPUT_PORTS": {}, "update": lambda self: S}
        shown = type("CgShown", (CanguardNode, py_trees.behaviour.Behaviour), ports, register=True)
        tagged = type("CgTagged", (CanguardNode, py_trees.behaviour.Behaviour), ports, tag="CgTag", register=True)
        hidden = type("CgHidden", (CanguardNode, py_trees.behaviour.Behaviour), ports)
        registry = py_trees.ports.get_ports_registry()
        assert registry.get("CgShown") is shown and registry.get("CgTag") is tagged
        assert "CgHidden" not in registry and hidden.__mro__[1] is CanguardNode

    def test_registry_contents(self) -> None:
        """Built-ins plus one entry per config action, each bound to the context."""
        rig = Rig(actions=("PerformRecovery",))
        registry = build_registry(rig.ctx)
        assert set(registry) == set(BUILTIN_NODES) | {"PerformRecovery"}
        assert all(p.keywords["context"] is rig.ctx for p in registry.values())
        assert registry["PerformRecovery"].keywords["action"] == ActionConfig(
            "PerformRecovery", rig.ctx.actions["PerformRecovery"].frames
        )

    def test_python_names_are_not_resolved(self, tmp_path: Path) -> None:
        """A dotted Python name in the XML is just an unknown node ID."""
        text = load_error(tmp_path, xml_tree("<py_trees.behaviours.Success/>"))
        assert "unknown node ID 'py_trees.behaviours.Success'" in text

    def test_plugins_load_lazily(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """Entry points are imported only when a tree uses them; built-ins win over plug-ins."""
        calls: list[str] = []
        eps: dict[str, Any] = {
            "Blink": FakeEntryPoint("Blink", Blink, calls),
            "Unused": FakeEntryPoint("Unused", ImportError("not installed"), calls),
            "Sequence": FakeEntryPoint("Sequence", Blink, calls),
        }
        monkeypatch.setattr(tree_module, "plugin_entry_points", lambda: eps)
        rig = Rig()
        rig.load_text(tmp_path, xml_tree('<Sequence><Blink period="2"/></Sequence>'))
        assert calls == ["Blink"]
        assert [rig.tick() for _ in range(3)] == [S, F, S]
        assert type(rig.loaded.root).__module__ == "canguard.bt.nodes.control"  # type: ignore[union-attr]

    def test_broken_plugin_names_itself(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """A plug-in that fails to import, or is not a ports behaviour, is a TreeError naming it."""
        monkeypatch.setattr(
            tree_module,
            "plugin_entry_points",
            lambda: {"X": FakeEntryPoint("X", ImportError("no module named x"))},
        )
        assert "node type X (canguard.nodes entry point tests:X): no module named x" in load_error(
            tmp_path, xml_tree("<X/>")
        )
        monkeypatch.setattr(tree_module, "plugin_entry_points", lambda: {"X": FakeEntryPoint("X", dict)})
        assert "is not a py_trees.ports.PortsMixin + py_trees Behaviour class" in load_error(tmp_path, xml_tree("<X/>"))


    def test_plugin_scan_finds_installed_entry_points(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """An installed distribution's canguard.nodes entry points are found (its other groups are not),
        exactly as importlib.metadata selects them: the quick text search before it misses none."""
        assert tree_module.plugin_entry_points() == {}  # this install has no plug-in
        info = tmp_path / "canguard_fake_plugin-1.0.dist-info"
        info.mkdir()
        (info / "METADATA").write_text("Metadata-Version: 2.1\nName: canguard-fake-plugin\nVersion: 1.0\n")
        (info / "entry_points.txt").write_text(
            "[console_scripts]\nfake = fake_mod:main\n\n[canguard.nodes]\nBlink = fake_mod:Blink\n"
        )
        monkeypatch.syspath_prepend(str(tmp_path))
        found = tree_module.plugin_entry_points()
        assert {name: ep.value for name, ep in found.items()} == {"Blink": "fake_mod:Blink"}
        assert found == {ep.name: ep for ep in importlib.metadata.entry_points(group=tree_module.ENTRY_POINT_GROUP)}


class TestTools:
    """render_text, render_dot, nodes_model_xml."""

    def test_render_text_with_status(self) -> None:
        """The status drawing shows the readable names and each node's status."""
        rig = Rig()
        loaded = rig.load(TREES / "protected_operation.xml")
        rig.tick()
        text = render_text(loaded.root, show_status=True)
        assert "IsCurrentSafe [✕] -- no_data" in text and "ReactiveSequence [✕]" in text

    def test_render_dot(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """.dot always works; .png without Graphviz is a clear error; unknown suffixes are refused."""
        loaded = Rig().load(TREES / "multi_current_monitoring.xml")
        out = render_dot(loaded.root, tmp_path / "t.dot")
        dot = out.read_text()
        assert dot.startswith("digraph") and "IsJointEffortNormal" in dot and not UUID.search(dot)
        monkeypatch.setattr(display_module.shutil, "which", lambda name: None)
        with pytest.raises(TreeError, match=r"needs Graphviz's `dot` program.*a \.dot file works without it"):
            render_dot(loaded.root, tmp_path / "t.png")
        with pytest.raises(TreeError, match=r"unknown drawing format '\.jpg'"):
            render_dot(loaded.root, tmp_path / "t.jpg")

    def test_nodes_model(self) -> None:
        """Every node type with its kind and ports (type, default, description); config actions included."""
        rig = Rig(actions=("PerformRecovery",))
        doc = ET.fromstring(nodes_model_xml(rig.ctx))
        assert doc.tag == "root" and doc.get("BTCPP_format") == "4"
        model = doc.find("TreeNodesModel")
        assert model is not None
        by_id = {e.get("ID"): e for e in model}
        assert set(by_id) == set(BUILTIN_NODES) | {"PerformRecovery"}
        kinds = {i: e.tag for i, e in by_id.items()}
        assert (
            kinds["IsCurrentSafe"],
            kinds["ExecuteTask"],
            kinds["Profile"],
            kinds["ReactiveSequence"],
        ) == ("Condition", "Action", "Decorator", "Control")
        port = by_id["IsCurrentSafe"].find("input_port[@name='overcurrent_threshold']")
        assert port is not None and port.get("type") == "double" and port.get("default") == "35.0"
        assert port.text and "(A)" in port.text
        out = by_id["PerformRecovery"].find("output_port[@name='output_time']")
        assert out is not None and out.get("type") == "double"
        assert by_id["IsElapsedSinceEvent"].find("input_port[@name='max_elapsed_sec']").get("default") == "inf"  # type: ignore[union-attr]


def test_fixture_shape_helper_is_exhaustive() -> None:
    """shape() visits every node (guards the equality test above)."""
    loaded = Rig().load(TREES / "time_windowed_action.xml")
    assert len(shape(loaded.root)) == len(list(loaded.root.iterate()))

