"""Soak: reloads leave nothing behind in py_trees' global blackboard, and old engines are freed.

Every node of a loaded tree registers a blackboard client and keys under a namespace
made of its uuid; py_trees keeps them in class attributes until removed. Before the
fix each reload added the old tree's 14 clients and ~80 keys for good: memory that
grew with every SIGHUP for the life of the daemon.
"""

from __future__ import annotations

import gc
import weakref
from pathlib import Path
from typing import Any

import yaml
from py_trees.blackboard import Blackboard

from canguard.engine.core import Engine
from canguard.service.daemon import Daemon, tree_clients
from canguard.service.systemd import Notifier
from checkout import REPO

ROBOT = REPO / "config" / "examples" / "robot_guard.yaml"
RELOADS = 12


def robot_config(tmp: Path, channel: str, tree: Path | None = None) -> Path:
    """The whole-robot example on a virtual bus, with absolute paths and its files in ``tmp``."""
    doc: dict[str, Any] = yaml.safe_load(ROBOT.read_text(encoding="utf-8"))
    doc["dbc"] = [str((ROBOT.parent / d).resolve()) for d in doc["dbc"]]
    doc["tree"]["file"] = str(tree or (ROBOT.parent / doc["tree"]["file"]).resolve())
    doc["buses"] = {"main": {"interface": "virtual", "channel": channel}}
    doc["events"] = str(tmp / "events.jsonl")
    doc["state"]["file"] = str(tmp / "i2t_state.json")
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def board() -> tuple[int, int, int]:
    """(clients, keys, values) on py_trees' global blackboard."""
    return len(Blackboard.clients), len(Blackboard.metadata), len(Blackboard.storage)


def test_good_reloads_leave_the_blackboard_as_one_tree_and_free_the_old_engines(tmp_path: Path) -> None:
    """N reloads: the blackboard holds exactly the running tree's clients and keys; no old engine survives."""
    daemon = Daemon(robot_config(tmp_path, "reload-memory-good"), notifier=Notifier(env={}))
    try:
        daemon.engine.start(daemon.clock.now())
        daemon.engine.advance(daemon.clock.now())
        one_tree = board()
        old: list[weakref.ref[Engine]] = []
        for _ in range(RELOADS):
            old.append(weakref.ref(daemon.engine))
            assert daemon.reload()
            daemon.engine.advance(daemon.clock.now())
        assert board() == one_tree
        assert set(Blackboard.clients) == tree_clients(daemon.engine.root)
        # the running tree's keys are all there, the shared root keys ({axis0_i2t_pct}) with them
        assert "/axis0_i2t_pct" in Blackboard.metadata
        gc.collect()
        assert [r for r in old if r() is not None] == []
    finally:
        daemon.journal.close()


def test_reloads_rejected_half_way_through_the_tree_leave_nothing(tmp_path: Path) -> None:
    """A tree that parses but fails to bind (a port value refused): its nodes' clients and keys are removed."""
    good = (ROBOT.parent / "../trees/robot_guard.xml").resolve()
    bad = tmp_path / "bad.xml"
    bad.write_text(good.read_text(encoding="utf-8").replace('continuous_current="10.0"', 'continuous_current="0"'),
                   encoding="utf-8")
    config = robot_config(tmp_path, "reload-memory-bad")
    daemon = Daemon(config, notifier=Notifier(env={}))
    try:
        daemon.engine.start(daemon.clock.now())
        one_tree = board()
        robot_config(tmp_path, "reload-memory-bad", tree=bad)
        for _ in range(RELOADS):
            assert not daemon.reload()
        assert board() == one_tree
        robot_config(tmp_path, "reload-memory-bad")
        assert daemon.reload()
        assert board() == one_tree
    finally:
        daemon.journal.close()
