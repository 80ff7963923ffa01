"""IsI2tSafe's peak_current is optional, derived from the rating.

Without ``peak_current`` the peak point is IEC 60034-1's occasional excess current
(design note 004 cites IEC 60034-1): 1.5 × the rated current (``continuous_current``)
for 120 s, unless ``peak_time`` says for how long. With 10 A rated (k = 1): the leaky
bucket's trip level is S = (15² − 10²) · 120 = 15 000 A²s, so 20 A from cold trips
after S / (20² − 10²) = 50 s; the thermal image's τ = 120 / ln(2.25 / 1.25) and 20 A
trips after τ · ln(4 / 3).
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from canguard.errors import TreeError
from canguard.protect.i2t import RATED_OVERLOAD, RATED_OVERLOAD_S, LeakyI2t, ThermalI2t
from treekit import F, Rig, S, find, xml_tree

START = 1000.0
SAMPLE_S = 0.125
TICK_S = 0.5


def first_failing_tick(rig: Rig, current_a: float, until_s: float) -> float:
    """Feed ``current_a`` every SAMPLE_S (a tick's own time included), tick every TICK_S; seconds to first FAILURE."""
    k = 0
    for i in range(1, int(until_s / TICK_S) + 1):
        t_tick = START + i * TICK_S
        while START + k * SAMPLE_S <= t_tick:
            rig.clock.set(START + k * SAMPLE_S)
            rig.feed("axis0", "current", current_a)
            k += 1
        rig.clock.set(t_tick)
        if rig.tick() == F:
            return t_tick - START
    return math.inf


class TestDerivedPeak:
    """A tree without peak_current loads and trips at the derived peak point's time."""

    def test_leaky_without_peak_trips_after_50_s_at_twice_the_rating(self, tmp_path: Path) -> None:
        """continuous_current=10 alone: S = 15 000 A²s; 20 A from cold fails the tick at 50 s, not before."""
        rig = Rig(start=START)
        loaded = rig.load_text(
            tmp_path, xml_tree('<IsI2tSafe name="i2t" topic_name="axis0" continuous_current="10"/>')
        )
        model = find(loaded, "i2t").model
        assert isinstance(model, LeakyI2t)
        assert (model.peak_a, model.peak_time_s) == (15.0, 120.0)
        assert model.trip_level == pytest.approx(15000.0)
        assert first_failing_tick(rig, 20.0, 60.0) == 50.0
        assert rig.trips()[-1]["reason"] == "i2t"

    def test_leaky_with_peak_time_only(self, tmp_path: Path) -> None:
        """peak_time=10 without peak_current: 15 A for 10 s, S = 1 250 A²s; 20 A trips after 4.17 s (tick at 4.5 s)."""
        rig = Rig(start=START)
        loaded = rig.load_text(
            tmp_path,
            xml_tree('<IsI2tSafe name="i2t" topic_name="axis0" continuous_current="10" peak_time="10"/>'),
        )
        assert find(loaded, "i2t").model.trip_level == pytest.approx(1250.0)
        assert first_failing_tick(rig, 20.0, 10.0) == 4.5

    def test_thermal_without_peak_or_tau(self, tmp_path: Path) -> None:
        """model="thermal", continuous_current=10 alone: τ from the derived peak point; 20 A trips after τ·ln(4/3)."""
        rig = Rig(start=START)
        loaded = rig.load_text(
            tmp_path,
            xml_tree('<IsI2tSafe name="i2t" topic_name="axis0" model="thermal" continuous_current="10"/>'),
        )
        model = find(loaded, "i2t").model
        assert isinstance(model, ThermalI2t)
        tau = 120.0 / math.log(2.25 / 1.25)
        assert model.tau_s == pytest.approx(tau)
        expected = tau * math.log(4.0 / 3.0)  # 58.72 s
        assert first_failing_tick(rig, 20.0, 70.0) == math.ceil(expected / TICK_S) * TICK_S

    def test_k_is_applied_to_the_continuous_current_only(self, tmp_path: Path) -> None:
        """k=1.2: I_cont = 12 A, the peak point stays 1.5 × the rating (15 A for 120 s): S = (225 − 144)·120."""
        rig = Rig(start=START)
        loaded = rig.load_text(
            tmp_path, xml_tree('<IsI2tSafe name="i2t" topic_name="axis0" continuous_current="10" k="1.2"/>')
        )
        assert find(loaded, "i2t").model.trip_level == pytest.approx((225.0 - 144.0) * 120.0)

    def test_constants(self) -> None:
        """The derivation's figures, as documented."""
        assert (RATED_OVERLOAD, RATED_OVERLOAD_S) == (1.5, 120.0)

    def test_below_the_derived_peak_it_never_trips(self, tmp_path: Path) -> None:
        """At the rating itself the bucket never fills: SUCCESS for a long run."""
        rig = Rig(start=START)
        rig.load_text(tmp_path, xml_tree('<IsI2tSafe topic_name="axis0" continuous_current="10"/>'))
        assert first_failing_tick(rig, 10.0, 200.0) == math.inf
        assert rig.tick() == S


class TestErrors:
    """What still cannot be derived is a load error naming the port."""

    @pytest.mark.parametrize(
        ("xml", "expected"),
        [
            (
                '<IsI2tSafe topic_name="axis0" continuous_current="10" peak_current="30"/>',
                "port peak_time: required with peak_current",
            ),
            (
                '<IsI2tSafe topic_name="axis0" continuous_current="10" k="1.5"/>',
                "port peak_current: required when k >= 1.5",
            ),
        ],
    )
    def test_load_errors(self, tmp_path: Path, xml: str, expected: str) -> None:
        """A datasheet peak without its time, or a k that leaves no room under 1.5 × the rating."""
        rig = Rig(start=START)
        with pytest.raises(TreeError) as info:
            rig.load_text(tmp_path, xml_tree(xml))
        assert expected in str(info.value)
        assert "tree.xml:" in str(info.value)
