"""Safety table row T4: a tree that leaves its guards behind while the task runs is stopped.

A guard the tree ticked when the task started (its cover) that is not ticked for longer than its
source's ``max_age`` while the task runs holds the task stopped (an inhibit ``guards``, a stop
event naming it) until it is ticked again: the models still see every sample, but no failure
could reach the tree.
"""

from __future__ import annotations

from pathlib import Path

from canguard.engine.gate import TaskGate
from test_engine import T0, Rig, bms_frame

LEFT_BEHIND = """<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <ReactiveSequence>
      <RunOnce then_skip="true">
        <IsCurrentSafe name="Pack" topic_name="/battery_state" overcurrent_threshold="40" recovery_threshold="30"/>
      </RunOnce>
      <ExecuteTask/>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""


def rig_with(tmp_path: Path, xml: str) -> Rig:
    tree = tmp_path / "tree.xml"
    tree.write_text(xml, encoding="utf-8")
    return Rig(tmp_path, tree={"file": str(tree), "main": "M", "tick_hz": 100})


def test_a_guard_left_behind_stops_the_task_and_says_which(tmp_path: Path) -> None:
    rig = rig_with(tmp_path, LEFT_BEHIND)
    rig.run(T0 + 0.8)  # the guard ran once (RunOnce), the task started, the guard is skipped since
    assert rig.engine.gate.state == TaskGate.STOPPED
    [stop] = rig.events.named("stop")
    assert stop["reason"] == "guards not ticked while the task runs: Pack" and stop["node"] == "Pack"
    # /battery_state's max_age is 0.5 s: the stop came once the guard had gone unticked that long
    assert T0 + 0.5 < stop["t"] <= T0 + 0.53


def test_guards_ticked_every_tick_never_trigger_it(tmp_path: Path) -> None:
    rig = Rig(tmp_path)  # the bundled tree: its guards sit under a ReactiveSequence
    rig.run(T0 + 3.0)
    assert rig.engine.gate.state == TaskGate.RUNNING
    assert not [e for e in rig.events.named("stop") if "not ticked" in e.get("reason", "")]


EFFORT_LEFT_BEHIND = """<root BTCPP_format="4" main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <ReactiveSequence>
      <IsCurrentSafe name="Pack" topic_name="/battery_state" overcurrent_threshold="40" recovery_threshold="30"/>
      <RunOnce then_skip="true">
        <IsJointEffortNormal name="Joints" topic_name="/joint_states" max_effort="150"/>
      </RunOnce>
      <ExecuteTask/>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""


def test_an_effort_guard_left_behind_stops_the_task_too(tmp_path: Path) -> None:
    """IsJointEffortNormal counts as ticked like every guard: left behind, it stops the task (it was never checked)."""
    from canguard.io.frame import Frame
    from test_engine import _db

    rig = rig_with(tmp_path, EFFORT_LEFT_BEHIND)
    t = T0 + 0.001
    while t < T0 + 0.8:  # fresh pack current and efforts on every axis, every 10 ms
        rig.feed(bms_frame(t, 10.0))
        for axis in range(4):
            msg = _db().get_message_by_name(f"Axis{axis}_Get_Torques")
            data = bytes(msg.encode({"Torque_Target": 1.0, "Torque_Estimate": 1.0}))
            rig.feed(Frame(t + 0.0002, "can0", msg.frame_id, data, False))
        t += 0.01
    rig.advance(T0 + 0.8)
    assert rig.engine.gate.state == TaskGate.STOPPED
    stops = [e for e in rig.events.named("stop") if "not ticked" in e.get("reason", "")]
    assert [s["node"] for s in stops] == ["Joints"]
