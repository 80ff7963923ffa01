"""Inrush blanking: which motor starts open a window, how long it lasts, which threshold it sets."""

from __future__ import annotations

import pytest

from canguard.protect import InrushBlanking


class TestInrushBlanking:
    """Motor-start detection and the threshold in force."""

    def test_start_after_being_stopped_long_enough_opens_a_window(self) -> None:
        """Rising above start current after 0.3 s below it blanks for 0.3 s from the rise."""
        blank = InrushBlanking(2.0, 0.3, 60.0)
        blank.observe(0.0, 0.0)
        blank.observe(0.5, 0.2)
        assert blank.observe(20.0, 0.3) is True
        assert blank.threshold(1.0, 0.3) == blank.threshold(1.0, 0.599) == 60.0
        assert blank.threshold(1.0, 0.6) == 1.0
        assert blank.threshold(1.0, 0.29) == 1.0

    def test_short_stop_is_not_a_start(self) -> None:
        """A dip below start current shorter than inrush_time does not re-arm the blanking."""
        blank = InrushBlanking(2.0, 0.3, 60.0)
        blank.observe(0.0, 0.0)
        blank.observe(20.0, 1.0)
        blank.observe(0.0, 1.5)
        assert blank.observe(20.0, 1.7) is False
        assert blank.threshold(1.0, 1.7) == 1.0

    def test_first_sample_above_start_current_is_not_a_start(self) -> None:
        """A motor already running when canguard starts is not blanked (fail safe)."""
        blank = InrushBlanking(2.0, 0.3)
        assert blank.observe(20.0, 0.0) is False
        assert blank.threshold(35.0, 0.0) == 35.0

    def test_threshold_inside_and_outside_a_window(self) -> None:
        """Inside the window the inrush threshold is in force, outside the normal one."""
        blank = InrushBlanking(2.0, 0.3, 80.0)
        blank.observe(0.0, 0.0)
        blank.observe(10.0, 1.0)
        assert blank.threshold(35.0, 1.1) == 80.0
        assert blank.threshold(35.0, 1.4) == 35.0

    def test_no_inrush_threshold_means_no_check(self) -> None:
        """Without an inrush threshold the threshold in force inside a window is None."""
        blank = InrushBlanking(2.0, 0.3)
        blank.observe(0.0, 0.0)
        blank.observe(10.0, 1.0)
        assert blank.threshold(35.0, 1.1) is None

    def test_start_current_itself_counts_as_stopped(self) -> None:
        """Exactly start_current is 'below'; only rising above it is a start."""
        blank = InrushBlanking(2.0, 0.3)
        blank.observe(2.0, 0.0)
        assert blank.observe(2.0, 0.5) is False
        assert blank.observe(2.01, 0.6) is True

    def test_out_of_order_samples_are_ignored(self) -> None:
        """A late sample from before the latest one does not start or stop anything."""
        blank = InrushBlanking(2.0, 0.3)
        blank.observe(0.0, 0.0)
        blank.observe(0.0, 1.0)
        assert blank.observe(50.0, 0.5) is False
        assert blank.running()[1] is None

    @pytest.mark.parametrize(
        ("args", "name"),
        [
            ((-1.0, 0.3), "start_current_a"),
            ((2.0, -0.3), "inrush_time_s"),
            ((2.0, 0.3, -5.0), "inrush_threshold_a"),
        ],
    )
    def test_bad_parameters_are_named(self, args: tuple[float, ...], name: str) -> None:
        """Negative parameters raise ValueError naming the parameter."""
        with pytest.raises(ValueError, match=name):
            InrushBlanking(*args)
