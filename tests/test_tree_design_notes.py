"""The eight trees of the design notes, as shipped in config/trees/, behave as the notes say.

Each runs on a manual clock with scripted samples fed as runs of one (``tests/feed.dispatch``).
"""

from __future__ import annotations

import math

import pytest

import canguard.bt.nodes.control as profile_module
from treekit import TREES, F, R, Rig, S, find


class TestPeriodicHealthCheck:
    """Note 000: Sequence[IsElapsedTimeCompare(60, GTE), PerformDiagnostics, ResetTimer]."""

    def test_diagnostics_every_60_s(self) -> None:
        """Diagnostics run 60 s after the first tick, then every 60 s (ticks every second for 5 min)."""
        rig = Rig(start=5000.0)
        rig.load(TREES / "periodic_health_check.xml")
        runs = []
        for _ in range(301):
            before = len(rig.labels())
            status = rig.tick()
            if len(rig.labels()) > before:
                runs.append(rig.now() - 5000.0)
                assert status == S
            else:
                assert status == F
            rig.advance(1.0)
        assert runs == [60.0, 120.0, 180.0, 240.0, 300.0]
        assert set(rig.labels()) == {"PerformDiagnostics"}

    def test_irregular_ticks_measure_from_the_reset(self) -> None:
        """With sparse ticks the next run is 60 s after the tick that ran the diagnostics."""
        rig = Rig(start=0.0)
        rig.load(TREES / "periodic_health_check.xml")
        rig.tick()  # first tick at t=0 starts the default timer
        rig.clock.set(70.0)
        assert rig.tick() == S  # 70 s >= 60 s, timer reset at 70
        rig.clock.set(125.0)
        assert rig.tick() == F  # only 55 s since the reset
        rig.clock.set(130.0)
        assert rig.tick() == S


class TestCooldownRecovery:
    """Note 000: Sequence[IsCooldownElapsed(10, {last_recovery_time}), PerformRecovery(output_time)]."""

    def test_recovery_at_most_every_10_s(self) -> None:
        """Ticked every 0.5 s for a minute, recovery runs at 0, 10, 20, ... s and never closer."""
        rig = Rig(start=2000.0)
        loaded = rig.load(TREES / "cooldown_recovery.xml")
        times = []
        for _ in range(121):
            before = len(rig.labels())
            rig.tick()
            if len(rig.labels()) > before:
                times.append(rig.now() - 2000.0)
            rig.advance(0.5)
        assert times == [0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0]
        assert find(loaded, "PerformRecovery").blackboard_client.get("output_time") == 2060.0

    def test_recovery_runs_at_once_when_never_run(self) -> None:
        """No {last_recovery_time} yet means "never executed": the first tick recovers."""
        rig = Rig()
        rig.load(TREES / "cooldown_recovery.xml")
        assert rig.tick() == S
        assert rig.labels() == ["PerformRecovery"]


class TestTimeWindowedAction:
    """Note 000: PerformTimedAction only between 10 s and 300 s after {mission_start_time}."""

    def test_window_from_the_recorded_mission_start(self) -> None:
        """Mission records the start at its first tick; the action runs from 10 s to 300 s only."""
        rig = Rig(start=10_000.0)
        rig.load(TREES / "time_windowed_action.xml")
        ran = []
        for _ in range(400):
            before = len(rig.labels())
            rig.tick()
            if len(rig.labels()) > before:
                ran.append(rig.now() - 10_000.0)
            rig.advance(1.0)
        assert ran == [float(t) for t in range(10, 301)]

    def test_note_tree_with_the_blackboard_written_elsewhere(self) -> None:
        """The note's TimeWindowedAction alone reads {mission_start_time} written by someone else."""
        import py_trees

        rig = Rig(start=500.0)
        rig.load(TREES / "time_windowed_action.xml", main="TimeWindowedAction")
        assert rig.tick() == F  # no mission start yet
        py_trees.blackboard.Blackboard.set("/mission_start_time", 495.0)
        assert rig.tick() == F  # 5 s
        rig.advance(5.0)
        assert rig.tick() == S  # 10 s
        rig.advance(290.0)
        assert rig.tick() == S  # 300 s
        rig.advance(0.5)
        assert rig.tick() == F


