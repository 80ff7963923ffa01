"""Boundaries of the hysteresis guard that mutation testing (scripts/mutation.sh) showed untested.

Each case pins a behaviour a user relies on: a gap of exactly ``max_gap_s`` is not a
gap; a persistence timer restarts from the next over (or under) sample after it was
broken; a recovery reports its own time in ``since``.
"""

from __future__ import annotations

from tests.feed import observe, step

from canguard.protect.hysteresis import Hysteresis


def test_gap_of_exactly_max_gap_keeps_the_persistence_timer() -> None:
    """Samples 0.125 s apart with max_gap 0.125 s: persistence runs on and trips at 0.375 s."""
    m = Hysteresis(35.0, 25.0, trip_after_s=0.375, max_gap_s=0.125)
    for t in (0.0, 0.125, 0.25):
        assert step(m, 40.0, t) is False
    assert step(m, 40.0, 0.375) is True
    assert m.tripped


def test_gap_longer_than_max_gap_restarts_it() -> None:
    """The same, but one gap is longer than max_gap: the timer restarts there and no trip comes yet."""
    m = Hysteresis(35.0, 25.0, trip_after_s=0.375, max_gap_s=0.125)
    for t in (0.0, 0.125, 0.5, 0.625):
        step(m, 40.0, t)
    assert not m.tripped


def test_broken_overcurrent_restarts_from_the_next_over_sample() -> None:
    """Over, under, over, over: the trip timer counts from the second run of over samples only."""
    m = Hysteresis(35.0, 25.0, trip_after_s=0.25)
    step(m, 40.0, 0.0)
    step(m, 30.0, 0.125)  # between the thresholds: breaks the overcurrent run
    step(m, 40.0, 0.25)
    assert step(m, 40.0, 0.375) is False and not m.tripped  # 0.125 s of the new run
    assert step(m, 40.0, 0.5) is True  # 0.25 s: trips


def test_broken_recovery_restarts_from_the_next_under_sample() -> None:
    """Tripped; under, between, under, under: recovery counts from the second run of under samples."""
    m = Hysteresis(35.0, 25.0, recover_after_s=0.25)
    assert step(m, 40.0, 0.0) is True
    step(m, 20.0, 0.125)
    step(m, 30.0, 0.25)  # above the recovery threshold: breaks the run
    step(m, 20.0, 0.375)
    assert step(m, 20.0, 0.5) is False and m.tripped
    assert step(m, 20.0, 0.625) is True and not m.tripped


def test_recovery_reports_its_time() -> None:
    """since is the time of the last edge: the trip's, then the recovery's."""
    m = Hysteresis(35.0, 25.0)
    step(m, 40.0, 1.0)
    assert m.snapshot().since == 1.0
    step(m, 20.0, 2.5)
    assert m.snapshot().since == 2.5


def test_second_trip_and_recovery_with_persistence() -> None:
    """Trip, recover, trip again, recover again: each edge needs its own full persistence time."""
    m = Hysteresis(35.0, 25.0, trip_after_s=0.25, recover_after_s=0.25)
    edges = []
    t = 0.0
    for value in [40.0] * 3 + [20.0] * 3 + [40.0] * 3 + [20.0] * 3:
        if step(m, value, t):
            edges.append((t, m.tripped))
        t += 0.125
    assert edges == [(0.25, True), (0.625, False), (1.0, True), (1.375, False)]


# -- source health (staleness): what a stale/invalid verdict rests on ------------------------------
import math  # noqa: E402

from canguard.config.schema import SignalRef, SourceConfig  # noqa: E402
from canguard.io.frame import Sample  # noqa: E402
from canguard.protect import SourceHealth  # noqa: E402


def _ref(role: str, minimum: float | None = None, maximum: float | None = None) -> SignalRef:
    return SignalRef(role, "can0", "M", 0x100, False, role.upper(), "A", minimum, maximum)


def _sample(role: str, value: float, t: float) -> Sample:
    return Sample("src", role, value, t, "")


def _joints(max_age_s: float = 0.5) -> SourceHealth:
    return SourceHealth(SourceConfig("arm", "joints", "can0", (_ref("j1"), _ref("j2")), max_age_s))


def test_every_role_exactly_max_age_old_is_fresh_and_a_bit_older_is_stale() -> None:
    """reason(now, role) judges each role on its own: 0.5 s old with max_age 0.5 s is fresh, 0.51 s is stale."""
    h = _joints()
    observe(h, _sample("j1", 1.0, 1.0))
    observe(h, _sample("j2", 2.0, 1.0))
    assert (h.reason(1.5, "j1"), h.reason(1.5, "j2")) == ("", "")
    assert (h.reason(1.51, "j1"), h.reason(1.51, "j2")) == ("stale", "stale")


def test_a_role_refreshed_on_the_fast_path_keeps_its_time_and_value() -> None:
    """Many fresh samples: the latest time and value are the last sample's, every role usable."""
    h = _joints()
    for i in range(5):
        observe(h, _sample("j1", float(i), 0.1 * i))
        observe(h, _sample("j2", 10.0 + i, 0.1 * i + 0.01))
    assert h.last_t("j1") == 0.1 * 4 and h.last_t("j2") == 0.1 * 4 + 0.01
    assert h.value("j1") == 4.0 and h.value("j2") == 14.0
    assert (h.reason(0.45, "j1"), h.reason(0.45, "j2")) == ("", "")


