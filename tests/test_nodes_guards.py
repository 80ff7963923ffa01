"""Guard conditions: sources, models fed with every sample, thresholds at tick, events on edges."""

from __future__ import annotations

from pathlib import Path

import py_trees
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canguard.protect.hysteresis import Hysteresis
from canguard.protect.i2t import LeakyI2t, ThermalI2t
from treekit import F, Rig, S, xml_tree


def guard(tmp_path: Path, body: str, rig: Rig | None = None) -> tuple[Rig, object]:
    rig = rig or Rig()
    loaded = rig.load_text(tmp_path, xml_tree(body))
    return rig, loaded.root


class TestIsCurrentNormal:
    """IsCurrentNormal(topic_name, max_current=30)."""

    def test_default_limit_on_a_current_source(self, tmp_path: Path) -> None:
        """30 A is normal, 30.1 A is not; sources of kind current work as well as battery."""
        rig, _ = guard(tmp_path, '<IsCurrentNormal topic_name="axis0"/>')
        rig.feed("axis0", "current", -30.0)
        assert rig.tick() == S
        rig.feed("axis0", "current", 30.1)
        assert rig.tick() == F
        assert rig.ctx.read_sources == {"axis0"}

    def test_every_sample_counts(self, tmp_path: Path) -> None:
        """Samples between ticks all reach the model: a spike is reported once, then cleared."""
        rig, _ = guard(tmp_path, '<IsCurrentNormal topic_name="axis0" max_current="10"/>')
        for v in (1.0, 12.0, 1.0):
            rig.advance(0.001)
            rig.feed("axis0", "current", v)
        assert rig.tick() == F
        rig.advance(0.01)
        assert rig.tick() == S

    def test_limit_from_the_blackboard_is_read_at_tick(self, tmp_path: Path) -> None:
        """max_current="{limit}" follows the key; the latest sample is judged again under a new limit."""
        rig, _ = guard(tmp_path, '<IsCurrentNormal topic_name="axis0" max_current="{limit}"/>')
        rig.feed("axis0", "current", 20.0)
        assert rig.tick() == S  # key unset: the port's default, 30 A
        py_trees.blackboard.Blackboard.set("/limit", 15.0)
        assert rig.tick() == F
        py_trees.blackboard.Blackboard.set("/limit", 25)  # an int is fine for a float port
        assert rig.tick() == S  # 20 A under 25 A at once: the trip was already reported

    def test_bad_limit_fails_safe(self, tmp_path: Path) -> None:
        """A negative or non-numeric limit on the blackboard fails the guard (bad_threshold)."""
        rig, _ = guard(tmp_path, '<IsCurrentNormal topic_name="axis0" max_current="{limit}"/>')
        rig.feed("axis0", "current", 1.0)
        py_trees.blackboard.Blackboard.set("/limit", -5.0)
        assert rig.tick() == F
        assert rig.events[-1]["reason"] == "bad_threshold"
        py_trees.blackboard.Blackboard.set("/limit", "lots")
        assert rig.tick() == F

    def test_edges_are_journalled_once(self, tmp_path: Path) -> None:
        """A trip and a recovery each give one event; a healthy start gives none."""
        rig, _ = guard(tmp_path, '<IsCurrentNormal topic_name="axis0" max_current="10"/>')
        for v in (1.0, 2.0, 11.0, 12.0, 5.0, 5.0, 4.0):
            rig.advance(0.01)
            rig.feed("axis0", "current", v)
            rig.tick()
        events = [(e["event"], e.get("value")) for e in rig.trips()]
        assert events == [("trip", 11.0), ("recover", 5.0)]
        assert rig.trips()[0]["t"] == pytest.approx(1000.03)


