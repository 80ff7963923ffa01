"""Boundaries of the hysteresis guard that mutation testing (scripts/mutation.sh) showed untested.

Each case pins a behaviour a user relies on: a gap of exactly ``max_gap_s`` is not a
gap; a persistence timer restarts from the next over (or under) sample after it was
broken; a recovery reports its own time in ``since``.
"""

from __future__ import annotations

from canguard.protect.hysteresis import Hysteresis


def test_gap_of_exactly_max_gap_keeps_the_persistence_timer() -> None:
    """Samples 0.125 s apart with max_gap 0.125 s: persistence runs on and trips at 0.375 s."""
    m = Hysteresis(35.0, 25.0, trip_after_s=0.375, max_gap_s=0.125)
    for t in (0.0, 0.125, 0.25):
        assert m.update(40.0, t) is False
    assert m.update(40.0, 0.375) is True
    assert m.tripped


def test_gap_longer_than_max_gap_restarts_it() -> None:
    """The same, but one gap is longer than max_gap: the timer restarts there and no trip comes yet."""
    m = Hysteresis(35.0, 25.0, trip_after_s=0.375, max_gap_s=0.125)
    for t in (0.0, 0.125, 0.5, 0.625):
        m.update(40.0, t)
    assert not m.tripped


def test_broken_overcurrent_restarts_from_the_next_over_sample() -> None:
    """Over, under, over, over: the trip timer counts from the second run of over samples only."""
    m = Hysteresis(35.0, 25.0, trip_after_s=0.25)
    m.update(40.0, 0.0)
    m.update(30.0, 0.125)  # between the thresholds: breaks the overcurrent run
    m.update(40.0, 0.25)
    assert m.update(40.0, 0.375) is False and not m.tripped  # 0.125 s of the new run
    assert m.update(40.0, 0.5) is True  # 0.25 s: trips


def test_broken_recovery_restarts_from_the_next_under_sample() -> None:
    """Tripped; under, between, under, under: recovery counts from the second run of under samples."""
    m = Hysteresis(35.0, 25.0, recover_after_s=0.25)
    assert m.update(40.0, 0.0) is True
    m.update(20.0, 0.125)
    m.update(30.0, 0.25)  # above the recovery threshold: breaks the run
    m.update(20.0, 0.375)
    assert m.update(20.0, 0.5) is False and m.tripped
    assert m.update(20.0, 0.625) is True and not m.tripped


def test_recovery_reports_its_time() -> None:
    """since is the time of the last edge: the trip's, then the recovery's."""
    m = Hysteresis(35.0, 25.0)
    m.update(40.0, 1.0)
    assert m.snapshot().since == 1.0
    m.update(20.0, 2.5)
    assert m.snapshot().since == 2.5


def test_second_trip_and_recovery_with_persistence() -> None:
    """Trip, recover, trip again, recover again: each edge needs its own full persistence time."""
    m = Hysteresis(35.0, 25.0, trip_after_s=0.25, recover_after_s=0.25)
    edges = []
    t = 0.0
    for value in [40.0] * 3 + [20.0] * 3 + [40.0] * 3 + [20.0] * 3:
        if m.update(value, t):
            edges.append((t, m.tripped))
        t += 0.125
    assert edges == [(0.25, True), (0.625, False), (1.0, True), (1.375, False)]
