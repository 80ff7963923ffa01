"""Every log of a replay run starts from a clean state.

``canguard replay a.log b.log`` must give b.log exactly the summary that
``canguard replay b.log`` gives: no blackboard key, timer, latched trip or task
gate state carries over from a, and ``--jobs`` changes nothing. Before the fix the
cooldown_recovery example sent 4 frames on each log alone and 0 on every log after
the first (its cooldown's last run time stayed on py_trees' class-level blackboard).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from canguard.cli.main import main
from checkout import REPO

LOGS = sorted((REPO / "examples").glob("*.log.gz"))
CONFIGS = [*sorted((REPO / "config" / "examples").glob("*.yaml")), REPO / "config" / "canguard.yaml"]
TIMED = {"profiling"}
"""Configs whose tree decides on Profile's timing of this machine's CPU work (docs/trees.md): a loaded machine
may stop a replay of them where a quiet one does not, so they cannot be held byte-identical across runs."""


def replay(capsys: pytest.CaptureFixture[str], config: Path, logs: list[Path], *extra: str) -> list[Any]:
    """Per-log summaries of one ``canguard replay --json`` run, as printed."""
    capsys.readouterr()
    rc = main(["replay", "-c", str(config), "--json", *extra, *map(str, logs)])
    assert rc == 0, capsys.readouterr().err
    out = json.loads(capsys.readouterr().out)
    return out if isinstance(out, list) else [out]


_ONE_RUN: dict[Path, list[Any]] = {}


def in_one_run(capsys: pytest.CaptureFixture[str], config: Path) -> list[Any]:
    """Per-log summaries of one run over the eight logs and the first again (:func:`replay`); one such run per
    config in this process, which every test here that needs the eight logs in one process reads (the summaries
    of the first eight are those of a run of the eight alone: a log's summary is printed before the next starts)."""
    if config not in _ONE_RUN:
        _ONE_RUN[config] = replay(capsys, config, [*LOGS, LOGS[0]])
    return _ONE_RUN[config]


def test_eight_example_logs() -> None:
    """The issue's check runs over the eight example logs."""
    assert len(LOGS) == 8


# protected_operation.yaml is left out: the bundled config (canguard) runs the same tree with all it has and more
# (the axes' sources, the I²t state file, the stop's confirmation and escalation).
@pytest.mark.parametrize("config", [c for c in CONFIGS if c.stem not in {*TIMED, "protected_operation"}],
                         ids=lambda p: p.stem)
def test_together_equal_one_by_one(capsys: pytest.CaptureFixture[str], config: Path) -> None:
    """Each log's summary in one run of all eight, the first again after them, is byte-identical to its own run."""
    order = [*LOGS, LOGS[0]]  # one run in which every log follows another (the first log twice)
    together = in_one_run(capsys, config)
    assert [s["log"] for s in together] == [str(p) for p in order]
    # The first log of that run is replayed from a clean state as it is alone: only the others are run alone.
    alone = {s["log"]: json.dumps(s, sort_keys=True) for log in LOGS[1:] for s in replay(capsys, config, [log])}
    alone[together[0]["log"]] = json.dumps(together[0], sort_keys=True)
    for s in together:
        assert json.dumps(s, sort_keys=True) == alone[s["log"]], f"{s['log']} differs after its neighbours"


def test_jobs_2_equals_one_process(capsys: pytest.CaptureFixture[str]) -> None:
    """--jobs 2 gives the same list as one process (each worker replays several logs), on the example that leaked."""
    config = next(c for c in CONFIGS if c.stem == "cooldown_recovery")
    assert replay(capsys, config, LOGS, "--jobs", "2") == in_one_run(capsys, config)[: len(LOGS)]


def test_a_cooldown_starts_cold_on_every_log(capsys: pytest.CaptureFixture[str]) -> None:
    """The case that leaked: the cooldown example sends its frames on every log, not only the first."""
    config = next(c for c in CONFIGS if c.stem == "cooldown_recovery")
    sent = [s["frames_sent"] for s in in_one_run(capsys, config)]
    assert all(n > 0 for n in sent), sent


def test_a_timed_tree_still_starts_clean_on_every_log(capsys: pytest.CaptureFixture[str]) -> None:
    """The Profile example also keeps no state between logs: its counts of ticks and frames match each log alone."""
    config = next(c for c in CONFIGS if c.stem in TIMED)
    keys = ("log", "frames", "ticks", "edge_ticks", "samples")
    alone = [{k: s.get(k) for k in keys} for log in LOGS for s in replay(capsys, config, [log])]
    together = [{k: s.get(k) for k in keys} for s in replay(capsys, config, LOGS)]
    assert together == alone