class TestIsJointEffortNormal:
    """IsJointEffortNormal(topic_name, max_effort=100)."""

    def test_default_limit_every_joint(self, tmp_path: Path) -> None:
        """Each joint is held to 100 by default; the failing joint is named."""
        rig, _ = guard(tmp_path, '<IsJointEffortNormal topic_name="/joint_states"/>')
        rig.joints(100.0, -100.0, 0.0, 50.0)
        assert rig.tick() == S
        rig.joints(1.0, 1.0, 1.0, -100.5)
        assert rig.tick() == F
        assert rig.trips()[-1]["signal"] == "axis3"

    def test_source_without_joints(self, tmp_path: Path) -> None:
        """A joints source that lists no joint fails (no efforts at all)."""
        from treekit import source

        rig = Rig(sources={"/joint_states": source("/joint_states", "joints", ())})
        rig, _ = guard(tmp_path, '<IsJointEffortNormal topic_name="/joint_states"/>', rig)
        assert rig.tick() == F
        assert rig.failure_reason() == "no_data"
        assert not rig.trips(), "no data yet fails the guard but is not a trip"

    def test_limit_from_the_blackboard(self, tmp_path: Path) -> None:
        """max_effort="{e}" applies to every joint at the next tick."""
        rig, _ = guard(tmp_path, '<IsJointEffortNormal topic_name="/joint_states" max_effort="{e}"/>')
        py_trees.blackboard.Blackboard.set("/e", 5.0)
        rig.joints(1.0, 2.0, 3.0, 4.0)
        assert rig.tick() == S
        py_trees.blackboard.Blackboard.set("/e", 3.5)
        assert rig.tick() == F


class TestIsCurrentSafe:
    """IsCurrentSafe: hysteresis, persistence, inrush blanking, thresholds at tick."""

    def test_model_built_from_ports(self, tmp_path: Path) -> None:
        """The Hysteresis gets the ports' values and the source's max_age as its gap limit."""
        _, node = guard(
            tmp_path,
            '<IsCurrentSafe topic_name="axis0" overcurrent_threshold="20" '
            'recovery_threshold="10" trip_after="0.1" recover_after="0.2"/>',
        )
        model = node.model  # type: ignore[attr-defined]
        assert isinstance(model, Hysteresis)
        assert (
            model.overcurrent_a,
            model.recovery_a,
            model.trip_after_s,
            model.recover_after_s,
            model.max_gap_s,
        ) == (20.0, 10.0, 0.1, 0.2, 0.5)

    def test_trip_after_needs_a_lasting_overcurrent(self, tmp_path: Path) -> None:
        """trip_after=0.1: 50 ms of 40 A pass, 100 ms trip."""
        rig, _ = guard(tmp_path, '<IsCurrentSafe topic_name="axis0" trip_after="0.1"/>')
        statuses = []
        for v in (10.0, 40.0, 40.0, 10.0, 40.0, 40.0, 40.0):
            rig.advance(0.05)
            rig.feed("axis0", "current", v)
            statuses.append(rig.tick())
        assert statuses == [S, S, S, S, S, S, F]

    def test_inrush_blanking(self, tmp_path: Path) -> None:
        """After a motor start 50 A is allowed for inrush_time (up to inrush_threshold), not afterwards."""
        rig, _ = guard(
            tmp_path,
            '<IsCurrentSafe topic_name="axis0" inrush_time="0.3" inrush_threshold="60" start_current="2"/>',
        )
        for _ in range(5):  # the motor is stopped long enough for a start to count
            rig.advance(0.1)
            rig.feed("axis0", "current", 0.5)
            rig.tick()
        statuses = []
        for v in (50.0, 50.0, 50.0, 50.0):
            rig.advance(0.1)
            rig.feed("axis0", "current", v)
            statuses.append(rig.tick())
        assert statuses == [S, S, S, F]

    def test_thresholds_from_the_blackboard(self, tmp_path: Path) -> None:
        """{over}/{rec} are re-read each tick (the port defaults apply until the keys are written)."""
        bb = py_trees.blackboard.Blackboard
        bb.set("/over", 50.0)
        bb.set("/rec", 40.0)
        rig, node = guard(
            tmp_path,
            '<IsCurrentSafe topic_name="axis0" overcurrent_threshold="{over}" recovery_threshold="{rec}"/>',
        )
        assert node.model.overcurrent_a == 50.0  # type: ignore[attr-defined]
        rig.feed("axis0", "current", 45.0)
        assert rig.tick() == S
        bb.set("/over", 44.0)
        assert rig.tick() == F
        assert node.model.overcurrent_a == 44.0  # type: ignore[attr-defined]
        bb.set("/over", 100.0)
        bb.set("/rec", 120.0)  # recovery above the trip threshold: not a hysteresis
        rig.feed("axis0", "current", 1.0)
        assert rig.tick() == F
        assert node.feedback_message.startswith("bad_threshold")  # type: ignore[attr-defined]


