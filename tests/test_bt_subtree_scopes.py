"""SubTree ports are blackboard remappings, as in BT.CPP 4 (gtest_subtree.cpp, xml_parsing.cpp).

``<SubTree ID="S" input="{x}"/>`` makes the subtree's ``input`` the parent's ``x`` for every
reader and writer — ports, scripts, pre/post conditions, SetBlackboard; a literal on the element
is a typed entry of the subtree (an integer, else a real, else a string); ``@key`` is the root's.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from canguard.bt.dryrun import dry_run
from canguard.bt.scopes import typed_literal
from canguard.errors import TreeError

DOUBLER = """
  <BehaviorTree ID="Doubler">
    <Sequence>
      <Script code="output := input * 2 + lit; @seen := txt; local := 1"/>
      <SetBlackboard output_key="@copied" value="{input}"/>
    </Sequence>
  </BehaviorTree>
"""


def tree(tmp_path: Path, main: str, extra: str = DOUBLER) -> Path:
    path = tmp_path / "t.xml"
    path.write_text(f'<root BTCPP_format="4" main_tree_to_execute="M">\n<BehaviorTree ID="M">\n{main}\n'
                    f"</BehaviorTree>{extra}</root>\n", encoding="utf-8")
    return path


class TestRemapping:
    def test_scripts_read_and_write_through_the_remapped_ports(self, tmp_path: Path) -> None:
        """output := input * 2 inside the subtree writes the parent's y from the parent's x; locals stay inside."""
        got = dry_run(tree(tmp_path, '<Sequence><Script code="x := 21"/>'
                                     '<SubTree ID="Doubler" input="{x}" output="{y}" lit="5" txt="abc"/></Sequence>'),
                      1, 0.1)
        assert got == {"ticks": ["SUCCESS"], "blackboard": {"copied": 21, "seen": "abc", "x": 21, "y": 47.0}}

    def test_two_instances_chain_through_the_parent(self, tmp_path: Path) -> None:
        """Each instance has its own scope: B reads what A wrote, each with its own literals."""
        got = dry_run(tree(tmp_path, '<Sequence><Script code="x := 21"/>'
                                     '<SubTree ID="Doubler" name="A" input="{x}" output="{y}" lit="5" txt="a"/>'
                                     '<SubTree ID="Doubler" name="B" input="{y}" output="{z}" lit="0.5" txt="b"/>'
                                     "</Sequence>"), 1, 0.1)
        assert got["blackboard"] == {"copied": 47.0, "seen": "b", "x": 21, "y": 47.0, "z": 94.5}

    def test_nested_remapping_reaches_the_root(self, tmp_path: Path) -> None:
        """A remap of a remap: the inner subtree's output is the outer's, which is the root's."""
        extra = DOUBLER + """
  <BehaviorTree ID="Outer">
    <SubTree ID="Doubler" input="{a}" output="{b}" lit="0" txt="nested"/>
  </BehaviorTree>
"""
        got = dry_run(tree(tmp_path, '<Sequence><Script code="x := 4"/><SubTree ID="Outer" a="{x}" b="{r}"/>'
                                     "</Sequence>", extra), 1, 0.1)
        assert got["blackboard"] == {"copied": 4, "r": 8.0, "seen": "nested", "x": 4}

    def test_set_blackboard_copies_the_typed_value(self, tmp_path: Path) -> None:
        """SetBlackboard value="{src}" copies the entry itself (an integer stays an integer)."""
        got = dry_run(tree(tmp_path, '<Sequence><Script code="src := 3"/>'
                                     '<SetBlackboard output_key="dst" value="{src}"/>'
                                     '<Script code="sum := dst + 1"/></Sequence>', ""), 1, 0.1)
        assert got == {"ticks": ["SUCCESS"], "blackboard": {"dst": 3, "src": 3, "sum": 4.0}}


