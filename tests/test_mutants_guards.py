"""The guard nodes as a tree author and the journal see them: port errors in port names, trip and recover events.

Written against the mutants ``SCOPE=gate bash scripts/mutation.sh`` left alive in
``bt/nodes/current.py``: each test asserts a load error a user reads (the port named, the model's
message in port words) or an event field in the journal.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from canguard.errors import TreeError
from treekit import Rig, xml_tree


def load_error(tmp_path: Path, node: str) -> str:
    rig = Rig()
    with pytest.raises(TreeError) as err:
        rig.load_text(tmp_path, xml_tree(f"<ReactiveSequence>{node}<ExecuteTask/></ReactiveSequence>"))
    return str(err.value)


class TestPortErrorsInPortWords:
    @pytest.mark.parametrize(("node", "port", "message"), [
        ('<IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="10" recovery_threshold="20"/>',
         "recovery_threshold", "recovery_threshold (20.0 A) must not exceed overcurrent_threshold (10.0 A)"),
        ('<IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="-1" recovery_threshold="0"/>',
         "overcurrent_threshold", "overcurrent_threshold must be a finite number >= 0, got -1.0"),
        ('<IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="10" recovery_threshold="5" '
         'trip_after="-1"/>', "trip_after", "trip_after must be a finite number >= 0, got -1.0"),
        ('<IsCurrentNormal topic_name="/battery_state" max_current="-3"/>',
         "max_current", "max_current must be a finite number >= 0, got -3.0"),
        ('<IsI2tSafe topic_name="/battery_state" continuous_current="10" peak_current="5" peak_time="3"/>',
         "peak_current", "peak_current (5.0 A) must exceed continuous_current (10.0 A)"),
        ('<IsI2tSafe topic_name="/battery_state" continuous_current="-10"/>',
         "continuous_current", "continuous_current must be a finite number > 0, got -10.0"),
        ('<IsI2tSafe topic_name="/battery_state" continuous_current="10" recover_fraction="1.5"/>',
         "recover_fraction", "recover_fraction must be > 0 and < 1, got 1.5"),
        ('<IsI2tSafe topic_name="/battery_state" continuous_current="10" k="0"/>',
         "k", "must be a finite number > 0, got 0.0"),
        ('<IsI2tSafe topic_name="/battery_state" continuous_current="10" peak_current="30"/>',
         "peak_time", "required with peak_current (a datasheet peak is a current and a time)"),
        ('<IsI2tSafe topic_name="/battery_state" continuous_current="10" k="1.6"/>',
         "peak_current", "required when k >= 1.5 (the derived peak 15 A = 1.5 × continuous_current must exceed "
                         "I_cont = k × continuous_current = 16 A)"),
        ('<IsI2tSafe topic_name="/battery_state" model="thermal" continuous_current="10" tau="-1"/>',
         "tau", "tau must be a finite number > 0, got -1.0"),
        ('<IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="10" recovery_threshold="5" '
         'inrush_time="0.5"/>', "start_current", "required when inrush_time > 0 (|I| of a motor start)"),
        ('<IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="10" recovery_threshold="5" '
         'recover_after="-2"/>', "recover_after", "recover_after must be a finite number >= 0, got -2.0"),
        ('<IsCurrentSafe topic_name="/battery_state" overcurrent_threshold="10" recovery_threshold="5" '
         'inrush_time="0.5" start_current="-1"/>', "start_current",
         "start_current must be a finite number >= 0, got -1.0"),
        ('<IsCurrentSafe topic_name="/nope" overcurrent_threshold="10" recovery_threshold="5"/>',
         "topic_name", "unknown source '/nope'"),
    ])
    def test_the_error_names_the_port(self, tmp_path: Path, node: str, port: str, message: str) -> None:
        text = load_error(tmp_path, node)
        assert f"port {port}: " in text, text
        assert message in text, text
        for model_word in ("overcurrent_a", "recovery_a", "max_value", "continuous_a", "peak_a"):
            assert model_word not in text, text  # the model's parameter names never reach the user


class TestEvents:
    def test_trip_and_recover_events_carry_node_source_signal_value_threshold(self, tmp_path: Path) -> None:
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsCurrentSafe name="Pack" topic_name="/battery_state" overcurrent_threshold="10" '
            'recovery_threshold="5"/><ExecuteTask/></ReactiveSequence>'))
        rig.battery(2.0)
        rig.tick()
        rig.advance(0.01)
        rig.battery(12.0)
        rig.tick()
        rig.advance(0.01)
        rig.battery(3.0)
        rig.tick()
        trip, recover = rig.trips()
        assert {k: trip[k] for k in ("event", "node", "source", "signal", "value", "threshold", "reason")} == {
            "event": "trip", "node": "Pack", "source": "/battery_state", "signal": "current", "value": 12.0,
            "threshold": 10.0, "reason": "overcurrent"}
        assert {k: recover[k] for k in ("event", "node", "source", "signal", "value", "threshold", "reason")} == {
            "event": "recover", "node": "Pack", "source": "/battery_state", "signal": "current", "value": 3.0,
            "threshold": 10.0, "reason": ""}
        assert rig.node("Pack").feedback_message == ""

    def test_feedback_says_why_while_failing(self, tmp_path: Path) -> None:
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsCurrentNormal name="Pack" topic_name="/battery_state" max_current="10"/>'
            "<ExecuteTask/></ReactiveSequence>"))
        rig.battery(12.5)
        rig.tick()
        assert rig.node("Pack").feedback_message == "overcurrent: current |12.5| (threshold 10)"


class TestI2tAndDynamic:
    def test_i2t_trip_speaks_of_heat_and_writes_the_level(self, tmp_path: Path) -> None:
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsI2tSafe name="Heat" topic_name="/battery_state" continuous_current="10" '
            'peak_current="20" peak_time="1" level="{heat}"/><ExecuteTask/></ReactiveSequence>'))
        for _ in range(30):  # 20 A: (400 - 100) A²s per second against a trip level of 300 A²s
            rig.battery(20.0)
            rig.tick()
            rig.advance(0.05)
        [trip] = [e for e in rig.trips() if e["event"] == "trip"]
        assert trip["reason"] == "i2t" and trip["node"] == "Heat" and trip["threshold"] == 300.0
        assert trip["value"] >= 300.0  # the heat (A²s) against the trip level, like with like
        feedback = rig.node("Heat").feedback_message
        assert feedback.startswith("i2t: heat ") and feedback.endswith("A²s of trip level 300 A²s (current |20|)")
        from py_trees.blackboard import Blackboard

        assert Blackboard.storage["/heat"] >= 100.0

    def test_a_threshold_from_the_blackboard_is_used_and_a_bad_one_fails_safe(self, tmp_path: Path) -> None:
        from py_trees.blackboard import Blackboard

        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsCurrentNormal name="Pack" topic_name="/battery_state" max_current="{limit}"/>'
            "<ExecuteTask/></ReactiveSequence>"))
        Blackboard.storage["/limit"] = 10.0
        rig.battery(12.0)
        assert rig.tick().name == "FAILURE"
        Blackboard.storage["/limit"] = 20.0
        rig.advance(0.01)
        rig.battery(12.0)
        assert rig.tick().name == "RUNNING"
        Blackboard.storage["/limit"] = -5.0
        rig.advance(0.01)
        rig.battery(1.0)
        assert rig.tick().name == "FAILURE"
        assert rig.node("Pack").reason == "bad_threshold"


class TestInrushAndDefaults:
    def test_the_inrush_threshold_port_is_in_force_during_a_start(self, tmp_path: Path) -> None:
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsCurrentSafe name="Pack" topic_name="/battery_state" overcurrent_threshold="10" '
            'recovery_threshold="5" inrush_time="0.5" start_current="2" inrush_threshold="40"/>'
            "<ExecuteTask/></ReactiveSequence>"))
        for _ in range(6):  # quiet for 0.5 s
            rig.battery(0.0)
            rig.tick()
            rig.advance(0.1)
        rig.battery(30.0)  # a motor start: 30 A is under the inrush threshold (40 A)
        assert rig.tick().name == "RUNNING"
        rig.advance(0.6)  # the window is over: 30 A is an overcurrent again
        rig.battery(30.0)
        assert rig.tick().name == "FAILURE"

    def test_thresholds_on_keys_not_written_yet_use_the_defaults(self, tmp_path: Path) -> None:
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsCurrentSafe name="Pack" topic_name="/battery_state" '
            'overcurrent_threshold="{over}" recovery_threshold="{rec}"/><ExecuteTask/></ReactiveSequence>'))
        rig.battery(34.5)  # the keys hold nothing yet: the ports' defaults, 35 / 25 A
        assert rig.tick().name == "RUNNING"
        rig.advance(0.01)
        rig.battery(35.5)
        assert rig.tick().name == "FAILURE" and rig.trips()[-1]["threshold"] == 35.0


class TestI2tBoundaries:
    def test_continuous_current_boundaries(self, tmp_path: Path) -> None:
        text = load_error(tmp_path, '<IsI2tSafe topic_name="/battery_state" continuous_current="0"/>')
        assert "port continuous_current: continuous_current must be a finite number > 0, got 0.0" in text
        rig = Rig()  # 1 A is a valid rating (small drives)
        rig.load_text(tmp_path, xml_tree('<ReactiveSequence><IsI2tSafe topic_name="/battery_state" '
                                         'continuous_current="1"/><ExecuteTask/></ReactiveSequence>'))

    def test_a_leaky_model_ignores_tau_and_derives_its_peak(self, tmp_path: Path) -> None:
        rig = Rig()
        rig.load_text(tmp_path, xml_tree('<ReactiveSequence><IsI2tSafe name="Heat" topic_name="/battery_state" '
                                         'model="leaky" continuous_current="10" tau="30"/><ExecuteTask/>'
                                         "</ReactiveSequence>"))
        model = rig.node("Heat").model
        assert model.peak_a == 15.0 and model.peak_time_s == 120.0  # 1.5 x rating for 120 s (IEC 60034-1)


class TestOneByOne:
    """Written against the survivors of the one-by-one pass (docs/mutants.md, "The guard nodes")."""

    def test_feedback_keeps_the_trip_value_while_the_reason_is_the_same(self, tmp_path: Path) -> None:
        """The feedback (and so a stop's ``reason``) changes at edges only, not with every new sample."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsCurrentNormal name="Pack" topic_name="/battery_state" max_current="10"/>'
            "<ExecuteTask/></ReactiveSequence>"))
        rig.battery(12.5)
        rig.tick()
        rig.advance(0.01)
        rig.battery(13.0)
        assert rig.tick().name == "FAILURE"
        assert rig.node("Pack").feedback_message == "overcurrent: current |12.5| (threshold 10)"
        assert [e["event"] for e in rig.trips()] == ["trip"]

    def test_a_guard_checks_its_own_signal_only(self, tmp_path: Path) -> None:
        """A source's other value signal (a voltage never received) does not fail a current guard."""
        from treekit import source

        rig = Rig(sources={"/battery_state": source("/battery_state", "battery", ("current", "voltage", "present"))})
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsCurrentNormal name="Pack" topic_name="/battery_state" max_current="10"/>'
            "<ExecuteTask/></ReactiveSequence>"))
        rig.battery(2.0)
        assert rig.tick().name == "RUNNING"
        assert rig.node("Pack").reason == "" and not rig.trips()

    def test_an_i2t_guard_on_a_stale_source_says_stale_and_the_signal(self, tmp_path: Path) -> None:
        """A health failure of an I²t guard is worded like any guard's: the reason, then the signal."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsI2tSafe name="Heat" topic_name="/battery_state" continuous_current="10"/>'
            "<ExecuteTask/></ReactiveSequence>"))
        rig.battery(5.0)
        assert rig.tick().name == "RUNNING"
        rig.advance(1.0)  # max_age 0.5 s
        assert rig.tick().name == "FAILURE"
        node = rig.node("Heat")
        assert node.reason == "stale"
        assert node.feedback_message.startswith("stale: current |"), node.feedback_message

    def test_a_start_above_the_inrush_threshold_trips(self, tmp_path: Path) -> None:
        """Inside the inrush window the inrush threshold is checked: 50 A against 40 A trips."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsCurrentSafe name="Pack" topic_name="/battery_state" overcurrent_threshold="10" '
            'recovery_threshold="5" inrush_time="0.5" start_current="2" inrush_threshold="40"/>'
            "<ExecuteTask/></ReactiveSequence>"))
        for _ in range(6):  # quiet for 0.5 s
            rig.battery(0.0)
            rig.tick()
            rig.advance(0.1)
        rig.battery(50.0)
        assert rig.tick().name == "FAILURE"
        assert rig.trips()[-1]["value"] == 50.0

    def test_a_threshold_key_of_the_wrong_type_at_load_fails_safe_on_the_defaults(self, tmp_path: Path) -> None:
        """A key holding text at load: the tree loads; the guard fails (bad_threshold) on 35 / 25 A till it is fixed."""
        from py_trees.blackboard import Blackboard

        Blackboard.storage["/over"] = "high"
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsCurrentSafe name="Pack" topic_name="/battery_state" '
            'overcurrent_threshold="{over}" recovery_threshold="20"/><ExecuteTask/></ReactiveSequence>'))
        rig.battery(1.0)
        assert rig.tick().name == "FAILURE"
        trip = rig.trips()[-1]
        assert (trip["reason"], trip["threshold"]) == ("bad_threshold", 35.0)
        rig.advance(0.01)
        rig.battery(40.0)  # an overcurrent under the defaults (35 A) ...
        rig.tick()
        rig.advance(0.01)
        rig.battery(25.5)  # ... not recovered: 25.5 A is above the default recovery (25 A)
        rig.tick()
        Blackboard.storage["/over"] = 35.0  # fixed: 35 / 20 A from now on, 25.5 A still an overcurrent
        rig.advance(0.01)
        assert rig.tick().name == "FAILURE"
        assert rig.node("Pack").reason == "overcurrent"

    def test_a_recovery_threshold_changed_alone_is_used(self, tmp_path: Path) -> None:
        """A new recovery_threshold on the blackboard applies even when overcurrent_threshold stays the same."""
        from py_trees.blackboard import Blackboard

        Blackboard.storage["/rec"] = 5.0
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsCurrentSafe name="Pack" topic_name="/battery_state" '
            'overcurrent_threshold="10" recovery_threshold="{rec}"/><ExecuteTask/></ReactiveSequence>'))
        rig.battery(12.0)
        assert rig.tick().name == "FAILURE"
        Blackboard.storage["/rec"] = 8.0
        rig.advance(0.01)
        rig.battery(7.0)
        assert rig.tick().name == "RUNNING"
        assert rig.trips()[-1]["event"] == "recover"

    def test_a_thermal_model_with_tau_needs_no_peak_even_with_k_above_1_5(self, tmp_path: Path) -> None:
        """With ``tau`` the thermal image derives no peak, so k = 1.6 without peak_current is no error."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            '<ReactiveSequence><IsI2tSafe name="Heat" topic_name="/battery_state" model="thermal" '
            'continuous_current="10" k="1.6" tau="30"/><ExecuteTask/></ReactiveSequence>'))
        rig.battery(5.0)
        assert rig.tick().name == "RUNNING"

    def test_a_thermal_recover_fraction_is_checked(self, tmp_path: Path) -> None:
        """The thermal model gets recover_fraction too: out of range is a load error naming the port."""
        text = load_error(tmp_path, '<IsI2tSafe topic_name="/battery_state" model="thermal" '
                                    'continuous_current="10" recover_fraction="1.5"/>')
        assert "port recover_fraction: recover_fraction must be > 0 and < 1, got 1.5" in text

    @pytest.mark.parametrize("model", ["leaky", "thermal"])
    def test_a_gap_in_the_samples_heats_for_max_age_only(self, tmp_path: Path, model: str) -> None:
        """A 2 s gap at 20 A (peak 20 A for 1 s) heats for the source's max_age (0.5 s), not 2 s: no trip."""
        rig = Rig()
        rig.load_text(tmp_path, xml_tree(
            f'<ReactiveSequence><IsI2tSafe name="Heat" topic_name="/battery_state" model="{model}" '
            'continuous_current="10" peak_current="20" peak_time="1"/><ExecuteTask/></ReactiveSequence>'))
        rig.battery(20.0)
        rig.tick()
        rig.advance(2.0)
        rig.battery(0.0)
        assert rig.tick().name == "RUNNING"
        assert not [e for e in rig.trips() if e["event"] == "trip"]


