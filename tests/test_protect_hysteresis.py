"""Hysteresis (IsCurrentSafe) and Threshold (IsCurrentNormal): edges, persistence, run-time thresholds."""

from __future__ import annotations

import math

import pytest
from tests.feed import step

from canguard.protect import Hysteresis, InrushBlanking, Threshold


def feed(model: Hysteresis | Threshold, values: list[float], t0: float = 0.0, dt: float = 0.01) -> list[bool]:
    """Feed ``values`` every ``dt`` from ``t0``; return the tripped state after each."""
    out = []
    for i, v in enumerate(values):
        step(model, v, t0 + i * dt)
        out.append(model.tripped)
    return out


class TestHysteresis:
    """Trips at |I| >= overcurrent, recovers only at |I| <= recovery."""

    def test_defaults_match_the_design_note(self) -> None:
        """The defaults are 35 A to trip and 25 A to recover."""
        model = Hysteresis()
        assert (model.overcurrent_a, model.recovery_a) == (35.0, 25.0)

    def test_trips_exactly_at_the_overcurrent_threshold(self) -> None:
        """34.999 A is fine, 35 A trips."""
        model = Hysteresis(35.0, 25.0)
        assert feed(model, [34.999, 35.0]) == [False, True]

    def test_recovers_exactly_at_the_recovery_threshold(self) -> None:
        """Once tripped, 25.001 A holds the trip and 25 A recovers."""
        model = Hysteresis(35.0, 25.0)
        assert feed(model, [40.0, 30.0, 25.001, 25.0]) == [True, True, True, False]

    def test_negative_currents_count_by_magnitude(self) -> None:
        """A discharge current of −36 A trips like +36 A."""
        model = Hysteresis(35.0, 25.0)
        assert feed(model, [-36.0, -26.0, -24.0]) == [True, True, False]

    def test_equal_thresholds_are_allowed(self) -> None:
        """With both thresholds at 30 A the model trips at 30 A and recovers below it at once."""
        model = Hysteresis(30.0, 30.0)
        assert feed(model, [30.0, 29.0]) == [True, False]

    def test_recovery_above_overcurrent_is_rejected(self) -> None:
        """recovery_a > overcurrent_a raises ValueError naming both values."""
        with pytest.raises(ValueError, match=r"recovery_a \(30\.0 A\).*overcurrent_a \(20\.0 A\)"):
            Hysteresis(20.0, 30.0)

    @pytest.mark.parametrize(
        "kwargs", [{"overcurrent_a": -1.0}, {"trip_after_s": -0.1}, {"recover_after_s": -1.0}]
    )
    def test_negative_values_are_rejected(self, kwargs: dict[str, float]) -> None:
        """A negative threshold or delay raises ValueError naming it."""
        with pytest.raises(ValueError, match=next(iter(kwargs))):
            Hysteresis(**{"overcurrent_a": 35.0, "recovery_a": 0.0, **kwargs})

    def test_trip_after_requires_a_held_overcurrent(self) -> None:
        """With trip_after_s = 0.1 a 50 ms burst does not trip, a 100 ms one does."""
        model = Hysteresis(35.0, 25.0, trip_after_s=0.1)
        assert not any(feed(model, [40.0] * 6 + [30.0]))
        states = feed(model, [40.0] * 11, t0=1.0)
        assert states[-1] and not states[-2]

    def test_a_dip_restarts_the_trip_timer(self) -> None:
        """A sample below the threshold in the middle of an overcurrent restarts trip_after_s."""
        model = Hysteresis(35.0, 25.0, trip_after_s=0.1)
        assert not any(feed(model, [40.0] * 8 + [34.0] + [40.0] * 8))

    def test_recover_after_requires_a_held_recovery(self) -> None:
        """With recover_after_s = 0.2 recovery waits 200 ms of |I| <= recovery."""
        model = Hysteresis(35.0, 25.0, recover_after_s=0.2)
        states = feed(model, [40.0] + [20.0] * 25)
        assert states.index(False) == 21  # first low sample at index 1, +0.2 s = index 21

    def test_gap_restarts_persistence(self) -> None:
        """Two overcurrent samples 5 s apart with max_gap_s = 0.5 do not make a held overcurrent."""
        model = Hysteresis(35.0, 25.0, trip_after_s=1.0, max_gap_s=0.5)
        step(model, 40.0, 0.0)
        assert not any(feed(model, [40.0] * 10, t0=5.0, dt=0.1))
        assert step(model, 40.0, 6.0) is True

    def test_set_thresholds_applies_from_the_next_sample(self) -> None:
        """Lowering the trip threshold at run time trips at the next sample above it."""
        model = Hysteresis(35.0, 25.0)
        assert feed(model, [30.0]) == [False]
        model.set_thresholds(28.0, 20.0)
        assert feed(model, [30.0], t0=1.0) == [True]
        with pytest.raises(ValueError, match="recovery_a"):
            model.set_thresholds(10.0, 20.0)
        assert (model.overcurrent_a, model.recovery_a) == (28.0, 20.0)

    def test_snapshot_reports_value_threshold_and_edge_time(self) -> None:
        """The snapshot carries |I|, the threshold in force, % of it and the trip time."""
        model = Hysteresis(40.0, 25.0)
        step(model, -20.0, 1.0)
        step(model, -50.0, 2.0)
        snap = model.snapshot()
        assert (snap.value, snap.threshold, snap.since, snap.reason) == (50.0, 40.0, 2.0, "overcurrent")
        assert snap.level_pct == pytest.approx(125.0)


