"""The I²t state file as an operator meets it: its log lines, its reasons, its layout, its failures.

Written against the mutants ``scripts/mutation.sh`` left alive in ``protect/state.py``: each
test asserts something a user of the daemon sees — the journal line that says why the
heat started hot, the file on disk, the error that names the path, nothing left behind.
"""

from __future__ import annotations

import json
import logging
import math
import os
from pathlib import Path
from typing import Any

import pytest

from canguard.errors import StateFileError
from canguard.protect.i2t import LeakyI2t
from canguard.protect.state import HeatStore, readable_problem

LOGGER = "canguard.protect.state"


def model() -> LeakyI2t:
    return LeakyI2t(10.0, 20.0, 5.0)


def messages(caplog: pytest.LogCaptureFixture, level: int) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == LOGGER and r.levelno == level]


class TestLogLines:
    def test_a_missing_file_starts_cold_and_says_so(self, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
        path = tmp_path / "heat.json"
        caplog.set_level(logging.INFO, logger=LOGGER)
        HeatStore(path).load(0.0)
        assert messages(caplog, logging.INFO) == [f"no I²t state file {path}: starting cold"]

    @pytest.mark.parametrize(("text", "why"), [
        ("[]", "expected a JSON object, got list"),
        ('{"format": "x", "version": 1, "t": 1, "models": {}}', "'format' is 'x', expected 'canguard-heat'"),
        ('{"format": "canguard-heat", "version": 7, "t": 1, "models": {}}', "unsupported version 7 (expected 1)"),
        ('{"format": "canguard-heat", "version": 1, "t": "a", "models": {}}', "'t' must be a finite number, got 'a'"),
        ('{"format": "canguard-heat", "version": 1, "t": 1}', "'models' missing or not an object"),
        ('{"format": "canguard-heat", "version": 1, "t": 1, "models": []}', "'models' missing or not an object"),
    ])
    @pytest.mark.parametrize("on_corrupt", ["hot", "cold"])
    def test_a_corrupt_file_names_the_file_why_and_how_models_start(
        self, tmp_path: Path, caplog: pytest.LogCaptureFixture, text: str, why: str, on_corrupt: str
    ) -> None:
        path = tmp_path / "heat.json"
        path.write_text(text, encoding="utf-8")
        store = HeatStore(path, on_corrupt=on_corrupt)
        caplog.set_level(logging.WARNING, logger=LOGGER)
        store.load(0.0)
        assert store.corrupt == why
        assert messages(caplog, logging.WARNING) == [
            f"I²t state file {path} is unusable ({why}): models start {on_corrupt}"]

    def test_not_json(self, tmp_path: Path) -> None:
        path = tmp_path / "heat.json"
        path.write_text("{nope", encoding="utf-8")
        store = HeatStore(path)
        store.load(0.0)
        assert store.corrupt is not None and store.corrupt.startswith("not valid JSON: ")

    def test_a_good_file_logs_what_it_loaded(self, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
        path = tmp_path / "heat.json"
        HeatStore(path).save({"g": model()}, 10.0)
        caplog.set_level(logging.DEBUG, logger=LOGGER)
        HeatStore(path).load(15.0)
        assert messages(caplog, logging.DEBUG) == [
            f"loaded I²t state of 1 models from {path} (saved 5.000 s before 15.000)"]

    def test_a_bad_entry_starts_that_model_hot_and_says_which(
        self, tmp_path: Path, caplog: pytest.LogCaptureFixture
    ) -> None:
        path = tmp_path / "heat.json"
        HeatStore(path).save({"g": model(), "h": model()}, 10.0)
        doc = json.loads(path.read_text(encoding="utf-8"))
        doc["models"]["g"] = {"kind": "nonsense"}
        path.write_text(json.dumps(doc), encoding="utf-8")
        store = HeatStore(path)
        g, h = model(), model()
        caplog.set_level(logging.WARNING, logger=LOGGER)
        store.restore("g", g, 12.0)
        store.restore("h", h, 12.0)
        [line] = messages(caplog, logging.WARNING)
        assert line == (f"I²t state of 'g' in {path} is unusable (i2t state: 'params' missing or not a mapping): "
                        "it starts hot")
        assert g.tripped and g.since == 12.0  # hot from the restore time
        assert not h.tripped


class TestLoadOnce:
    def test_the_file_is_read_once(self, tmp_path: Path) -> None:
        """A file rewritten after the first read is not read again: every model restores from one snapshot."""
        path = tmp_path / "heat.json"
        hot = model()
        hot.set_hot(0.0)
        HeatStore(path).save({"g": hot}, 10.0)
        store = HeatStore(path)
        first = model()
        store.restore("g", first, 10.0)
        HeatStore(path).save({"g": model()}, 10.0)  # cold now
        second = model()
        store.restore("g", second, 10.0)
        assert first.level == second.level > 0.9

    def test_a_corrupt_file_starts_hot_at_the_restore_time(self, tmp_path: Path) -> None:
        path = tmp_path / "heat.json"
        path.write_text("[]", encoding="utf-8")
        m = model()
        HeatStore(path).restore("g", m, 42.0)
        assert m.tripped and m.since == 42.0


class TestFileOnDisk:
    def test_layout_is_sorted_and_indented_for_diffs(self, tmp_path: Path) -> None:
        """The same state gives the same bytes: keys sorted, one space of indent (git-diffable, stable)."""
        path = tmp_path / "heat.json"
        HeatStore(path).save({"b": model(), "a": model()}, 10.0)
        text = path.read_text(encoding="utf-8")
        assert text == json.dumps(json.loads(text), sort_keys=True, indent=1)
        assert text.startswith('{\n "format": "canguard-heat",')
        assert list(json.loads(text)["models"]) == ["a", "b"]

    def test_missing_directories_are_created(self, tmp_path: Path) -> None:
        path = tmp_path / "var" / "lib" / "canguard" / "heat.json"
        HeatStore(path).save({"g": model()}, 1.0)
        assert json.loads(path.read_text(encoding="utf-8"))["t"] == 1.0

    def test_the_temp_file_sits_beside_the_state_file(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """The rename is atomic only within one filesystem: the temp file is written next to the target."""
        path = tmp_path / "heat.json"
        seen: list[tuple[str, str]] = []
        replace = os.replace

        def spy(src: Any, dst: Any) -> None:
            seen.append((str(src), str(dst)))
            replace(src, dst)

        monkeypatch.setattr(os, "replace", spy)
        HeatStore(path).save({"g": model()}, 1.0)
        [(src, dst)] = seen
        assert dst == str(path)
        assert Path(src).parent == tmp_path
        assert Path(src).name.startswith(".heat.json.") and src.endswith(".tmp")

    def test_a_failed_write_names_the_file_keeps_the_old_one_and_leaves_nothing(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        path = tmp_path / "heat.json"
        HeatStore(path).save({"g": model()}, 1.0)
        before = path.read_bytes()

        def refuse(src: Any, dst: Any) -> None:
            raise OSError(28, "No space left on device")

        monkeypatch.setattr(os, "replace", refuse)
        with pytest.raises(StateFileError) as err:
            HeatStore(path).save({"g": model()}, 2.0)
        assert str(err.value) == f"cannot write I²t state file {path}: [Errno 28] No space left on device"
        assert path.read_bytes() == before
        assert sorted(p.name for p in tmp_path.iterdir()) == ["heat.json"]

    def test_a_parent_that_is_a_file_is_an_error_and_closes_nothing_of_ours(self, tmp_path: Path) -> None:
        (tmp_path / "blocker").write_text("x", encoding="utf-8")
        path = tmp_path / "blocker" / "heat.json"
        with pytest.raises(StateFileError, match=f"cannot write I²t state file {path}"):
            HeatStore(path).save({"g": model()}, 1.0)
        os.fstat(1)  # stdout is still open (nothing but our own descriptors is closed on the way out)
        os.fstat(2)

    def test_a_value_json_cannot_hold_is_refused_not_written(self, tmp_path: Path) -> None:
        """NaN is not JSON: the save fails naming the file; the old file stays."""

        class NanHeat:
            def export(self) -> dict[str, Any]:
                return {"kind": "leaky", "acc": math.nan}

            def restore(self, state: Any, downtime_s: float) -> None: ...

            def set_hot(self, t: float | None = None) -> None: ...

        path = tmp_path / "heat.json"
        with pytest.raises(StateFileError) as err:
            HeatStore(path).save({"g": NanHeat()}, 1.0)
        assert str(err.value).startswith(f"cannot encode I²t state for {path}: ")
        assert not path.exists()

    @pytest.mark.parametrize("verb", ["save", "restore"])
    def test_a_model_without_heat_is_a_type_error_naming_it(self, tmp_path: Path, verb: str) -> None:
        store = HeatStore(tmp_path / "heat.json")
        with pytest.raises(TypeError) as err:
            if verb == "save":
                store.save({"k": 5}, 1.0)
            else:
                store.restore("k", 5, 1.0)
        assert str(err.value) == f"model 'k' (int) has no heat state to {verb}"


class TestProblems:
    def test_readable(self, tmp_path: Path) -> None:
        path = tmp_path / "heat.json"
        assert readable_problem(path) == "no such file"
        assert readable_problem(tmp_path) == "not a regular file"
        path.write_text("{}", encoding="utf-8")
        assert readable_problem(path) == ""
