"""SourceHealth: no data, stale, not present, NaN/inf, out of range, undecodable."""

from __future__ import annotations

import math

import pytest
from tests.feed import observe

from canguard.config.schema import SignalRef, SourceConfig
from canguard.io.frame import Sample
from canguard.protect import SourceHealth


def ref(role: str, minimum: float | None = None, maximum: float | None = None) -> SignalRef:
    """A signal of the test source."""
    return SignalRef(role, "can0", "BMS", 0x100, False, role.upper(), "A", minimum, maximum)


def battery(max_age_s: float = 0.5) -> SourceHealth:
    """A battery source with a present flag and a current limited to [-200|200] A."""
    cfg = SourceConfig("bms", "battery", "can0", (ref("current", -200.0, 200.0), ref("present")), max_age_s)
    return SourceHealth(cfg)


def joints() -> SourceHealth:
    """A joints source with two joints and no presence signal."""
    return SourceHealth(SourceConfig("arm", "joints", "can0", (ref("j1"), ref("j2")), 0.5))


def s(role: str, value: float, t: float, reason: str = "", source: str = "bms") -> Sample:
    """A sample of the test source."""
    return Sample(source, role, value, t, reason)


class TestSourceHealth:
    """Freshness, presence and validity of one source."""

    def test_no_sample_yet_is_no_data(self) -> None:
        """Before any sample the source and every role report no_data, values are NaN."""
        h = battery()
        assert h.reason(0.0) == "no_data"
        assert h.reason(0.0, "current") == "no_data"
        assert math.isnan(h.value("current"))
        assert h.last_t("current") is None and h.age(0.0) == math.inf

    def test_fresh_valid_present_source_is_healthy(self) -> None:
        """A present flag of 1 and a fresh current make the source healthy with its value."""
        h = battery()
        observe(h, s("present", 1.0, 0.0))
        observe(h, s("current", -12.5, 0.1))
        assert h.reason(0.2) == ""
        assert h.value("current") == -12.5
        assert h.age(0.3) == pytest.approx(0.2)

    def test_older_than_max_age_is_stale(self) -> None:
        """A current last seen more than max_age_s ago is stale; exactly max_age_s is still fresh."""
        h = battery(max_age_s=0.5)
        observe(h, s("present", 1.0, 1.0))
        observe(h, s("current", 10.0, 1.0))
        assert h.reason(1.5) == ""
        assert h.reason(1.51) == "stale"
        assert h.reason(1.51, "current") == "stale"
        assert h.value("current") == 10.0  # kept, however old

    def test_present_zero_is_not_present(self) -> None:
        """present = 0 fails the whole source, every role included."""
        h = battery()
        observe(h, s("current", 1.0, 0.0))
        observe(h, s("present", 0.0, 0.0))
        assert h.reason(0.0) == "not_present"
        assert h.reason(0.0, "current") == "not_present"
        assert h.reason(0.0, "present") == "not_present"

    @pytest.mark.parametrize(
        ("sample", "reason"),
        [
            (s("current", math.nan, 0.1), "nan"),
            (s("current", math.inf, 0.1), "inf"),
            (s("current", -math.inf, 0.1), "inf"),
            (s("current", 250.0, 0.1), "out_of_range"),
            (s("current", -200.5, 0.1), "out_of_range"),
            (s("current", math.nan, 0.1, "bad_length"), "bad_length"),
            (s("current", math.nan, 0.1, "undecodable"), "undecodable"),
        ],
    )
    def test_invalid_latest_sample_names_the_reason(self, sample: Sample, reason: str) -> None:
        """The latest invalid sample decides the reason and the last valid value is kept."""
        h = battery()
        observe(h, s("present", 1.0, 0.0))
        observe(h, s("current", 5.0, 0.0))
        assert observe(h, sample) is True
        assert h.reason(0.1) == reason
        assert h.value("current") == 5.0

    def test_range_edges_are_valid(self) -> None:
        """Values exactly at the DBC minimum and maximum are valid."""
        h = battery()
        observe(h, s("present", 1.0, 0.0))
        observe(h, s("current", 200.0, 0.0))
        assert h.reason(0.0) == ""
        observe(h, s("current", -200.0, 0.1))
        assert h.reason(0.1) == ""

    def test_newer_valid_sample_clears_an_invalid_reason(self) -> None:
        """After a NaN a newer valid sample makes the source healthy again, reported as an edge."""
        h = battery()
        observe(h, s("present", 1.0, 0.0))
        observe(h, s("current", math.nan, 0.0))
        assert observe(h, s("current", 3.0, 0.1)) is True
        assert h.reason(0.1) == ""

    def test_observe_reports_edges_only(self) -> None:
        """observe returns True when the reason changes and False while it stays the same."""
        h = battery()
        assert observe(h, s("present", 1.0, 0.0)) is False  # no_data (current) -> no_data
        assert observe(h, s("current", 3.0, 0.0)) is True  # -> healthy
        assert observe(h, s("current", 4.0, 0.01)) is False
        assert observe(h, s("current", 4.0, 2.0)) is True  # healthy -> stale (present is old)
        assert observe(h, s("current", 4.0, 2.1)) is False  # still stale

    def test_data_coming_back_after_a_stale_spell_is_an_edge(self) -> None:
        """A sample arriving after a gap longer than max_age_s is a change from stale."""
        h = SourceHealth(SourceConfig("c", "current", "can0", (ref("current"),), 0.5))
        observe(h, s("current", 1.0, 0.0, source="c"))
        assert h.reason(1.0) == "stale"
        assert observe(h, s("current", 1.0, 1.0, source="c")) is True

    def test_out_of_order_samples_are_ignored(self) -> None:
        """A sample older than the latest one neither changes the value nor clears a reason."""
        h = battery()
        observe(h, s("present", 1.0, 1.0))
        observe(h, s("current", math.nan, 1.0))
        assert observe(h, s("current", 7.0, 0.5)) is False
        assert h.reason(1.0) == "nan"
        assert math.isnan(h.value("current"))

    def test_duplicate_timestamp_is_a_normal_sample(self) -> None:
        """A second sample with the same time replaces the value."""
        h = battery()
        observe(h, s("current", 1.0, 1.0))
        observe(h, s("current", 2.0, 1.0))
        assert h.value("current") == 2.0

    def test_a_bad_sample_right_after_a_healthy_check_is_seen(self) -> None:
        """The "nothing can be stale yet" shortcut of reason() never hides a sample that made a role unusable."""
        h = battery(max_age_s=0.5)
        observe(h, s("present", 1.0, 0.0))
        observe(h, s("current", 10.0, 0.0))
        assert h.reason(0.1) == ""  # healthy: the shortcut is armed
        assert observe(h, s("current", math.nan, 0.2)) is True
        assert h.reason(0.2) == "nan" and h.reason(0.2, "current") == "nan"
        assert observe(h, s("current", 5.0, 0.3)) is True
        assert h.reason(0.3) == ""
        assert observe(h, s("present", 0.0, 0.35)) is True
        assert h.reason(0.35) == "not_present"

    def test_healthy_source_still_goes_stale(self) -> None:
        """After a healthy check, a role that stops sending is stale max_age later, not sooner, not later."""
        h = joints()
        observe(h, s("j1", 1.0, 0.0, source="arm"))
        observe(h, s("j2", 1.0, 0.2, source="arm"))
        assert h.reason(0.3) == ""
        observe(h, s("j2", 1.0, 0.4, source="arm"))  # j1 stays at 0.0
        assert h.reason(0.5) == ""
        assert h.reason(0.5000001) == "stale"

    def test_joints_source_checks_every_joint(self) -> None:
        """A joints source is healthy only when every joint is fresh, with each joint's value."""
        h = joints()
        observe(h, s("j1", 1.5, 0.0, source="arm"))
        assert h.reason(0.0) == "no_data"
        assert h.reason(0.0, "j1") == ""
        observe(h, s("j2", -2.5, 0.0, source="arm"))
        assert h.reason(0.1) == ""
        assert (h.value("j1"), h.value("j2")) == (1.5, -2.5)
