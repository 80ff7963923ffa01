"""BehaviorTree.CPP 4's pre- and post-conditions on any node: ``_failureIf``, ``_successIf``, ``_onSuccess``...

Run in BT.CPP's order (``checkPreConditions``, ``executeTick``). A script that fails while it runs
fails the node, fail-safe (BT.CPP throws); one in ``_onHalted`` is only reported.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING, Any

import py_trees

from canguard.bt.nodes.base import FAILURE, INVALID, RUNNING, SKIPPED, SUCCESS, halted, mark_skipped, run_script
from canguard.bt.scripting import ScriptError
from canguard.errors import quote

if TYPE_CHECKING:
    from canguard.bt.scopes import TreeBlackboard
    from canguard.bt.scripting import Script

ALL = ("_failureIf", "_successIf", "_skipIf", "_while", "_onSuccess", "_onFailure", "_post", "_onHalted")
"""BT.CPP's pre-conditions, then its post-conditions."""


def take_conditions(attrib: dict[str, str]) -> tuple[dict[str, Script], list[str]]:
    """Remove the condition attributes from ``attrib``; (parsed scripts, problems as 'attr: why')."""
    scripts: dict[str, Script] = {}
    problems: list[str] = []
    for attr in ALL:
        text = attrib.pop(attr, None)
        if text is None:
            continue
        from canguard.bt.scripting import parse  # the language: only for nodes with conditions

        try:
            scripts[attr] = parse(text)
        except ScriptError as exc:
            problems.append(f"{attr}: script {quote(text)}: {exc}")
    return scripts, problems


def _run(node: py_trees.behaviour.Behaviour, script: Script | None, board: TreeBlackboard, attr: str) -> bool:
    """Run a post-condition script; False when it failed (its error noted on the node)."""
    if script is None:
        return True
    try:
        run_script(node, attr, script, board)
    except ScriptError:
        return False
    return True


def _precondition(node: py_trees.behaviour.Behaviour, scripts: Mapping[str, Script], board: TreeBlackboard) -> Any:
    """The status BT.CPP's ``checkPreConditions`` substitutes (None: tick the node)."""
    if node.status != RUNNING:
        for attr, status in (("_failureIf", FAILURE), ("_successIf", SUCCESS), ("_skipIf", SKIPPED)):
            script = scripts.get(attr)
            if script is not None and run_script(node, attr, script, board, condition=True):
                return status
    script = scripts.get("_while")
    if script is not None and not run_script(node, "_while", script, board, condition=True):
        return SKIPPED  # while running: halted below (mark_skipped stops it: _onHalted runs)
    return None


def install(node: py_trees.behaviour.Behaviour, scripts: Mapping[str, Script], board: TreeBlackboard) -> None:
    """Wrap ``node``'s tick and stop (instance attributes) with its conditions, run on ``board``."""
    if not scripts:
        return
    tick, stop = node.tick, node.stop

    def tick_with_conditions() -> Iterator[py_trees.behaviour.Behaviour]:
        try:
            substituted = _precondition(node, scripts, board)
        except ScriptError:  # fail-safe: the node fails (halted first if it was running)
            if node.status == RUNNING:
                stop_with_conditions(INVALID)
            stop(FAILURE)
            yield node
            return
        if substituted is SKIPPED:
            mark_skipped(node)
            yield node
            return
        if substituted is not None:
            stop(substituted)
            yield node
        else:
            yield from tick()
        # as BT.CPP's executeTick: the post-conditions follow a completed status, substituted or ticked
        if getattr(node, "skipped", False) or node.status not in (SUCCESS, FAILURE):
            return
        first = "_onSuccess" if node.status == SUCCESS else "_onFailure"
        if not (_run(node, scripts.get(first), board, first) and _run(node, scripts.get("_post"), board, "_post")):
            node.status = FAILURE  # a post-condition that fails fails the node (BT.CPP throws)

    def stop_with_conditions(new_status: Any = INVALID) -> None:
        was_halted = halted(node, new_status)
        stop(new_status)
        if was_halted:
            _run(node, scripts.get("_onHalted"), board, "_onHalted")

    node.tick = tick_with_conditions  # type: ignore[method-assign]
    node.stop = stop_with_conditions  # type: ignore[method-assign]