class TestHysteresisWithInrush:
    """Inrush blanking raises (or removes) the overcurrent threshold right after a motor start."""

    def test_inrush_threshold_applies_during_the_window(self) -> None:
        """After a start, 50 A is tolerated under a 60 A inrush threshold, 65 A is not."""
        model = Hysteresis(35.0, 25.0, inrush=InrushBlanking(2.0, 0.3, 60.0))
        feed(model, [0.0] * 40)  # stopped for 0.4 s
        assert not any(feed(model, [50.0] * 20, t0=1.0))  # 0.2 s inside the 0.3 s window
        assert feed(model, [65.0], t0=1.2) == [True]

    def test_normal_threshold_returns_after_the_window(self) -> None:
        """Once the inrush window is over, 50 A trips against the normal 35 A threshold."""
        model = Hysteresis(35.0, 25.0, inrush=InrushBlanking(2.0, 0.3, 60.0))
        feed(model, [0.0] * 40)
        states = feed(model, [50.0] * 40, t0=1.0)
        assert states.index(True) == 30  # t = 1.3 s, the end of the window

    def test_no_inrush_threshold_turns_the_check_off(self) -> None:
        """Without an inrush threshold even 500 A is not checked inside the window."""
        model = Hysteresis(35.0, 25.0, inrush=InrushBlanking(2.0, 0.3))
        feed(model, [0.0] * 40)
        assert not any(feed(model, [500.0] * 30, t0=1.0))
        assert model.snapshot().threshold == math.inf
        assert feed(model, [500.0], t0=1.3) == [True]

    def test_no_blanking_when_running_from_the_start(self) -> None:
        """A motor already above start current on the first sample is checked normally (fail safe)."""
        model = Hysteresis(35.0, 25.0, inrush=InrushBlanking(2.0, 0.3))
        assert feed(model, [50.0]) == [True]


class TestThreshold:
    """A plain limit: tripped while |v| > max_value, with the peak latch of poll."""

    def test_equal_to_the_limit_is_fine(self) -> None:
        """|v| == max_value does not trip, anything above does."""
        model = Threshold(30.0)
        assert feed(model, [30.0, -30.0, 30.001, 29.0]) == [False, False, True, False]

    def test_one_frame_spike_is_reported_at_the_next_poll(self) -> None:
        """A single 100 A frame between two ticks makes exactly the next poll report an overcurrent."""
        model = Threshold(30.0)
        feed(model, [10.0, 100.0, 10.0])
        assert model.tripped is False
        assert model.poll(0.05).reason == "overcurrent"
        assert model.poll(0.06).tripped is False

    def test_negative_limit_is_rejected(self) -> None:
        """A negative max_value raises ValueError naming it."""
        with pytest.raises(ValueError, match="max_value"):
            Threshold(-1.0)