def test_age_of_the_source_is_its_oldest_role() -> None:
    """age(now) is the age of the oldest value role (the one that goes stale first), not the newest one's."""
    h = _joints()
    observe(h, _sample("j1", 1.0, 0.0))
    observe(h, _sample("j2", 1.0, 1.0))
    assert h.age(2.0) == 2.0


def test_a_signal_with_only_a_minimum_is_range_checked() -> None:
    """A DBC range with only a lower bound still makes values below it out_of_range."""
    h = SourceHealth(SourceConfig("m", "current", "can0", (_ref("current", 0.0, None),), 0.5))
    assert h.ranges == {"current": (0.0, None)}
    observe(h, _sample("current", -1.0, 0.0))
    assert h.reason(0.0) == "out_of_range"


# -- I²t: restore boundaries, the held current after a restore, gaps ---------------------------------
from canguard.protect.i2t import LeakyI2t  # noqa: E402


def _heated(level: float, tripped: bool) -> dict[str, object]:
    """An exported leaky I²t state at ``level`` (fraction of the trip level), tripped or not."""
    m = LeakyI2t(10.0, 20.0, 1.0)
    state = m.export()
    state.update(level=level, accumulator=level * m.trip_level, tripped=tripped)
    return state


def test_restore_trips_at_exactly_the_trip_level() -> None:
    """A state saved at 100 % comes back tripped; at 99.9 % and not tripped, it does not."""
    m = LeakyI2t(10.0, 20.0, 1.0)
    m.restore(_heated(1.0, False), 0.0)
    assert m.tripped and m.snapshot().tripped
    m2 = LeakyI2t(10.0, 20.0, 1.0)
    m2.restore(_heated(0.999, False), 0.0)
    assert not m2.tripped


def test_restore_keeps_a_trip_down_to_exactly_the_recover_fraction() -> None:
    """Saved tripped at exactly recover_fraction: still tripped; just below it: recovered."""
    m = LeakyI2t(10.0, 20.0, 1.0, recover_fraction=0.5)
    m.restore(_heated(0.5, True), 0.0)
    assert m.tripped
    m2 = LeakyI2t(10.0, 20.0, 1.0, recover_fraction=0.5)
    m2.restore(_heated(0.49, True), 0.0)
    assert not m2.tripped


def test_export_restore_round_trip_keeps_the_level() -> None:
    """Half-heated, exported and restored with no downtime: the same level, samples work after it."""
    m = LeakyI2t(10.0, 20.0, 1.0)
    step(m, 20.0, 0.0)
    step(m, 20.0, 0.5)
    level = m.level
    assert 0.0 < level < 1.0
    fresh = LeakyI2t(10.0, 20.0, 1.0)
    fresh.restore(m.export(), 0.0)
    assert fresh.level == level
    assert step(fresh, 20.0, 10.0) is False  # the first sample after a restore only sets the held current
    step(fresh, 20.0, 10.6)
    assert fresh.tripped  # and the heat goes on from the restored level: 0.5 + 0.6 s at 2x the rating


def test_each_stale_gap_heats_as_max_gap() -> None:
    """Two gaps longer than max_gap_s each integrate as max_gap_s (a gap of exactly max_gap_s whole)."""
    m = LeakyI2t(10.0, 20.0, 1.0, max_gap_s=0.25)
    for t in (0.0, 0.25, 1.0, 1.25, 2.0):
        step(m, 15.0, t)
    assert math.isclose(m.accumulator, (15.0**2 - 10.0**2) * 4 * 0.25)  # 0.25 + 0.25 (of 0.75) + 0.25 + 0.25


def test_i2t_recovery_reports_its_time() -> None:
    """since is the recovery's time once the bucket has cooled below recover_fraction."""
    m = LeakyI2t(10.0, 20.0, 1.0, recover_fraction=0.5)
    t = 0.0
    while not m.tripped:
        step(m, 20.0, t)
        t += 0.125
    while m.tripped:
        step(m, 0.0, t)
        t += 0.125
    assert m.snapshot().since == t - 0.125


# -- the I²t state file ---------------------------------------------------------------------------
from pathlib import Path  # noqa: E402

from canguard.protect.state import HeatStore  # noqa: E402


def test_corrupt_state_file_starts_hot_at_the_restore_time(tmp_path: Path) -> None:
    """A corrupt file: the model starts tripped, and its trip is dated at the restore (the events say when)."""
    path = tmp_path / "i2t.json"
    path.write_text("{not json")
    model = LeakyI2t(10.0, 20.0, 1.0)
    HeatStore(path).restore("Axis0I2t", model, 123.0)
    assert model.tripped and model.snapshot().since == 123.0


def test_periodic_save_once_per_period_boundary(tmp_path: Path) -> None:
    """maybe_save saves at exactly one period after the last save, not before; time going back saves too."""
    store = HeatStore(tmp_path / "i2t.json")
    models = {"A": LeakyI2t(10.0, 20.0, 1.0)}
    assert store.maybe_save(models, 10.0, 5.0) is True
    assert store.maybe_save(models, 14.999, 5.0) is False
    assert store.maybe_save(models, 15.0, 5.0) is True
    assert store.maybe_save(models, 15.0, 5.0) is False  # the same instant: nothing new
    assert store.maybe_save(models, 12.0, 5.0) is True  # the clock went back: save rather than wait
