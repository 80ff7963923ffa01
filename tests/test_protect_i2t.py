"""I²t models: trip and cooling times against the closed forms, persistence, robustness."""

from __future__ import annotations

import json
import math
import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tests.feed import step

from canguard.protect import LeakyI2t, ThermalI2t, thermal_tau

DT = 0.01
CURRENTS = [12.5, 15.0, 20.0, 30.0, 60.0]
GOOD = {"continuous_a": 6.0, "peak_a": 12.0, "peak_time_s": 1.0}


def trip_time(model: LeakyI2t | ThermalI2t, current: float, t0: float = 0.0, dt: float = DT) -> float:
    """Seconds from ``t0`` until ``model`` trips at a constant ``current`` sampled every ``dt``."""
    t = t0
    step(model, current, t)
    while not model.tripped:
        t += dt
        step(model, current, t)
        assert t - t0 < 1e4
    return t - t0


def recover_time(model: LeakyI2t | ThermalI2t, t0: float, dt: float = DT) -> float:
    """Seconds from ``t0`` until ``model`` recovers at 0 A (the held current before t0 counts up to t0)."""
    t = t0
    step(model, 0.0, t)
    while model.tripped:
        t += dt
        step(model, 0.0, t)
        assert t - t0 < 1e4
    return t - t0


def hold(model: LeakyI2t | ThermalI2t, current: float, t0: float, duration: float, dt: float = DT) -> float:
    """Feed ``current`` from ``t0`` for ``duration`` seconds; return the end time."""
    n = round(duration / dt)
    for i in range(n + 1):
        step(model, current, t0 + i * dt)
    return t0 + n * dt


