"""HeatStore: I²t heat saved atomically and restored, cooled for the downtime, across restarts."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from canguard.errors import StateFileError
from canguard.protect import HeatStore, LeakyI2t, ThermalI2t, Threshold


def hot_models() -> dict[str, LeakyI2t | ThermalI2t]:
    """A leaky model at A = 100 A²s and a thermal one at θ = 0.8, as if heated before a shutdown."""
    leaky, thermal = LeakyI2t(6.0, 12.0, 1.0), ThermalI2t(6.0, tau_s=10.0)
    leaky.restore({**leaky.export(), "accumulator": 100.0}, 0.0)
    thermal.restore({**thermal.export(), "accumulator": 0.8}, 0.0)
    return {"leaky": leaky, "thermal": thermal}


class TestHeatStore:
    """Saving, loading and restoring the state file."""

    def test_restart_restores_heat_cooled_for_the_downtime(self, tmp_path: Path) -> None:
        """State saved at t = 100 and restored at t = 110 is cooled for 10 s by each model's law."""
        path = tmp_path / "heat.json"
        HeatStore(path).save(hot_models(), 100.0)
        store = HeatStore(path)
        store.load(110.0)
        leaky, thermal = LeakyI2t(6.0, 12.0, 1.0), ThermalI2t(6.0, tau_s=10.0)
        store.restore("leaky", leaky, 110.0)
        store.restore("thermal", thermal, 110.0)
        assert leaky.accumulator == pytest.approx(max(0.0, 100.0 - 36.0 * 10.0))
        assert thermal.accumulator == pytest.approx(0.8 * 0.36787944117, rel=1e-9)

    def test_short_downtime_keeps_most_of_the_heat(self, tmp_path: Path) -> None:
        """After a 1 s restart the leaky bucket holds A − I_cont²·1 s."""
        path = tmp_path / "heat.json"
        HeatStore(path).save(hot_models(), 50.0)
        leaky = LeakyI2t(6.0, 12.0, 1.0)
        HeatStore(path).restore("leaky", leaky, 51.0)
        assert leaky.accumulator == pytest.approx(64.0)

    def test_missing_file_starts_cold_without_warning(
        self, tmp_path: Path, caplog: pytest.LogCaptureFixture
    ) -> None:
        """The first start (no file) leaves models cold and logs no warning."""
        model = LeakyI2t(6.0, 12.0, 1.0)
        with caplog.at_level(logging.WARNING):
            HeatStore(tmp_path / "none.json").restore("leaky", model, 0.0)
        assert model.accumulator == 0.0 and not model.tripped
        assert not [r for r in caplog.records if r.levelno >= logging.WARNING]

    @pytest.mark.parametrize(
        "content",
        [
            b"{not json",
            b"[]",
            b'{"format": "other"}',
            b"\xff\xfe",
            b'{"format": "canguard-heat", "version": 1}',
        ],
    )
    def test_corrupt_file_starts_hot_with_a_warning(
        self, tmp_path: Path, caplog: pytest.LogCaptureFixture, content: bytes
    ) -> None:
        """A corrupt file logs a warning naming it, and models start at the trip level (tripped)."""
        path = tmp_path / "heat.json"
        path.write_bytes(content)
        model = ThermalI2t(6.0, tau_s=10.0)
        with caplog.at_level(logging.WARNING):
            HeatStore(path).restore("thermal", model, 5.0)
        assert model.tripped and model.accumulator == 1.0
        assert any(str(path) in r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)

    def test_corrupt_file_under_on_corrupt_cold_starts_cold(self, tmp_path: Path) -> None:
        """With on_corrupt = cold a corrupt file leaves models cold."""
        path = tmp_path / "heat.json"
        path.write_text("garbage")
        model = LeakyI2t(6.0, 12.0, 1.0)
        store = HeatStore(path, on_corrupt="cold")
        store.restore("leaky", model, 0.0)
        assert model.accumulator == 0.0 and store.corrupt is not None

    def test_unreadable_file_counts_as_corrupt(self, tmp_path: Path) -> None:
        """A path that cannot be read as a file (here a directory) starts models hot."""
        path = tmp_path / "heat.json"
        path.mkdir()
        model = LeakyI2t(6.0, 12.0, 1.0)
        HeatStore(path).restore("leaky", model, 0.0)
        assert model.tripped

    def test_malformed_entry_affects_only_that_model(self, tmp_path: Path) -> None:
        """One broken model entry starts that model hot; the others restore normally."""
        path = tmp_path / "heat.json"
        HeatStore(path).save(hot_models(), 0.0)
        doc = json.loads(path.read_text())
        doc["models"]["thermal"]["accumulator"] = -5
        path.write_text(json.dumps(doc))
        store = HeatStore(path)
        leaky, thermal = LeakyI2t(6.0, 12.0, 1.0), ThermalI2t(6.0, tau_s=10.0)
        store.restore("leaky", leaky, 0.0)
        store.restore("thermal", thermal, 0.0)
        assert leaky.accumulator == pytest.approx(100.0) and not leaky.tripped
        assert thermal.tripped

    def test_unknown_key_starts_cold(self, tmp_path: Path) -> None:
        """A guard the file does not know yet starts cold."""
        path = tmp_path / "heat.json"
        HeatStore(path).save(hot_models(), 0.0)
        model = LeakyI2t(6.0, 12.0, 1.0)
        HeatStore(path).restore("new_guard", model, 1.0)
        assert model.accumulator == 0.0

    def test_save_is_atomic_and_leaves_no_temp_files(self, tmp_path: Path) -> None:
        """A save replaces the file whole and leaves only the state file in its directory."""
        path = tmp_path / "sub" / "heat.json"
        store = HeatStore(path)
        store.save(hot_models(), 1.0)
        store.save(hot_models(), 2.0)
        assert [p.name for p in path.parent.iterdir()] == ["heat.json"]
        assert json.loads(path.read_text())["t"] == 2.0

    def test_unwritable_location_raises_state_file_error(self, tmp_path: Path) -> None:
        """Saving below a regular file raises StateFileError naming the path."""
        blocker = tmp_path / "file"
        blocker.write_text("x")
        with pytest.raises(StateFileError, match=r"heat\.json"):
            HeatStore(blocker / "heat.json").save(hot_models(), 0.0)

    def test_maybe_save_saves_once_per_period(self, tmp_path: Path) -> None:
        """maybe_save writes at once, then only when period_s has passed (or time went back)."""
        store = HeatStore(tmp_path / "heat.json")
        models = hot_models()
        results = [store.maybe_save(models, t, 5.0) for t in (0.0, 1.0, 4.9, 5.0, 6.0, 1.0)]
        assert results == [True, False, False, True, False, True]
        assert json.loads((tmp_path / "heat.json").read_text(encoding="utf-8"))["t"] == 1.0  # the last save's

    def test_no_path_never_persists(self, tmp_path: Path) -> None:
        """With path None nothing is read or written and models stay as they are."""
        store = HeatStore(None)
        model = LeakyI2t(6.0, 12.0, 1.0)
        store.restore("leaky", model, 0.0)
        store.save({"leaky": model}, 0.0)
        assert store.maybe_save({"leaky": model}, 100.0, 1.0) is False
        assert model.accumulator == 0.0 and list(tmp_path.iterdir()) == []

    def test_models_without_heat_are_rejected(self, tmp_path: Path) -> None:
        """Saving or restoring a model that holds no heat raises TypeError naming its key."""
        store = HeatStore(tmp_path / "heat.json")
        with pytest.raises(TypeError, match="peak"):
            store.save({"peak": Threshold(1.0)}, 0.0)
        with pytest.raises(TypeError, match="peak"):
            store.restore("peak", Threshold(1.0), 0.0)

    def test_bad_on_corrupt_is_rejected(self) -> None:
        """on_corrupt other than hot or cold raises ValueError."""
        with pytest.raises(ValueError, match="on_corrupt"):
            HeatStore(None, on_corrupt="warm")
