"""Trip and recover are reported at the first tick at or after the model's transition.

Each test drives one guard on a manual clock: samples every 1/16 s at known times
(off the tick grid), ticks every 0.25 s. The model's own transition time
(``model.since``, the time of the sample that tripped / recovered it) is checked
against the closed form, and the tree must report the trip and the recovery at
the first tick at or after it; the ``trip`` / ``recover`` events carry that
tick's time. Before the fix the peak latch held a trip that had already been
reported for one more tick, so every recovery came one tick (here 0.25 s) late.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import pytest

from canguard.engine.gate import TaskGate
from canguard.io.frame import Frame
from test_engine import SET_STATE_IDS, bms_frame
from test_engine import Rig as EngineRig
from treekit import F, Rig, S, Status, find, xml_tree

START = 1000.0
TICK_S = 0.25
SAMPLE_S = 1.0 / 16.0
OFFSET_S = 1.0 / 32.0
"""Samples sit half a sample period off the grid, so no sample shares a tick's time."""


def tick_at_or_after(t: float) -> float:
    """The first tick of the grid (START + k·TICK_S) at or after ``t``."""
    return START + math.ceil((t - START) / TICK_S - 1e-9) * TICK_S


def drive(
    rig: Rig,
    feed: Callable[[float, float], None],
    current: Callable[[float], float],
    until_s: float,
) -> list[tuple[float, Status]]:
    """Feed ``current(t - START)`` every SAMPLE_S and tick every TICK_S up to ``until_s``; (tick time, status)."""
    out: list[tuple[float, Status]] = []
    n_ticks = int(until_s / TICK_S) + 1
    k = 0
    for i in range(1, n_ticks):  # the first tick after the first sample (before it: no data)
        t_tick = START + i * TICK_S
        while START + OFFSET_S + k * SAMPLE_S < t_tick:
            t = START + OFFSET_S + k * SAMPLE_S
            rig.clock.set(t)
            feed(t, current(t - START))
            k += 1
        rig.clock.set(t_tick)
        out.append((t_tick, rig.tick()))
    return out


def edges(statuses: list[tuple[float, Status]]) -> list[tuple[float, Status]]:
    """The ticks at which the status changed (the first tick counts when it fails)."""
    out = []
    prev: Status | None = S
    for t, st in statuses:
        if st != prev:
            out.append((t, st))
        prev = st
    return out


def event_times(rig: Rig) -> list[tuple[str, float]]:
    """(event, t) of every trip / recover."""
    return [(e["event"], e["t"]) for e in rig.trips()]


class TestIsCurrentSafe:
    """Hysteresis 35 / 25 A: trip at the first sample >= 35 A, recover at the first <= 25 A."""

    def test_recovery_at_the_first_tick_after_the_recovering_sample(self, tmp_path: Path) -> None:
        """40 A from 0.5 s, 30 A (held) from 1.5 s, 20 A from 2.6 s: FAILURE at 0.75 s, SUCCESS again at 2.75 s."""
        rig = Rig(start=START)
        loaded = rig.load_text(
            tmp_path,
            xml_tree('<IsCurrentSafe name="guard" topic_name="axis0" overcurrent_threshold="35" '
                     'recovery_threshold="25"/>'),
        )

        def current(dt: float) -> float:
            return 10.0 if dt < 0.5 else 40.0 if dt < 1.5 else 30.0 if dt < 2.6 else 20.0

        statuses = drive(rig, lambda t, v: rig.feed("axis0", "current", v, t), current, 4.0)
        model = find(loaded, "guard").model
        t_trip, t_rec = START + 0.53125, START + 2.65625  # first samples at 40 A and at 20 A
        assert model.since == t_rec
        assert edges(statuses) == [(tick_at_or_after(t_trip), F), (tick_at_or_after(t_rec), S)]
        assert edges(statuses) == [(START + 0.75, F), (START + 2.75, S)]
        assert event_times(rig) == [("trip", START + 0.75), ("recover", START + 2.75)]

    def test_recover_after_counts_from_the_model_transition(self, tmp_path: Path) -> None:
        """recover_after=0.3: the model recovers 0.3 s after the first sample <= 25 A; the tree at the next tick."""
        rig = Rig(start=START)
        loaded = rig.load_text(
            tmp_path,
            xml_tree('<IsCurrentSafe name="guard" topic_name="axis0" recover_after="0.3"/>'),
        )

        def current(dt: float) -> float:
            return 40.0 if 0.5 <= dt < 1.5 else 10.0

        statuses = drive(rig, lambda t, v: rig.feed("axis0", "current", v, t), current, 3.0)
        t_rec = find(loaded, "guard").model.since
        # first sample <= 25 A at 1.53125 s; 0.3 s later, the first sample at or after 1.83125 s: 1.84375 s
        assert t_rec == START + 1.84375
        assert edges(statuses)[-1] == (START + 2.0, S)
        assert event_times(rig)[-1] == ("recover", START + 2.0)


