"""I²t models as the config author and the state file meet them: parameter errors, the exported state, boundaries.

Written against the mutants ``scripts/mutation.sh`` left alive in ``protect/i2t.py``. Each test asserts
what a user sees: the message naming the wrong parameter (it reaches ``canguard check`` as a port
error), the exact fields of the state file, the level at which a trip ends, a restore that refuses a
malformed entry.
"""

from __future__ import annotations

import math

import pytest
from tests.feed import step

from canguard.protect.i2t import LeakyI2t, ThermalI2t, cooled_level


class TestParameterErrors:
    @pytest.mark.parametrize(("kwargs", "message"), [
        ({"continuous_a": -1, "peak_a": 20, "peak_time_s": 5}, "continuous_a must be a finite number > 0, got -1"),
        ({"continuous_a": 10, "peak_a": -1, "peak_time_s": 5}, "peak_a must be a finite number > 0, got -1"),
        ({"continuous_a": 10, "peak_a": 20, "peak_time_s": 0}, "peak_time_s must be a finite number > 0, got 0"),
        ({"continuous_a": 10, "peak_a": 20, "peak_time_s": 5, "recover_fraction": 0},
         "recover_fraction must be > 0 and < 1, got 0"),
        ({"continuous_a": 10, "peak_a": 20, "peak_time_s": 5, "recover_fraction": 1},
         "recover_fraction must be > 0 and < 1, got 1"),
        ({"continuous_a": 10, "peak_a": 10, "peak_time_s": 5}, "peak_a (10 A) must exceed continuous_a (10 A)"),
        ({"continuous_a": 10, "peak_a": 20, "peak_time_s": 5, "max_gap_s": 0},
         "max_gap_s must be > 0 (inf: no limit), got 0"),
    ])
    def test_leaky(self, kwargs: dict, message: str) -> None:
        with pytest.raises(ValueError) as err:
            LeakyI2t(**kwargs)
        assert str(err.value) == message

    @pytest.mark.parametrize(("kwargs", "message"), [
        ({"continuous_a": 10},
         "tau_s is required unless both peak_a and peak_time_s are given (got tau_s=None, peak_a=None, "
         "peak_time_s=None)"),
        ({"continuous_a": 10, "tau_s": -1}, "tau_s must be a finite number > 0, got -1"),
        ({"continuous_a": 10, "tau_s": 5, "tau_cool_s": 0}, "tau_cool_s must be a finite number > 0, got 0"),
        ({"continuous_a": 10, "peak_a": 5, "peak_time_s": 3}, "peak_a (5 A) must exceed continuous_a (10 A)"),
        ({"continuous_a": 10, "peak_a": -5, "peak_time_s": 3}, "peak_a must be a finite number > 0, got -5"),
        ({"continuous_a": 10, "peak_a": 20, "peak_time_s": -3}, "peak_time_s must be a finite number > 0, got -3"),
        ({"continuous_a": 0, "tau_s": 5}, "continuous_a must be a finite number > 0, got 0"),
    ])
    def test_thermal(self, kwargs: dict, message: str) -> None:
        with pytest.raises(ValueError) as err:
            ThermalI2t(**kwargs)
        assert str(err.value) == message

    def test_peak_equal_to_continuous_is_allowed_for_thermal_only_when_tau_is_given(self) -> None:
        ThermalI2t(10.0, tau_s=5.0)  # no peak figures: fine
        with pytest.raises(ValueError, match="must exceed"):
            ThermalI2t(10.0, peak_a=10.0, peak_time_s=5.0)


class TestStateFileFields:
    def test_leaky_export_is_exactly_these_fields(self) -> None:
        assert LeakyI2t(10.0, 20.0, 5.0).export() == {
            "kind": "leaky", "version": 1,
            "params": {"continuous_a": 10.0, "peak_a": 20.0, "peak_time_s": 5.0, "recover_fraction": 0.5,
                       "max_gap_s": None},
            "accumulator": 0.0, "level": 0.0, "tripped": False, "t": None,
        }

    def test_thermal_export_is_exactly_these_fields(self) -> None:
        m = ThermalI2t(10.0, tau_s=30.0, tau_cool_s=60.0, max_gap_s=2.0)
        step(m, 20.0, 0.0)
        step(m, 20.0, 1.0)
        got = m.export()
        assert set(got) == {"kind", "version", "params", "accumulator", "level", "tripped", "t"}
        assert got["params"] == {"continuous_a": 10.0, "peak_a": None, "peak_time_s": None, "tau_s": 30.0,
                                 "tau_cool_s": 60.0, "recover_fraction": 0.5, "max_gap_s": 2.0}
        assert got["level"] == pytest.approx(got["accumulator"]) and got["t"] == 1.0