class TestLeakyI2t:
    """The leaky bucket: A += (I² − I_cont²)·dt, floored at 0, trips at S."""

    def test_trip_level_matches_the_datasheet_example(self) -> None:
        """12 A peak, 6 A continuous and 1 s give S = 108 A²s."""
        assert LeakyI2t(6.0, 12.0, 1.0).trip_level == pytest.approx(108.0)

    @pytest.mark.parametrize("current", CURRENTS)
    def test_trip_time_from_cold(self, current: float) -> None:
        """From cold the trip comes within one sample period after S / (I² − I_cont²)."""
        expected = 108.0 / (current**2 - 36.0)
        measured = trip_time(LeakyI2t(6.0, 12.0, 1.0), current)
        assert expected - 1e-9 <= measured <= expected + DT + 1e-9

    @pytest.mark.parametrize("current", CURRENTS)
    def test_trip_time_does_not_depend_on_irregular_sampling(self, current: float) -> None:
        """With random spacing up to 20 ms the trip still comes within one sample of the closed form."""
        rng = random.Random(current)
        model = LeakyI2t(6.0, 12.0, 1.0)
        t = 0.0
        step(model, current, t)
        while not model.tripped:
            t += rng.uniform(0.001, 0.02)
            step(model, current, t)
        expected = 108.0 / (current**2 - 36.0)
        assert expected - 1e-9 <= t <= expected + 0.02

    @pytest.mark.parametrize("current", CURRENTS)
    def test_trip_time_from_warm(self, current: float) -> None:
        """After 0.5 s at 10 A the trip takes (S − 64·0.5) / (I² − 36)."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        t = hold(model, 10.0, 0.0, 0.5)
        assert model.accumulator == pytest.approx(32.0)
        expected = (108.0 - 32.0) / (current**2 - 36.0)
        measured = trip_time(model, current, t)
        assert expected - 1e-9 <= measured <= expected + DT + 1e-9

    def test_cooling_time_after_a_trip(self) -> None:
        """After a trip at 0 A it recovers once A − I_cont²·t falls below S/2."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        t = trip_time(model, 20.0)
        a_trip = model.accumulator
        expected = (a_trip - 54.0) / 36.0
        measured = recover_time(model, t)
        assert expected - 1e-9 <= measured <= expected + DT + 1e-9

    def test_never_trips_at_or_below_continuous(self) -> None:
        """At the continuous current the accumulator stays at zero for an hour."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        hold(model, 6.0, 0.0, 3600.0, dt=1.0)
        assert model.accumulator == 0.0 and not model.tripped

    def test_accumulator_floors_at_zero(self) -> None:
        """Cooling far longer than needed leaves the accumulator at exactly zero, not below."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        hold(model, 20.0, 0.0, 0.1)
        hold(model, 0.0, 0.2, 100.0, dt=1.0)
        assert model.accumulator == 0.0

    def test_gap_longer_than_max_gap_integrates_only_max_gap(self) -> None:
        """A 10 s hole in the data with max_gap_s = 0.5 heats like 0.5 s, not like 10 s."""
        model = LeakyI2t(6.0, 12.0, 1.0, max_gap_s=0.5)
        step(model, 10.0, 0.0)
        step(model, 10.0, 10.0)
        assert model.accumulator == pytest.approx(64.0 * 0.5)
        assert not model.tripped

    def test_step_back_in_time_is_ignored(self) -> None:
        """A sample older than the latest one neither heats nor moves the held current."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        step(model, 10.0, 1.0)
        step(model, 100.0, 0.5)
        step(model, 10.0, 2.0)
        assert model.accumulator == pytest.approx(64.0)

    @pytest.mark.parametrize(
        ("kwargs", "name"),
        [
            ({"continuous_a": 0.0, "peak_a": 12.0, "peak_time_s": 1.0}, "continuous_a"),
            ({"continuous_a": 6.0, "peak_a": 6.0, "peak_time_s": 1.0}, "peak_a"),
            ({"continuous_a": 6.0, "peak_a": 12.0, "peak_time_s": -1.0}, "peak_time_s"),
            ({**GOOD, "recover_fraction": 1.0}, "recover_fraction"),
            ({**GOOD, "max_gap_s": 0.0}, "max_gap_s"),
        ],
    )
    def test_bad_parameters_are_named(self, kwargs: dict[str, float], name: str) -> None:
        """Every invalid parameter raises ValueError naming that parameter."""
        with pytest.raises(ValueError, match=name):
            LeakyI2t(**kwargs)

    def test_restore_cools_for_the_downtime(self) -> None:
        """A state exported at A = 100 and restored after 1 s of downtime holds A = 100 − 36."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        model.restore({**model.export(), "accumulator": 100.0}, 0.0)
        state = json.loads(json.dumps(model.export()))
        fresh = LeakyI2t(6.0, 12.0, 1.0)
        fresh.restore(state, 1.0)
        assert fresh.accumulator == pytest.approx(64.0)

    def test_restore_keeps_a_trip_until_cooled_below_recovery(self) -> None:
        """A tripped state stays tripped after a short downtime and is clear after a long one."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        trip_time(model, 30.0)
        state = model.export()
        short, long_ = LeakyI2t(6.0, 12.0, 1.0), LeakyI2t(6.0, 12.0, 1.0)
        short.restore(state, 0.5)
        long_.restore(state, 1000.0)
        assert short.tripped and short.poll(0.0).tripped
        assert not long_.tripped and long_.accumulator == 0.0

    def test_negative_downtime_does_not_heat_or_cool(self) -> None:
        """A clock that went back across the restart restores the state as saved."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        model.restore({**model.export(), "accumulator": 50.0}, -30.0)
        assert model.accumulator == pytest.approx(50.0)

    def test_restore_from_other_parameters_carries_the_level(self) -> None:
        """A state saved with another S (or by a thermal model) keeps its fraction of the trip level."""
        other = LeakyI2t(5.0, 10.0, 2.0)
        other.restore({**other.export(), "accumulator": other.trip_level * 0.75}, 0.0)
        model = LeakyI2t(6.0, 12.0, 1.0)
        model.restore(other.export(), 0.0)
        assert model.level == pytest.approx(0.75)
        thermal = ThermalI2t(6.0, tau_s=10.0)
        thermal.restore({**thermal.export(), "accumulator": 0.4}, 0.0)
        model.restore(thermal.export(), 0.0)
        assert model.level == pytest.approx(0.4)

    @pytest.mark.parametrize(
        "state",
        [
            {},
            {"kind": "leaky", "params": {}, "accumulator": 1.0},
            {"kind": "magic", "params": {}, "accumulator": 1.0},
            {"kind": "leaky", "params": GOOD, "accumulator": -1},
            {"kind": "leaky", "params": GOOD, "accumulator": "x"},
        ],
    )
    def test_malformed_state_raises_and_leaves_the_model(self, state: dict[str, object]) -> None:
        """A malformed state raises ValueError and the model keeps its own state."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        hold(model, 10.0, 0.0, 0.5)
        before = model.accumulator
        with pytest.raises(ValueError, match="i2t state"):
            model.restore(state, 1.0)
        assert model.accumulator == before

    def test_set_hot_puts_the_model_at_the_trip_level(self) -> None:
        """set_hot trips the model at 100 % of S."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        model.set_hot()
        assert model.tripped and model.snapshot().level_pct == pytest.approx(100.0)

    def test_export_is_json(self) -> None:
        """export() survives a strict JSON round trip, infinite max_gap_s included."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        hold(model, 10.0, 0.0, 0.2)
        state = json.loads(json.dumps(model.export(), allow_nan=False))
        assert state["kind"] == "leaky" and state["t"] == pytest.approx(0.2)
        assert state["params"]["max_gap_s"] is None


class TestThermalI2t:
    """The first-order thermal image: θ' = (I²/I_cont² − θ)/τ, trips at θ >= 1."""

    def test_tau_follows_from_the_peak_figures(self) -> None:
        """τ = t_peak / ln(I_peak² / (I_peak² − I_cont²)) and the model trips at the peak point."""
        model = ThermalI2t(6.0, 12.0, 1.0)
        assert model.tau_s == pytest.approx(1.0 / math.log(144.0 / 108.0))
        assert model.tau_s == pytest.approx(thermal_tau(6.0, 12.0, 1.0))
        assert 1.0 - 1e-9 <= trip_time(model, 12.0) <= 1.0 + DT

    @pytest.mark.parametrize("current", CURRENTS)
    def test_trip_time_from_cold(self, current: float) -> None:
        """From cold the trip comes within one sample period after τ·ln(I² / (I² − I_cont²))."""
        model = ThermalI2t(6.0, tau_s=30.0)
        expected = 30.0 * math.log(current**2 / (current**2 - 36.0))
        measured = trip_time(model, current)
        assert expected - 1e-9 <= measured <= expected + DT + 1e-9

    @pytest.mark.parametrize("current", CURRENTS)
    def test_trip_time_from_warm(self, current: float) -> None:
        """After steady state at 4 A the trip takes τ·ln((I² − 16) / (I² − 36))."""
        model = ThermalI2t(6.0, 12.0, 1.0)
        t = hold(model, 4.0, 0.0, 20 * model.tau_s, dt=0.05)
        assert model.accumulator == pytest.approx(16.0 / 36.0, rel=1e-6)
        expected = model.tau_s * math.log((current**2 - 16.0) / (current**2 - 36.0))
        measured = trip_time(model, current, t)
        assert expected - 1e-6 <= measured <= expected + DT + 1e-6

    def test_cooling_uses_the_cooling_time_constant(self) -> None:
        """After a trip at 0 A it recovers after τ_cool·ln(θ_trip / 0.5)."""
        model = ThermalI2t(6.0, tau_s=10.0, tau_cool_s=40.0)
        t = trip_time(model, 20.0)
        theta = model.accumulator
        measured = recover_time(model, t)
        expected = 40.0 * math.log(theta / 0.5)
        assert expected - 1e-6 <= measured <= expected + DT + 1e-6

    def test_steady_state_below_continuous_never_trips(self) -> None:
        """At 0.99·I_cont θ settles below 1 and never trips."""
        model = ThermalI2t(6.0, tau_s=5.0)
        hold(model, 5.94, 0.0, 200.0, dt=0.1)
        assert model.accumulator == pytest.approx(0.99**2, rel=1e-6)
        assert not model.tripped

    def test_restore_cools_exponentially(self) -> None:
        """θ = 0.8 restored after one cooling time constant is 0.8/e."""
        model = ThermalI2t(6.0, tau_s=10.0, tau_cool_s=20.0)
        model.restore({**model.export(), "accumulator": 0.8}, 0.0)
        fresh = ThermalI2t(6.0, tau_s=10.0, tau_cool_s=20.0)
        fresh.restore(json.loads(json.dumps(model.export())), 20.0)
        assert fresh.accumulator == pytest.approx(0.8 / math.e)

    def test_restore_after_trip_and_downtime(self) -> None:
        """A model tripped at shutdown is still tripped after a downtime shorter than τ·ln(2θ)."""
        model = ThermalI2t(6.0, tau_s=10.0)
        trip_time(model, 20.0)
        state = model.export()
        theta = state["accumulator"]
        still = ThermalI2t(6.0, tau_s=10.0)
        still.restore(state, 0.9 * 10.0 * math.log(theta / 0.5))
        cool = ThermalI2t(6.0, tau_s=10.0)
        cool.restore(state, 1.1 * 10.0 * math.log(theta / 0.5))
        assert still.tripped and not cool.tripped

    @pytest.mark.parametrize(
        ("kwargs", "name"),
        [
            ({"continuous_a": 6.0}, "tau_s"),
            ({"continuous_a": 6.0, "peak_a": 12.0}, "peak_time_s"),
            ({"continuous_a": 6.0, "peak_a": 5.0, "peak_time_s": 1.0}, "peak_a"),
            ({"continuous_a": 6.0, "tau_s": 0.0}, "tau_s"),
            ({"continuous_a": 6.0, "tau_s": 1.0, "tau_cool_s": -2.0}, "tau_cool_s"),
            ({"continuous_a": -6.0, "tau_s": 1.0}, "continuous_a"),
        ],
    )
    def test_bad_parameters_are_named(self, kwargs: dict[str, float], name: str) -> None:
        """Missing or invalid parameters raise ValueError naming the parameter."""
        with pytest.raises(ValueError, match=name):
            ThermalI2t(**kwargs)

    def test_set_hot_trips_at_theta_one(self) -> None:
        """set_hot puts θ at 1 and trips, recording the given time."""
        model = ThermalI2t(6.0, tau_s=10.0)
        model.set_hot(5.0)
        assert model.accumulator == 1.0 and model.tripped and model.since == 5.0