class TestIsJointEffortNormal:
    """Plain limit per joint: recovered as soon as every joint is back at or below max_effort."""

    def test_recovery_at_the_first_tick_after_the_joint_is_back(self, tmp_path: Path) -> None:
        """axis2 at 120 N·m from 0.6 s to 1.7 s: FAILURE at 0.75 s, SUCCESS again at 1.75 s."""
        rig = Rig(start=START)
        rig.load_text(tmp_path, xml_tree('<IsJointEffortNormal topic_name="/joint_states" max_effort="100"/>'))

        def feed(t: float, v: float) -> None:
            for i, e in enumerate((10.0, 20.0, v, 30.0)):
                rig.feed("/joint_states", f"axis{i}", e, t)

        statuses = drive(rig, feed, lambda dt: 120.0 if 0.6 <= dt < 1.7 else 50.0, 3.0)
        # first samples at 120 and back at 50: 0.65625 s and 1.71875 s
        assert edges(statuses) == [(tick_at_or_after(START + 0.65625), F), (tick_at_or_after(START + 1.71875), S)]
        assert edges(statuses) == [(START + 0.75, F), (START + 1.75, S)]
        assert event_times(rig) == [("trip", START + 0.75), ("recover", START + 1.75)]


class TestIsI2tSafe:
    """Leaky bucket 6 A continuous, 12 A for 1 s (S = 108 A²s), recovery below 50 %."""

    def test_recovery_at_the_first_tick_after_cooling_below_the_fraction(self, tmp_path: Path) -> None:
        """12 A from 0 s, 0 A from 1.05 s: the bucket trips at 1.03125 s, cools below 54 A²s at 2.84375 s.

        Held-current integration from the first sample (1/32 s): 108 A²s reached at 1/32 + 1 s;
        the 12 A held until the first 0 A sample (1.09375 s) adds 6.75 A²s (114.75), which
        cools at 36 A²s/s: exactly 54 at 2.78125 s (not below), 51.75 at the next sample.
        """
        rig = Rig(start=START)
        loaded = rig.load_text(
            tmp_path,
            xml_tree('<IsI2tSafe name="i2t" topic_name="axis0" continuous_current="6" peak_current="12" '
                     'peak_time="1"/>'),
        )
        statuses = drive(rig, lambda t, v: rig.feed("axis0", "current", v, t), lambda dt: 12.0 if dt < 1.05 else 0.0,
                         4.0)
        assert find(loaded, "i2t").model.since == START + 2.84375
        assert edges(statuses) == [(tick_at_or_after(START + 1.03125), F), (tick_at_or_after(START + 2.84375), S)]
        assert edges(statuses) == [(START + 1.25, F), (START + 3.0, S)]
        assert event_times(rig) == [("trip", START + 1.25), ("recover", START + 3.0)]


class TestPeakLatch:
    """The latch still reports a trip that began and ended between two ticks, exactly once."""

    @pytest.mark.parametrize(
        "xml",
        [
            '<IsCurrentSafe topic_name="axis0"/>',
            '<IsCurrentNormal topic_name="axis0" max_current="30"/>',
        ],
    )
    def test_spike_between_ticks_fails_one_tick(self, tmp_path: Path, xml: str) -> None:
        """A one-sample 50 A spike at 0.59375 s fails the tick at 0.75 s only."""
        rig = Rig(start=START)
        rig.load_text(tmp_path, xml_tree(xml))
        statuses = drive(rig, lambda t, v: rig.feed("axis0", "current", v, t),
                         lambda dt: 50.0 if 0.58 < dt < 0.6 else 10.0, 2.0)
        assert edges(statuses) == [(START + 0.75, F), (START + 1.0, S)]


class TestEngine:
    """End to end: the engine ticks at once on the recovering sample and resumes the task then."""

    def test_task_resumes_at_the_recovering_frame(self, tmp_path: Path) -> None:
        """The bundled tree (IsCurrentSafe 35 / 25 A on the pack): 25 A at t_rec resumes the task frames at t_rec."""
        rig = EngineRig(tmp_path)
        rig.run(rig.t + 0.2)
        t_over = rig.t + 0.001
        rig.feed(bms_frame(t_over, 40.0))
        rig.run(t_over + 0.1, pack_a=30.0)
        assert rig.engine.gate.state != TaskGate.RUNNING
        t_rec = rig.t + 0.002
        rig.feed(bms_frame(t_rec, 25.0))
        rig.engine.advance(t_rec)  # nothing is due yet: only flushes the events
        recover = [e for e in rig.events.named("recover") if e["t"] >= t_over]
        assert [e["t"] for e in recover] == [t_rec]
        assert rig.engine.gate.state == TaskGate.RUNNING
        resumed: list[Frame] = rig.sent(SET_STATE_IDS, since=t_rec)
        assert resumed and resumed[0].t == t_rec
