"""A reload (SIGHUP) continues each guard's model where it stood.

Before: only the trip flag of a threshold guard crossed a reload; a running
``trip_after`` timer restarted, and I²t heat without a state file started cold. The
new model keeps the new parameters and takes over the running state when the guard
is the same (same node name, node type and source).
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml
from tests.feed import step

from canguard.config.loader import load_config
from canguard.config.schema import Config
from canguard.engine.core import Engine
from canguard.engine.gate import LogSink, TaskGate
from canguard.io.block import one_block
from canguard.io.clock import ManualClock
from canguard.protect.hysteresis import Hysteresis
from canguard.protect.i2t import LeakyI2t, ThermalI2t
from canguard.protect.inrush import InrushBlanking
from canguard.protect.threshold import Threshold
from test_engine import T0, bms_frame, write_config

TREE = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <ReactiveSequence>
      {guard}
      <ExecuteTask/>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""
SAFE = '<IsCurrentSafe name="pack" topic_name="/battery_state" overcurrent_threshold="{over}" ' \
       'recovery_threshold="25" trip_after="{after}"/>'
HEAT = '<IsI2tSafe name="heat" topic_name="/battery_state" continuous_current="{cont}" ' \
       'peak_current="60" peak_time="2"/>'


class Reloadable:
    """An engine built from a tree text, reloaded (as the daemon does) with another tree text."""

    def __init__(self, tmp: Path, guard: str) -> None:
        self.tmp = tmp
        self.clock = ManualClock(T0)
        self.cfg = self._config(guard, "a")
        self.sink = LogSink(self.clock.now, self.cfg.buses)
        self.engine = Engine(self.cfg, self.clock, self.sink)
        self.engine.start(T0)
        self.t = T0

    def _config(self, guard: str, tag: str) -> Config:
        tree = self.tmp / f"tree_{tag}.xml"
        tree.write_text(TREE.format(guard=guard), encoding="utf-8")
        path = write_config(self.tmp, state={"file": None})
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
        doc["tree"].update(file=str(tree), main="Main")
        path.write_text(yaml.safe_dump(doc), encoding="utf-8")
        return load_config(path)

    def reload(self, guard: str) -> Engine:
        """Daemon.reload's sequence: build, start at now, adopt the old engine."""
        old = self.engine
        new = Engine(self._config(guard, "b"), self.clock, self.sink, previous=old)
        new.start(self.t)
        new.adopt(old)
        self.engine = new
        return new

    def pack(self, current_a: float, seconds: float, step_s: float = 0.01) -> None:
        """Battery current ``current_a`` every ``step_s`` for ``seconds``."""
        end = self.t + seconds
        while self.t + step_s <= end + 1e-9:
            self.t += step_s
            self.engine.take("main", one_block(bms_frame(self.t, current_a)))
        self.engine.advance(self.t)


def test_a_running_trip_after_timer_crosses_a_reload_that_changed_the_threshold(tmp_path: Path) -> None:
    """trip_after 0.5 s: 0.3 s over 35 A, reload to 40 A, still over: the stop comes 0.5 s after onset, not 0.8 s."""
    rig = Reloadable(tmp_path, SAFE.format(over=35, after=0.5))
    rig.pack(10.0, 0.2)
    onset = rig.t + 0.01
    rig.pack(50.0, 0.3)
    assert rig.engine.gate.state == TaskGate.RUNNING
    new = rig.reload(SAFE.format(over=40, after=0.5))
    rig.pack(50.0, 0.3)
    assert new.gate.state == TaskGate.STOPPED
    [trip] = new.stats.trips
    assert trip["t"] == pytest.approx(onset + 0.5, abs=0.011)


def test_i2t_heat_crosses_a_reload_without_a_state_file(tmp_path: Path) -> None:
    """Heat at 64 % of the trip level stays 64 % after a reload that changed continuous_current (no state file)."""
    rig = Reloadable(tmp_path, HEAT.format(cont=10))
    rig.pack(40.0, 3.0)  # leaky: (1600 - 100) A² each second of (3600 - 100) * 2 = 7000 A²s: 64 %
    old_level = rig.engine.guard_nodes[0].model.level
    assert 0.6 < old_level < 0.7
    new = rig.reload(HEAT.format(cont=12))
    model = new.guard_nodes[0].model
    assert model.continuous_a == 12.0
    assert model.level == pytest.approx(old_level)
    rig.pack(40.0, 2.0)  # the rest, 36 % of (3600 - 144) * 2 A²s, takes 1.7 s at 40 A; from cold 4.7 s
    assert new.gate.state == TaskGate.STOPPED


class TestModels:
    """carry_from on each model, as the reload uses it."""

    def test_threshold_keeps_the_latched_unreported_trip(self) -> None:
        """A spike between the last tick and the reload is still reported at the new model's first poll."""
        old = Threshold(30.0)
        old.poll(0.0)
        step(old, 50.0, 0.1)
        step(old, 10.0, 0.2)
        new = Threshold(40.0)
        new.carry_from(old)
        assert new.poll(0.25).tripped
        assert not new.poll(0.3).tripped

    def test_hysteresis_keeps_recover_after_and_the_inrush_window(self) -> None:
        """A running recover_after timer and an open inrush window continue."""
        old = Hysteresis(35.0, 25.0, recover_after_s=1.0, inrush=InrushBlanking(2.0, 0.5, 80.0))
        for i in range(60):
            step(old, 1.0, i * 0.01)  # motor stopped for 0.6 s
        step(old, 50.0, 0.6)  # a start: the inrush window opens at 0.6 s
        assert old.inrush is not None and old.inrush.threshold(35.0, 0.7) == 80.0
        new = Hysteresis(36.0, 25.0, recover_after_s=1.0, inrush=InrushBlanking(2.0, 0.5, 80.0))
        new.carry_from(old)
        assert new.inrush is not None and new.inrush.threshold(36.0, 0.7) == 80.0
        assert not step(new, 70.0, 0.7)  # inside the window: 80 A in force
        old2 = Hysteresis(35.0, 25.0, recover_after_s=1.0)
        step(old2, 50.0, 0.0)
        step(old2, 10.0, 0.5)  # under since 0.5
        new2 = Hysteresis(30.0, 20.0, recover_after_s=1.0)
        new2.carry_from(old2)
        assert new2.tripped
        assert not step(new2, 10.0, 1.4)
        assert step(new2, 10.0, 1.5)  # 1.0 s after the first sample under recovery, as the old timer ran

    @pytest.mark.parametrize("new_kind", ["leaky", "thermal"])
    def test_i2t_level_carries_across_kinds(self, new_kind: str) -> None:
        """Leaky at some heat -> a leaky or thermal model of other figures starts at the same level, not cold."""
        old = LeakyI2t(10.0, 60.0, 2.0)
        step(old, 40.0, 0.0)
        step(old, 40.0, 1.0)
        new = LeakyI2t(12.0, 60.0, 2.0) if new_kind == "leaky" else ThermalI2t(12.0, 60.0, 2.0)
        new.carry_from(old)
        assert new.level == pytest.approx(old.level)
        assert 0 < new.level < 1 and math.isfinite(new.accumulator)

    def test_a_model_of_another_kind_carries_the_trip_only(self) -> None:
        """Threshold -> Hysteresis: tripped since the same time; nothing else is invented."""
        old = Threshold(30.0)
        step(old, 50.0, 1.0)
        new = Hysteresis(35.0, 25.0)
        new.carry_from(old)
        assert new.tripped and new.since == 1.0
