"""Timers are per node unless a ``timer`` key names a shared one (design note 000).

Note 000's IsElapsedTimeCompare keeps its own ``start_time_`` (set at its first
tick); sharing a reference goes through the blackboard. So two comparisons that
name no ``timer`` measure from their own first ticks, two that name the same key
share it, and a ResetTimer without ``timer`` restarts the unnamed timers nearest
to it (those under its closest ancestor that holds any), not every unnamed timer
of the tree.
"""

from __future__ import annotations

from pathlib import Path

import py_trees
import pytest

from canguard.errors import TreeError
from treekit import F, Rig, S, find, xml_tree

BB = py_trees.blackboard.Blackboard
START = 1000.0


def at(rig: Rig, *offsets: float) -> list[object]:
    """Tick at START + each offset; the root's statuses."""
    out = []
    for dt in offsets:
        rig.clock.set(START + dt)
        out.append(rig.tick())
    return out


class TestIsElapsedTimeCompare:
    """First-tick references of nodes without a ``timer`` port are their own."""

    BODY = (
        '<Sequence><IsElapsedTimeCompare name="a" reference_sec="5" operator="GTE"{timer}/>'
        '<IsElapsedTimeCompare name="b" reference_sec="3" operator="GTE"{timer}/></Sequence>'
    )

    def test_unnamed_timers_are_independent(self, tmp_path: Path) -> None:
        """a is first ticked at 0 s, b (behind a) at 5 s: b needs 3 s from its own first tick, i.e. 8 s."""
        rig = Rig(start=START)
        loaded = rig.load_text(tmp_path, xml_tree(self.BODY.format(timer="")))
        assert at(rig, 0.0, 5.0, 7.9, 8.0) == [F, F, F, S]
        assert find(loaded, "b").feedback_message == "elapsed 3.000 s GTE 3 s: True"
        assert not [k for k in BB.storage if "timer" in k]  # nothing shared on the blackboard

    def test_the_same_timer_key_is_shared(self, tmp_path: Path) -> None:
        """With timer="{t}" on both, b measures from a's first tick: SUCCESS as soon as a is (5 s)."""
        rig = Rig(start=START)
        rig.load_text(tmp_path, xml_tree(self.BODY.format(timer=' timer="{t}"')))
        assert at(rig, 0.0, 5.0, 7.9, 8.0) == [F, S, S, S]
        assert BB.get("/t") == START

    def test_one_named_one_unnamed(self, tmp_path: Path) -> None:
        """A named timer started elsewhere does not move an unnamed one, nor the other way round."""
        rig = Rig(start=START)
        body = (
            "<Sequence>"
            '<ForceSuccess><IsElapsedTimeCompare name="own" reference_sec="10" operator="GTE"/></ForceSuccess>'
            '<ForceSuccess><IsElapsedTimeCompare name="nav" reference_sec="10" operator="GTE" timer="{nav}"/>'
            "</ForceSuccess></Sequence>"
        )
        loaded = rig.load_text(tmp_path, xml_tree(body))
        BB.set("/nav", START - 20.0)
        at(rig, 0.0, 9.0)
        assert find(loaded, "own").feedback_message == "elapsed 9.000 s GTE 10 s: False"
        assert find(loaded, "nav").feedback_message == "elapsed 29.000 s GTE 10 s: True"


class TestResetTimer:
    """Without ``timer``, ResetTimer restarts the unnamed timers nearest to it."""

    def test_reset_stays_in_its_branch(self, tmp_path: Path) -> None:
        """ResetTimer in branch A restarts A's comparison only; the unnamed one beside the branch keeps its start."""
        rig = Rig(start=START)
        body = (
            "<Sequence>"
            '<ForceSuccess><Sequence name="A"><IsElapsedTimeCompare name="ta" reference_sec="2" operator="GTE"/>'
            '<ResetTimer name="ra"/></Sequence></ForceSuccess>'
            '<ForceSuccess><IsElapsedTimeCompare name="tb" reference_sec="3" operator="GTE"/></ForceSuccess>'
            "</Sequence>"
        )
        loaded = rig.load_text(tmp_path, xml_tree(body))
        at(rig, 0.0, 2.0)
        assert find(loaded, "ta").feedback_message == "elapsed 2.000 s GTE 2 s: True"  # then ra restarted it
        at(rig, 3.0)
        assert find(loaded, "ta").feedback_message == "elapsed 1.000 s GTE 2 s: False"  # since the reset
        # 3 s since its own first tick: ra did not reset it
        assert find(loaded, "tb").feedback_message == "elapsed 3.000 s GTE 3 s: True"

    def test_reset_reaches_up_to_the_nearest_timers(self, tmp_path: Path) -> None:
        """A ResetTimer in a branch of its own restarts the comparison in the sibling branch (nearest ancestor)."""
        rig = Rig(start=START)
        body = (
            "<Fallback>"
            '<Inverter><IsElapsedTimeCompare name="due" reference_sec="60" operator="GTE"/></Inverter>'
            '<Sequence><PerformDiagnostics/><ResetTimer/></Sequence>'
            "</Fallback>"
        )
        rig.load_text(tmp_path, xml_tree(body))
        assert at(rig, 0.0, 59.0, 60.0, 61.0, 119.0, 120.0) == [S, S, S, S, S, S]
        assert rig.labels() == ["PerformDiagnostics", "PerformDiagnostics"]

    def test_last_reset_per_node(self, tmp_path: Path) -> None:
        """reference="last_reset" without a timer fails until the ResetTimer next to it ran, then measures from it."""
        rig = Rig(start=START)
        body = (
            "<Sequence><ForceSuccess>"
            '<IsElapsedTimeCompare name="since_reset" reference_sec="1" operator="GTE" reference="last_reset"/>'
            "</ForceSuccess>"
            '<Sequence><IsElapsedSinceEvent event_timestamp="{go}"/><ResetTimer name="reset"/></Sequence>'
            "</Sequence>"
        )
        loaded = rig.load_text(tmp_path, xml_tree(body))
        at(rig, 0.0, 5.0)
        assert find(loaded, "since_reset").status == F
        assert "no reset yet" in find(loaded, "since_reset").feedback_message
        BB.set("/go", START)
        at(rig, 5.0)  # the reset runs after since_reset in this tick
        BB.set("/go", START + 1e9)  # no more resets
        at(rig, 5.5)
        assert find(loaded, "since_reset").feedback_message == "elapsed 0.500 s GTE 1 s: False"
        at(rig, 6.0)
        assert find(loaded, "since_reset").feedback_message == "elapsed 1.000 s GTE 1 s: True"

    def test_reset_without_any_unnamed_timer_is_a_load_error(self, tmp_path: Path) -> None:
        """A ResetTimer with no timer to restart names the file, the node and the port."""
        rig = Rig(start=START)
        with pytest.raises(TreeError) as info:
            rig.load_text(
                tmp_path,
                xml_tree('<Sequence><IsElapsedTimeCompare reference_sec="1" timer="{t}"/><ResetTimer/></Sequence>'),
            )
        text = str(info.value)
        assert "tree.xml:" in text and "ResetTimer" in text and "port timer" in text
        assert "no IsElapsedTimeCompare without a timer" in text