samples_st = st.lists(
    st.tuples(st.floats(-1e6, 1e6), st.floats(-1e3, 1e6)), min_size=1, max_size=50
)


class TestI2tProperties:
    """Properties that hold for any input sequence."""

    @settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.differing_executors])
    @given(samples=samples_st, thermal=st.booleans())
    def test_accumulator_never_negative_or_nan(
        self, samples: list[tuple[float, float]], thermal: bool
    ) -> None:
        """Whatever the values and timestamps, the accumulator stays finite and >= 0."""
        model: LeakyI2t | ThermalI2t = (
            ThermalI2t(6.0, 12.0, 1.0, max_gap_s=0.5) if thermal else LeakyI2t(6.0, 12.0, 1.0)
        )
        for value, t in samples:
            step(model, value, t)
            assert math.isfinite(model.accumulator) and model.accumulator >= 0
            assert math.isfinite(model.snapshot().level_pct)

    @settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.differing_executors])
    @given(
        low=st.floats(6.5, 100.0),
        step=st.floats(0.5, 100.0),
        thermal=st.booleans(),
    )
    def test_trip_time_falls_as_current_rises(self, low: float, step: float, thermal: bool) -> None:
        """A higher constant current never trips later than a lower one."""

        def make() -> LeakyI2t | ThermalI2t:
            return ThermalI2t(6.0, 12.0, 1.0) if thermal else LeakyI2t(6.0, 12.0, 1.0)

        dt = 0.05
        assert trip_time(make(), low + step, dt=dt) <= trip_time(make(), low, dt=dt)