FALLBACK_GUARDS = """<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <ReactiveSequence>
      <IsCurrentSafe name="Pack" topic_name="/battery_state" overcurrent_threshold="40" recovery_threshold="30"/>
      <ReactiveFallback>
        <IsCurrentNormal name="A" topic_name="/battery_state" max_current="40"/>
        <IsCurrentNormal name="B" topic_name="/battery_state" max_current="45"/>
      </ReactiveFallback>
      <ExecuteTask/>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""


def test_a_guard_never_reached_is_not_left_behind(tmp_path: Path) -> None:
    """A fallback's second guard, never ticked while the first holds, neither stops the task nor breaks the loop."""
    from canguard.engine.gate import TaskGate
    from test_engine import T0
    from test_engine import Rig as EngineRig

    tree = tmp_path / "tree.xml"
    tree.write_text(FALLBACK_GUARDS, encoding="utf-8")
    rig = EngineRig(tmp_path, tree={"file": str(tree), "main": "M", "tick_hz": 100})
    rig.run(T0 + 1.0)
    assert rig.engine.gate.state == TaskGate.RUNNING and not rig.events.named("stop")


def test_a_quiet_retick_writes_the_heat_level_again_and_counts_as_ticked(tmp_path: Path) -> None:
    """A quiet tick (the engine's repeat of the last tick) writes an I²t guard's ``level`` from the heat now, and
    marks the guard ticked (the engine's left-behind watch reads it)."""
    from py_trees.blackboard import Blackboard

    rig = Rig()
    rig.load_text(tmp_path, xml_tree(
        '<ReactiveSequence><IsI2tSafe name="Heat" topic_name="/battery_state" continuous_current="10" '
        'peak_current="20" peak_time="1" level="{heat}"/><IsCurrentNormal name="Pack" '
        'topic_name="/battery_state" max_current="30"/><ExecuteTask/></ReactiveSequence>'))
    rig.battery(15.0)
    rig.tick()
    before = Blackboard.storage["/heat"]
    rig.advance(0.2)
    rig.battery(15.0)  # heats: (225 - 100) A²s/s against a trip level of 300 A²s
    heat, pack = rig.node("Heat"), rig.node("Pack")
    heat.quiet_retick(rig.now())
    pack.quiet_retick(rig.now())
    level = Blackboard.storage["/heat"]
    assert level == pytest.approx(heat.model.snapshot().level_pct) and level > before
    assert heat.judged_t == rig.now() and pack.judged_t == rig.now()
