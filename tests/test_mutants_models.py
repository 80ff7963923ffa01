"""Threshold, hysteresis, inrush and source health as a user meets them: errors, counters, exact boundaries.

Written against the mutants ``scripts/mutation.sh`` left alive in ``protect/``: each test asserts a
message a config author reads, a counter the summary prints, or a trip/recovery at the exact time the
docs promise (boundaries are inclusive: ``trip_after`` reached is a trip).
"""

from __future__ import annotations

import math

import pytest
from tests.feed import observe, step

from canguard.config.schema import SignalRef, SourceConfig
from canguard.io.frame import Sample
from canguard.protect import SourceHealth
from canguard.protect.hysteresis import Hysteresis
from canguard.protect.inrush import InrushBlanking
from canguard.protect.threshold import Threshold, level_pct


class TestErrorsNameTheParameter:
    @pytest.mark.parametrize(("make", "message"), [
        (lambda: Threshold(-1.0), "max_value must be a finite number >= 0, got -1.0"),
        (lambda: Threshold(5.0).set_max(math.nan), "max_value must be a finite number >= 0, got nan"),
        (lambda: Hysteresis(-1.0, 0.0), "overcurrent_a must be a finite number >= 0, got -1.0"),
        (lambda: Hysteresis(10.0, -1.0), "recovery_a must be a finite number >= 0, got -1.0"),
        (lambda: Hysteresis(10.0, 5.0, trip_after_s=-1.0), "trip_after_s must be a finite number >= 0, got -1.0"),
        (lambda: Hysteresis(10.0, 5.0, recover_after_s=-1.0),
         "recover_after_s must be a finite number >= 0, got -1.0"),
        (lambda: Hysteresis(10.0, 5.0, max_gap_s=0.0), "max_gap_s must be > 0 (inf: no limit), got 0.0"),
        (lambda: Hysteresis(10.0, 5.0, max_gap_s=math.nan), "max_gap_s must be > 0 (inf: no limit), got nan"),
        (lambda: InrushBlanking(-1.0, 1.0), "start_current_a must be a finite number >= 0, got -1.0"),
        (lambda: InrushBlanking(1.0, -1.0), "inrush_time_s must be a finite number >= 0, got -1.0"),
        (lambda: InrushBlanking(1.0, 1.0, -1.0), "inrush_threshold_a must be a finite number >= 0, got -1.0"),
    ])
    def test_message(self, make: object, message: str) -> None:
        with pytest.raises(ValueError) as err:
            make()  # type: ignore[operator]
        assert str(err.value) == message

    def test_recovery_at_or_above_the_trip_threshold(self) -> None:
        Hysteresis(10.0, 10.0)  # equal: allowed (no hysteresis band)
        with pytest.raises(ValueError) as err:
            Hysteresis(10.0, 11.0)
        assert str(err.value) == ("recovery_a (11.0 A) must not exceed overcurrent_a (10.0 A): "
                                  "the current must fall below the trip threshold to recover")


class TestCounters:
    def test_samples_not_finite_or_older_are_ignored(self) -> None:
        m = Threshold(10.0)
        step(m, 1.0, 5.0)
        step(m, math.nan, 6.0)
        step(m, math.inf, 6.0)
        step(m, 2.0, 4.0)
        step(m, 3.0, 3.0)
        assert (m.last_t, m.snapshot().value) == (5.0, 1.0)
        assert m.snapshot().since is None  # never tripped

    def test_inrush_counts_every_start(self) -> None:
        b = InrushBlanking(2.0, 0.5)
        starts = []
        for t, a in [(0.0, 0.0), (0.5, 0.0), (0.6, 5.0), (0.7, 0.0), (1.3, 0.0), (1.4, 5.0)]:
            starts.append(b.observe(a, t))
        assert starts.count(True) == 2 and b.running()[1] == 1.4

    def test_source_health_ignores_older_samples(self) -> None:
        h = SourceHealth(SourceConfig("c", "current", "can0", (ref("current"),), 0.5))
        observe(h, Sample("c", "current", 1.0, 1.0))
        observe(h, Sample("c", "current", math.nan, 1.1, "nan"))
        observe(h, Sample("c", "current", math.nan, 1.2, "nan"))
        observe(h, Sample("c", "current", 1.0, 0.5))
        observe(h, Sample("c", "current", 1.0, 0.4))
        assert (h.latest_t("current"), h.value("current"), h.reason(1.2)) == (1.2, 1.0, "nan")


def ref(role: str, minimum: float | None = None, maximum: float | None = None) -> SignalRef:
    return SignalRef(role, "can0", "BMS", 0x100, False, role.upper(), "A", minimum, maximum)