class TestLiterals:
    def test_literal_types(self) -> None:
        """As xml_parsing.cpp: an integer, else a real, else the text."""
        assert [typed_literal(t) for t in ("5", "-3", "0.5", "1e3", "1;2;3", "abc", "")] == [
            5, -3, 0.5, 1000.0, "1;2;3", "abc", ""]


class TestConditionsOnTheElement:
    COUNT = """
  <BehaviorTree ID="Count">
    <Script code="k += 1"/>
  </BehaviorTree>
"""

    def test_pre_and_post_conditions_on_a_subtree(self, tmp_path: Path) -> None:
        """_skipIf / _onSuccess on <SubTree> apply to it and run on the parent's blackboard (BT.CPP's SubTree node)."""
        main = ('<Sequence><Script code="go := 0; n := 0"/>'
                '<SubTree ID="Count" name="first" k="{n}" _skipIf="go == 0" _onSuccess="after := n"/>'
                '<Script code="go := 1"/>'
                '<SubTree ID="Count" name="second" k="{n}" _skipIf="go == 0" _onSuccess="after := n"/></Sequence>')
        got = dry_run(tree(tmp_path, main, self.COUNT), 1, 0.1)
        assert got == {"ticks": ["SUCCESS"], "blackboard": {"after": 1, "go": 1, "n": 1}}

    def test_a_bad_condition_script_is_a_load_error(self, tmp_path: Path) -> None:
        """A condition on a <SubTree> that does not parse names the file, line and attribute."""
        with pytest.raises(TreeError, match=r"t.xml:3: SubTree Count \(BehaviorTree M\), _skipIf: script"):
            dry_run(tree(tmp_path, '<SubTree ID="Count" k="{n}" _skipIf="go =="/>', self.COUNT), 1, 0.1)


class TestEntryTypes:
    def test_one_entry_two_port_types_is_a_load_error(self, tmp_path: Path) -> None:
        """An int port and a string port on one entry: refused at load, naming both places (xml_parsing.cpp)."""
        main = ('<Sequence><LoopInt queue="1;2" value="{v}"><AlwaysSuccess/></LoopInt>'
                '<LoopString queue="a;b" value="{v}"><AlwaysSuccess/></LoopString></Sequence>')
        with pytest.raises(TreeError, match=r"port value: the entry \[v\] was created with type \[int\] "
                                            r"\(.*t.xml:3, node LoopInt\) and is used here as \[std::string\]"):
            dry_run(tree(tmp_path, main, ""), 1, 0.1)

    def test_a_string_first_converts_and_any_type_ports_do_not_count(self, tmp_path: Path) -> None:
        """A string port first, then an int one, is accepted (BT.CPP converts from strings); so are BT::Any ports."""
        main = ('<Sequence><LoopString queue="3" value="{v}"><AlwaysSuccess/></LoopString>'
                '<LoopInt queue="4" value="{v}"><AlwaysSuccess/></LoopInt>'
                '<SkipUnlessUpdated entry="{w}"><LoopInt queue="5" value="{w}"><AlwaysSuccess/></LoopInt>'
                "</SkipUnlessUpdated></Sequence>")
        assert dry_run(tree(tmp_path, main, ""), 1, 0.1)["ticks"] == ["RUNNING"]


def test_root_keys_in_ports_from_any_depth(tmp_path: Path) -> None:
    """{@limit} in a port inside a SubTree is the root's entry (BT.CPP), as @limit in a script."""
    extra = """
  <BehaviorTree ID="C">
    <Sequence>
      <LoopInt queue="4;5" value="{@limit}"><AlwaysSuccess/></LoopInt>
      <Script code="@limit_copy := @limit"/>
    </Sequence>
  </BehaviorTree>
"""
    got = dry_run(tree(tmp_path, '<Sequence><SubTree ID="C"/><Script code="seen := limit_copy"/></Sequence>', extra),
                  3, 0.1)
    assert got == {"ticks": ["RUNNING", "RUNNING", "SUCCESS"], "blackboard": {"limit": 5, "limit_copy": 5, "seen": 5}}