class TestIsI2tSafe:
    """IsI2tSafe: leaky bucket or thermal image, level output, heat registry."""

    def test_leaky_trips_after_peak_time_and_writes_level(self, tmp_path: Path) -> None:
        """6 A continuous, 12 A for 1 s: constant 12 A trips after 1 s; {lvl} holds the level in %."""
        rig, node = guard(
            tmp_path,
            '<IsI2tSafe topic_name="axis0" continuous_current="6" peak_current="12" peak_time="1" level="{lvl}"/>',
        )
        model = node.model  # type: ignore[attr-defined]
        assert isinstance(model, LeakyI2t) and model.trip_level == pytest.approx(108.0)
        assert rig.ctx.heat_models == {"IsI2tSafe": model}
        statuses = []
        for _ in range(12):
            rig.feed("axis0", "current", 12.0)
            statuses.append(rig.tick())
            rig.advance(0.1)
        assert statuses[:10] == [S] * 10 and statuses[-1] == F
        assert py_trees.blackboard.Blackboard.get("/lvl") >= 100.0
        assert rig.trips()[-1]["reason"] == "i2t"

    def test_recovers_below_recover_fraction(self, tmp_path: Path) -> None:
        """After a trip, the guard recovers once the heat falls below recover_fraction of the trip level."""
        rig, _ = guard(
            tmp_path,
            '<IsI2tSafe topic_name="axis0" continuous_current="6" peak_current="12" '
            'peak_time="1" recover_fraction="0.5" level="{lvl}"/>',
        )
        for _ in range(12):
            rig.feed("axis0", "current", 12.0)
            rig.tick()
            rig.advance(0.1)
        assert rig.tick() == F
        levels = []
        for _ in range(100):
            rig.feed("axis0", "current", 0.0)
            status = rig.tick()
            levels.append(py_trees.blackboard.Blackboard.get("/lvl"))
            if status == S:
                break
            rig.advance(0.1)
        assert status == S and levels[-1] < 50.0 and max(levels[:-2]) >= 50.0

    def test_thermal_with_k_factor(self, tmp_path: Path) -> None:
        """model="thermal": I_cont = k * continuous_current; tau given directly."""
        _, node = guard(
            tmp_path,
            '<IsI2tSafe topic_name="axis0" model="thermal" continuous_current="5" k="1.2" tau="30" tau_cool="60"/>',
        )
        model = node.model  # type: ignore[attr-defined]
        assert isinstance(model, ThermalI2t)
        assert (model.continuous_a, model.tau_s, model.tau_cool_s) == (pytest.approx(6.0), 30.0, 60.0)

    def test_stale_source_fails_even_when_cool(self, tmp_path: Path) -> None:
        """No fresh current: FAILURE whatever the heat."""
        rig, _ = guard(
            tmp_path, '<IsI2tSafe topic_name="axis0" continuous_current="6" peak_current="12" peak_time="1"/>'
        )
        rig.feed("axis0", "current", 1.0)
        assert rig.tick() == S
        rig.advance(1.0)
        assert rig.tick() == F
        assert rig.trips()[-1]["reason"] == "stale"


class TestAgainstTheNote:
    """IsCurrentSafe agrees with design note 004's C++ logic, sample by sample."""

    # differing_executors: mutmut runs the class's tests through its own trampoline
    @settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.differing_executors])
    @given(st.lists(st.floats(min_value=-60.0, max_value=60.0, allow_nan=False), min_size=1, max_size=60))
    def test_hysteresis_matches_the_note(self, currents: list[float]) -> None:
        """One sample per tick: FAILURE exactly when the note's is_normal_ is false after the sample.

        The note's node looks only at the latest message; canguard's peak latch also reports
        a trip that began since the previous tick, which with one sample per tick is the same.
        A trip the previous tick already reported is not held past the recovering sample.
        """
        import tempfile

        py_trees.blackboard.Blackboard.clear()
        with tempfile.TemporaryDirectory() as tmp:
            rig, _ = guard(Path(tmp), '<IsCurrentSafe topic_name="/battery_state"/>')
        normal = True
        for current in currents:
            if abs(current) >= 35.0:
                normal = False
            elif abs(current) <= 25.0:
                normal = True
            rig.advance(0.01)
            rig.battery(current)
            assert rig.tick() == (S if normal else F), currents