class TestBoundaries:
    def test_trip_after_reached_is_a_trip_and_recover_after_reached_a_recovery(self) -> None:
        m = Hysteresis(10.0, 5.0, trip_after_s=0.5, recover_after_s=0.25)
        assert not step(m, 20.0, 1.0)
        assert not step(m, 20.0, 1.25)
        assert step(m, 20.0, 1.5) and m.tripped
        assert not step(m, 1.0, 2.0)
        assert step(m, 1.0, 2.25) and not m.tripped

    def test_a_fresh_model_reports_its_trip_threshold(self) -> None:
        blanked = Hysteresis(10.0, 5.0, inrush=InrushBlanking(2.0, 0.5, 40.0))
        assert blanked.snapshot().threshold == 10.0 and blanked.snapshot().level_pct == 0.0
        step(blanked, 0.0, 0.0)
        step(blanked, 0.0, 0.5)
        step(blanked, 3.0, 0.6)  # a start after 0.5 s quiet: the blanking threshold is in force
        assert blanked.snapshot().threshold == 40.0 and blanked.snapshot().level_pct == pytest.approx(7.5)

    def test_level_pct(self) -> None:
        assert level_pct(5.0, 10.0) == 50.0
        assert level_pct(5.0, 0.0) == 100.0 and level_pct(0.0, 0.0) == 0.0
        assert level_pct(0.5, 0.5) == 100.0 and level_pct(1.0, 0.0) == 100.0
        assert level_pct(1.0, None) == 0.0 and level_pct(math.nan, 10.0) == 0.0
        assert level_pct(1e300, 1e-300) == 1e12

    def test_inrush_ignores_non_finite_and_accepts_a_repeated_time(self) -> None:
        b = InrushBlanking(2.0, 0.5)
        assert not b.observe(0.0, 0.0)
        assert not b.observe(math.nan, 1.0) and not b.observe(5.0, math.inf)
        assert b.observe(5.0, 0.5)  # below since 0.0, for exactly inrush_time: a start, at a repeated time too
        assert b.threshold(1.0, 0.5) is None and b.threshold(1.0, 0.99) is None and b.threshold(1.0, 1.0) == 1.0

    def test_a_start_needs_the_full_quiet_time(self) -> None:
        b = InrushBlanking(2.0, 0.5)
        b.observe(0.0, 0.0)
        assert not b.observe(5.0, 0.4)
        assert b.running()[1] is None  # no window opened


class TestSourceHealthAfterSamples:
    def test_fresh_after_a_second_valid_sample_and_stale_after_max_age(self) -> None:
        h = SourceHealth(SourceConfig("c", "current", "can0", (ref("current"),), 0.5))
        observe(h, Sample("c", "current", 1.0, 1.0))
        assert not observe(h, Sample("c", "current", 2.0, 1.2))  # the fast path
        assert h.reason(1.2) == "" and h.reason(1.7) == "" and h.reason(1.71) == "stale"
        assert h.value("current") == 2.0 and h.last_t("current") == 1.2

    def test_a_second_invalid_sample_in_a_row_is_no_new_edge(self) -> None:
        h = SourceHealth(SourceConfig("c", "current", "can0", (ref("current"),), 0.5))
        observe(h, Sample("c", "current", 1.0, 1.0))
        assert observe(h, Sample("c", "current", math.nan, 1.1, "nan"))
        assert not observe(h, Sample("c", "current", math.nan, 1.2, "nan"))
        assert observe(h, Sample("c", "current", 1.0, 1.3))

    def test_a_minimum_alone_is_a_range(self) -> None:
        h = SourceHealth(SourceConfig("c", "current", "can0", (ref("current", minimum=-10.0),), 0.5))
        observe(h, Sample("c", "current", -20.0, 1.0))
        assert h.reason(1.0) == "out_of_range"

    def test_presence_is_judged_before_the_values(self) -> None:
        cfg = SourceConfig("bms", "battery", "can0", (ref("current"), ref("present")), 0.5)
        h = SourceHealth(cfg)
        observe(h, Sample("bms", "present", 0.0, 1.0))
        observe(h, Sample("bms", "current", 1.0, 1.0))
        assert h.reason(1.0) == "not_present" and h.reason(1.0, "current") == "not_present"
        assert h.age(1.5) == 0.5
        empty = SourceHealth(SourceConfig("x", "current", "can0", (ref("current"),), 0.5))
        assert empty.age(3.0) == math.inf


class TestReloadCarries:
    def test_a_tripped_i2t_model_stays_tripped_since_the_same_time(self) -> None:
        from canguard.protect.i2t import LeakyI2t

        old = LeakyI2t(10.0, 20.0, 5.0)
        old.set_hot(7.0)
        new = LeakyI2t(10.0, 25.0, 5.0)
        new.carry_from(old)
        assert new.tripped and new.since == 7.0 and new.level == pytest.approx(1.0)

    def test_a_sample_older_than_the_old_models_last_is_out_of_order(self) -> None:
        old = Threshold(10.0)
        step(old, 1.0, 5.0)
        new = Threshold(20.0)
        new.carry_from(old)
        step(new, 1.0, 4.0)
        assert new.last_t == 5.0 and new.snapshot().value == 1.0

    def test_inrush_starts_and_a_new_blanking_carry_over(self) -> None:
        old = Hysteresis(10.0, 5.0, inrush=InrushBlanking(2.0, 0.5))
        for t, a in [(0.0, 0.0), (0.5, 0.0), (0.6, 5.0)]:
            step(old, a, t)
        new = Hysteresis(12.0, 5.0, inrush=InrushBlanking(2.0, 0.5))
        new.carry_from(old)
        assert new.inrush is not None and old.inrush is not None and new.inrush.running() == old.inrush.running()
        assert new.inrush.threshold(12.0, 0.7) is None  # the window opened at 0.6 s goes on
        plain = Hysteresis(10.0, 5.0)
        step(plain, 3.0, 1.0)
        added = Hysteresis(10.0, 5.0, inrush=InrushBlanking(2.0, 0.5))
        added.carry_from(plain)  # blanking added by the reload: nothing to carry, no error
        assert added.inrush is not None and added.inrush.running() == (None, None, None) and added.last_t == 1.0


def test_inrush_start_at_a_repeated_timestamp() -> None:
    b = InrushBlanking(2.0, 0.5)
    b.observe(0.0, 0.0)
    b.observe(0.0, 0.5)
    assert b.observe(5.0, 0.5)  # the same time as the last quiet sample: a normal sample, a start