class TestBoundaries:
    def test_recovery_needs_the_level_strictly_below_recover_fraction(self) -> None:
        """Tripped at 100 %; exactly at recover_fraction it stays tripped; just below it recovers."""
        m = LeakyI2t(10.0, 20.0, 5.0, recover_fraction=0.5)
        m.set_hot(0.0)
        s = m.trip_level
        # cool at zero current: A falls by I_cont² per second (100 A²/s)
        seconds_to_half = (s - 0.5 * s) / 100.0
        step(m, 0.0, 10.0)
        step(m, 0.0, 10.0 + seconds_to_half)
        assert m.level == pytest.approx(0.5)
        assert m.tripped
        step(m, 0.0, 10.0 + seconds_to_half + 0.01)
        assert not m.tripped

    def test_thermal_cools_with_tau_cool_and_heats_with_tau(self) -> None:
        """Above the steady state the level falls at tau_cool, below it rises at tau."""
        heat = ThermalI2t(10.0, tau_s=10.0, tau_cool_s=1000.0)
        step(heat, 20.0, 0.0)
        step(heat, 20.0, 1.0)  # q = 4: θ = 4 (1 - e^(-1/10))
        assert heat.accumulator == pytest.approx(4.0 * (1.0 - math.exp(-0.1)))
        cool = ThermalI2t(10.0, tau_s=10.0, tau_cool_s=1000.0)
        cool.set_hot(0.0)
        step(cool, 0.0, 0.0)
        step(cool, 0.0, 1.0)  # q = 0 < θ = 1: θ = e^(-1/1000)
        assert cool.accumulator == pytest.approx(math.exp(-0.001))

    def test_a_zero_gap_integrates_nothing(self) -> None:
        m = LeakyI2t(10.0, 20.0, 5.0)
        step(m, 20.0, 1.0)
        step(m, 20.0, 1.0)
        assert m.accumulator == 0.0
        step(m, 20.0, 2.0)
        assert m.accumulator == pytest.approx(300.0)


class TestRestoreRefuses:
    @pytest.mark.parametrize(("state", "message"), [
        ([1, 2], "i2t state: expected a mapping, got list"),
        ({"kind": "leaky", "accumulator": 0.0}, "i2t state: 'params' missing or not a mapping"),
        ({"kind": "leaky", "params": {}, "accumulator": -1.0},
         "i2t state: 'accumulator' must be a finite number >= 0, got -1.0"),
        ({"kind": "leaky", "params": {"continuous_a": 10.0, "peak_a": 5.0, "peak_time_s": 5.0}, "accumulator": 0.0},
         "i2t state: leaky parameters do not give a positive trip level"),
        ({"kind": "leaky", "params": {"continuous_a": -10.0, "peak_a": 20.0, "peak_time_s": 5.0}, "accumulator": 0.0},
         "i2t state: leaky parameters do not give a positive trip level"),
        ({"kind": "thermal", "params": {"tau_cool_s": 0.0}, "accumulator": 0.5}, "i2t state: tau_cool_s must be > 0"),
        ({"kind": "other", "params": {}, "accumulator": 0.5},
         "i2t state: unknown kind 'other' (expected 'leaky' or 'thermal')"),
    ])
    def test_malformed_states(self, state: object, message: str) -> None:
        with pytest.raises(ValueError) as err:
            cooled_level(state, 0.0)  # type: ignore[arg-type]
        assert str(err.value) == message

    def test_a_zero_accumulator_and_tiny_parameters_are_valid(self) -> None:
        """Boundaries that are allowed: an empty bucket, a continuous current below 1 A, a tau_cool below 1 s."""
        assert cooled_level({"kind": "leaky", "params": {"continuous_a": 0.5, "peak_a": 1.0, "peak_time_s": 0.5},
                             "accumulator": 0.0}, 1.0) == 0.0
        assert cooled_level({"kind": "thermal", "params": {"tau_cool_s": 0.5}, "accumulator": 1.0},
                            0.5) == pytest.approx(math.exp(-1.0))
        assert cooled_level({"kind": "leaky", "params": {"continuous_a": 10.0, "peak_a": 20.0, "peak_time_s": 0.5},
                             "accumulator": 150.0}, 0.0) == pytest.approx(1.0)


class TestMore:
    def test_a_rate_of_exactly_one_integrates(self) -> None:
        """I² − I_cont² = 1 A² exactly (1.25² − 0.75²): the bucket fills by 1 A²s per second."""
        m = LeakyI2t(0.75, 2.0, 1.0)
        step(m, 1.25, 0.0)
        step(m, 1.25, 2.0)
        assert m.accumulator == 2.0
        level = LeakyI2t(0.75, 2.0, 1.0)
        step(level, 0.75, 0.0)
        step(level, 0.75, 2.0)
        assert level.accumulator == 0.0

    @pytest.mark.parametrize("params", [
        {"continuous_a": 0.0, "peak_a": 20.0, "peak_time_s": 5.0},
        {"continuous_a": 10.0, "peak_a": 10.0, "peak_time_s": 5.0},
    ])
    def test_a_zero_current_or_trip_level_in_a_state_is_refused(self, params: dict) -> None:
        with pytest.raises(ValueError) as err:
            cooled_level({"kind": "leaky", "params": params, "accumulator": 1.0}, 0.0)
        assert str(err.value) == "i2t state: leaky parameters do not give a positive trip level"

    def test_restoring_a_tripped_state_reports_the_trip_once(self) -> None:
        hot = LeakyI2t(10.0, 20.0, 5.0)
        hot.set_hot(3.0)
        m = LeakyI2t(10.0, 20.0, 5.0)
        m.restore(hot.export(), 0.0)
        assert m.tripped and m.since is None
        assert m.poll(0.0).tripped
        warm = LeakyI2t(10.0, 20.0, 5.0)
        step(warm, 20.0, 0.0)
        step(warm, 20.0, 1.0)
        cold = LeakyI2t(10.0, 20.0, 5.0)
        cold.restore(warm.export(), 0.0)
        assert not cold.tripped and not cold.poll(0.0).tripped

    def test_a_reload_carries_the_level_after_a_stale_gap(self) -> None:
        old = LeakyI2t(10.0, 20.0, 5.0, max_gap_s=0.1)
        step(old, 20.0, 0.0)
        step(old, 20.0, 1.0)  # a 1 s gap: integrated as 0.1 s
        new = LeakyI2t(10.0, 20.0, 5.0, max_gap_s=0.1)
        new.carry_from(old)
        assert new.level == old.level == pytest.approx(300.0 * 0.1 / 1500.0)