class TestProfiledNavigation:
    """Note 003: Profile writing {nav_tick_ms} {nav_avg_ms} {nav_max_ms} around NavigateToPose."""

    def test_outputs_written_and_status_transparent(self) -> None:
        """Every tick writes the three keys; the tree returns NavigateToPose's SUCCESS."""
        import py_trees

        rig = Rig()
        rig.load(TREES / "profiling.xml")
        for _ in range(5):
            assert rig.tick() == S
        bb = py_trees.blackboard.Blackboard
        last, avg, peak = bb.get("/nav_tick_ms"), bb.get("/nav_avg_ms"), bb.get("/nav_max_ms")
        assert all(isinstance(v, float) and v >= 0.0 for v in (last, avg, peak))
        assert avg <= peak and last <= peak
        assert rig.node("Profile").count == 5
        assert rig.labels() == ["NavigateToPose"] * 5


class TestPathBottleneck:
    """Note 003, 4.1: ComputePath and FollowPath each under their own Profile."""

    def test_each_stage_timed_separately(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """With a scripted clock, {path_time} and {follow_time} hold each stage's own duration."""
        import py_trees

        ticks = iter([0.0, 0.030, 1.0, 1.002])  # ComputePath 30 ms, FollowPath 2 ms
        monkeypatch.setattr(profile_module, "perf_counter", lambda: next(ticks))
        rig = Rig()
        rig.load(TREES / "profiling.xml", main="PathBottleneck")
        assert rig.tick() == S
        assert py_trees.blackboard.Blackboard.get("/path_time") == pytest.approx(30.0)
        assert py_trees.blackboard.Blackboard.get("/follow_time") == pytest.approx(2.0)
        assert rig.labels() == ["ComputePath", "FollowPath"]


class TestLatencyWarning:
    """Note 003, 4.2: Profile(last_ms={tick_time}) + IsValueBelow({tick_time}, 50)."""

    def test_fails_when_processing_takes_50_ms_or_more(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """12 ms passes, 50 ms and 75 ms fail, 3 ms passes again."""
        durations = [0.012, 0.050, 0.075, 0.003]
        clock = iter(x for d in durations for x in (0.0, d))
        monkeypatch.setattr(profile_module, "perf_counter", lambda: next(clock))
        rig = Rig()
        rig.load(TREES / "profiling.xml", main="LatencyWarning")
        assert [rig.tick() for _ in durations] == [S, F, F, S]
        assert rig.node("Profile").max_ms == pytest.approx(75.0)


class TestCurrentProtectedOperation:
    """Note 004, 4.1: ReactiveSequence[IsCurrentSafe(/battery_state, 35, 25), ExecuteTask]."""

    def run(self, rig: Rig, currents: list[float]) -> list[object]:
        out = []
        for i in currents:
            rig.advance(0.01)
            rig.battery(i)
            out.append(rig.tick())
        return out

    def test_trips_above_35_and_recovers_only_at_25(self) -> None:
        """The task runs at 20 A, stops at 36 A, stays stopped down to 25.1 A, runs again from 25 A.

        The tick right after the recovering sample (25 A) already runs the task: a trip the
        previous tick reported is not held past the recovery.
        """
        rig = Rig()
        rig.load(TREES / "protected_operation.xml")
        statuses = self.run(rig, [20.0, 34.9, 36.0, 30.0, 25.1, 25.1, 25.0, 25.0, 10.0])
        assert statuses == [R, R, F, F, F, F, R, R, R]
        halts = [c for c in rig.task.calls if c[0] == "halt"]
        assert len(halts) == 1 and halts[0][1] == "ExecuteTask"
        assert [(e["event"], e["reason"]) for e in rig.trips()] == [("trip", "overcurrent"), ("recover", "")]
        trip = rig.trips()[0]
        assert trip["node"] == "IsCurrentSafe" and trip["source"] == "/battery_state"
        assert trip["value"] == 36.0 and trip["threshold"] == 35.0

    def test_discharge_current_is_taken_as_magnitude(self) -> None:
        """A discharge of -36 A trips like +36 A (BatteryState current is negative when discharging)."""
        rig = Rig()
        rig.load(TREES / "protected_operation.xml")
        assert self.run(rig, [-20.0, -36.0]) == [R, F]

    def test_spike_between_ticks_is_not_lost(self) -> None:
        """A one-frame 50 A spike between two ticks fails the next tick even though the current is back."""
        rig = Rig()
        rig.load(TREES / "protected_operation.xml")
        assert self.run(rig, [20.0]) == [R]
        rig.advance(0.002)
        rig.battery(50.0)
        rig.advance(0.002)
        rig.battery(20.0)
        assert rig.tick() == F

    @pytest.mark.parametrize(
        ("setup", "reason"),
        [
            (lambda rig: None, "no_data"),
            (lambda rig: (rig.battery(20.0), rig.advance(0.6)), "stale"),
            (lambda rig: rig.battery(20.0, present=0.0), "not_present"),
            (
                lambda rig: (
                    rig.feed("/battery_state", "present", 1.0),
                    rig.feed("/battery_state", "current", math.nan, reason="nan"),
                ),
                "nan",
            ),
        ],
        ids=["no_data", "stale", "not_present", "nan"],
    )
    def test_fail_safe_on_bad_data(self, setup, reason: str) -> None:  # type: ignore[no-untyped-def]
        """No data, stale data, present = 0 and NaN all fail the guard and keep the task stopped."""
        rig = Rig()
        rig.load(TREES / "protected_operation.xml")
        setup(rig)
        assert rig.tick() == F
        assert rig.failure_reason() == reason
        if reason == "no_data":
            assert not rig.trips(), "no data yet fails the guard but is not a trip"
        assert not [c for c in rig.task.calls if c[0] == "run"]


class TestMultiCurrentMonitoring:
    """Note 004, 4.2: ReactiveSequence[IsCurrentNormal(40), IsJointEffortNormal(150), ContinueOperation]."""

    def healthy(self, rig: Rig, battery: float = 20.0, efforts: tuple[float, ...] = (10.0, -20.0, 30.0, 0.0)) -> None:
        rig.advance(0.01)
        rig.battery(battery)
        rig.joints(*efforts)

    def test_runs_while_everything_is_normal(self) -> None:
        """40 A and 150 N·m exactly are still normal; ContinueOperation runs every tick."""
        rig = Rig()
        rig.load(TREES / "multi_current_monitoring.xml")
        self.healthy(rig, 40.0, (150.0, -150.0, 0.0, 1.0))
        assert rig.tick() == S
        assert rig.labels() == ["ContinueOperation"]

    @pytest.mark.parametrize(
        ("battery", "efforts", "node", "reason"),
        [
            (40.5, (0.0, 0.0, 0.0, 0.0), "IsCurrentNormal", "overcurrent"),
            (-41.0, (0.0, 0.0, 0.0, 0.0), "IsCurrentNormal", "overcurrent"),
            (10.0, (0.0, 0.0, 151.0, 0.0), "IsJointEffortNormal", "overcurrent"),
            (10.0, (0.0, -150.5, 0.0, 0.0), "IsJointEffortNormal", "overcurrent"),
        ],
    )
    def test_fails_on_any_excess(self, battery: float, efforts: tuple[float, ...], node: str, reason: str) -> None:
        """BMS |I| > 40 A or any joint |effort| > 150 fails the tree; ContinueOperation does not run."""
        rig = Rig()
        rig.load(TREES / "multi_current_monitoring.xml")
        self.healthy(rig)
        assert rig.tick() == S
        self.healthy(rig, battery, efforts)
        assert rig.tick() == F
        assert rig.labels() == ["ContinueOperation"]
        assert rig.trips()[-1]["node"] == node and rig.trips()[-1]["reason"] == reason

    def test_one_stale_joint_fails(self) -> None:
        """A joint that stops reporting makes the tree fail after max_age, naming the joint."""
        rig = Rig()
        rig.load(TREES / "multi_current_monitoring.xml")
        self.healthy(rig)
        assert rig.tick() == S
        for _ in range(6):
            rig.advance(0.1)
            rig.battery(20.0)
            for i in (0, 1, 3):
                rig.feed("/joint_states", f"axis{i}", 1.0)
        assert rig.tick() == F
        trip = rig.trips()[-1]
        assert (trip["node"], trip["signal"], trip["reason"]) == ("IsJointEffortNormal", "axis2", "stale")

    def test_nan_and_not_present(self) -> None:
        """A NaN effort fails; battery present = 0 fails; both recover with good data."""
        rig = Rig()
        rig.load(TREES / "multi_current_monitoring.xml")
        self.healthy(rig)
        assert rig.tick() == S
        rig.feed("/joint_states", "axis1", math.nan, reason="nan")
        assert rig.tick() == F
        self.healthy(rig)
        assert rig.tick() == S
        rig.battery(20.0, present=0.0)
        assert rig.tick() == F
        assert rig.trips()[-1]["reason"] == "not_present"
        self.healthy(rig)
        assert rig.tick() == S

    def test_no_joint_data_fails(self) -> None:
        """Battery fine but no joint data at all: FAILURE (no_data)."""
        rig = Rig()
        rig.load(TREES / "multi_current_monitoring.xml")
        rig.battery(10.0)
        assert rig.tick() == F
        assert rig.failure_reason() == "no_data"
        assert not rig.trips(), "no data yet fails the guard but is not a trip"
