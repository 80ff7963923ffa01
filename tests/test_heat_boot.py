"""I²t heat across a daemon restart when the wall clock stepped in between (NTP after boot)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from tests.feed import step

from canguard.io import clock
from canguard.io.clock import BootClock
from canguard.protect.i2t import LeakyI2t
from canguard.protect.state import HeatStore

BOOT_ID = "5f1c0d8e-0000-4000-8000-000000000001"


@pytest.fixture
def boot(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> BootClock:
    """A BootClock reading a boot id from a file the test controls."""
    path = tmp_path / "boot_id"
    path.write_text(BOOT_ID + "\n", encoding="ascii")
    monkeypatch.setattr(clock, "BOOT_ID_PATH", str(path))
    return BootClock()


def hot_model() -> LeakyI2t:
    """A 10 A / 20 A-for-1 s bucket at 90 % of its trip level."""
    m = LeakyI2t(10.0, 20.0, 1.0)
    step(m, 20.0, 0.0)
    step(m, 20.0, 0.9)
    return m


class TestBootClockDowntime:
    """Downtime within one boot comes from the boot clock, not from the wall clock."""

    def test_wall_clock_step_is_not_cooling(self, tmp_path: Path, boot: BootClock) -> None:
        """Saved 1 s ago by the boot clock but an hour ago by the wall clock: the heat is kept."""
        state = tmp_path / "heat.json"
        before = BootClock.since_boot()
        HeatStore(state, clock=boot).save({"axis0": hot_model()}, now=1000.0)
        doc = json.loads(state.read_text(encoding="utf-8"))
        assert doc["stamp"]["boot_id"] == BOOT_ID
        doc["stamp"]["since_boot_s"] -= 1.0
        state.write_text(json.dumps(doc), encoding="utf-8")
        restored = LeakyI2t(10.0, 20.0, 1.0)
        HeatStore(state, clock=boot).restore("axis0", restored, now=1000.0 + 3600.0)  # NTP stepped +1 h
        after = BootClock.since_boot()
        assert before is not None and after is not None
        # 1 s of cooling at I_cont² = 100 A²/s from 270 A²s, plus the test's own time between the save and
        # the restore (at most after - before; on a busy machine tens of ms), not an hour (which would be cold).
        assert 170.0 - 100.0 * (after - before) - 1e-6 <= restored.accumulator <= 170.0 + 1e-6
        assert after - before < 0.5

    def test_after_a_reboot_the_wall_clock_counts(self, tmp_path: Path, boot: BootClock) -> None:
        """A save from another boot is cooled by the wall-clock difference."""
        state = tmp_path / "heat.json"
        HeatStore(state, clock=boot).save({"axis0": hot_model()}, now=1000.0)
        doc = json.loads(state.read_text(encoding="utf-8"))
        doc["stamp"]["boot_id"] = "another-boot"
        state.write_text(json.dumps(doc), encoding="utf-8")
        restored = LeakyI2t(10.0, 20.0, 1.0)
        HeatStore(state, clock=boot).restore("axis0", restored, now=1001.0)
        assert restored.accumulator == pytest.approx(170.0, abs=1e-6)

    def test_stamp_reads_this_boot(self) -> None:
        """On Linux the stamp carries the kernel's boot id and a time since boot."""
        stamp = BootClock().stamp()
        if stamp["boot_id"] is None:
            pytest.skip("no /proc/sys/kernel/random/boot_id here")
        assert isinstance(stamp["since_boot_s"], float) and stamp["since_boot_s"] > 0
        assert abs(stamp["since_boot_s"] - time.clock_gettime(time.CLOCK_BOOTTIME)) < 5
