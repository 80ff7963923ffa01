"""The I²t state directory fails while the daemon runs (safety table row H5).

The engine saves heat every ``state.save_period``; a save that fails is one ``error``
event (not one per tick), the guards go on judging, and the next save that works
clears the condition (a later failure is reported again).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml

from canguard.config.loader import load_config
from canguard.engine.core import Engine
from canguard.engine.gate import LogSink
from canguard.io.clock import ManualClock
from canguard.protect.state import HeatStore
from checkout import REPO

ROBOT = REPO / "config" / "examples" / "robot_guard.yaml"
T0 = 1_700_000_000.0


class Events:
    def __init__(self) -> None:
        self.lines: list[dict[str, object]] = []

    def write(self, event: dict[str, object]) -> None:
        self.lines.append(dict(event))

    def flush(self) -> None:
        pass


def test_failing_saves_are_one_event_and_the_guards_go_on(tmp_path: Path) -> None:
    doc = yaml.safe_load(ROBOT.read_text(encoding="utf-8"))
    doc["dbc"] = [str((ROBOT.parent / d).resolve()) for d in doc["dbc"]]
    doc["tree"]["file"] = str((ROBOT.parent / doc["tree"]["file"]).resolve())
    doc.pop("events", None)
    state_dir = tmp_path / "state"
    doc["state"] = {"file": str(state_dir / "i2t.json"), "save_period": 1}
    cfg_path = tmp_path / "c.yaml"
    cfg_path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    cfg = load_config(cfg_path)
    clock = ManualClock(T0)
    events = Events()
    engine = Engine(cfg, clock, LogSink(clock.now, cfg.buses), events=events, heat=HeatStore(cfg.state.file),
                    save_heat=True)
    engine.start(T0)

    def run(until: float) -> None:
        t = clock.now()
        while t < until:
            t += 0.05
            engine.advance(t)
            clock.advance_to(t)

    run(T0 + 2.0)
    assert (state_dir / "i2t.json").exists()
    shutil.rmtree(state_dir)
    state_dir.write_text("not a directory")  # the state directory is gone: saves cannot work
    ticks = engine.stats.ticks
    run(T0 + 6.0)
    errors = [e for e in events.lines if e["event"] == "error" and "cannot save I²t state" in str(e["reason"])]
    assert len(errors) == 1
    assert engine.stats.ticks > ticks + 50  # the guards kept ticking
    state_dir.unlink()
    run(T0 + 8.0)
    assert (state_dir / "i2t.json").exists()  # saving works again by itself
    state_dir.joinpath("i2t.json").unlink()
    shutil.rmtree(state_dir)
    state_dir.write_text("gone again")
    run(T0 + 10.0)
    errors = [e for e in events.lines if e["event"] == "error" and "cannot save I²t state" in str(e["reason"])]
    assert len(errors) == 2  # a new failure after a success is reported again
