"""BehaviorTree.CPP 4's pre- and post-conditions on any node: ``_failureIf``, ``_successIf``, ``_onSuccess``...

Scripts in these attributes are parsed once, at load (a syntax error is a load error
with the file and line), and run on the node's (sub)tree blackboard:

- before a node starts (it is not RUNNING): ``_failureIf`` true → FAILURE, ``_successIf``
  true → SUCCESS, ``_skipIf`` true → SKIPPED, ``_while`` false → SKIPPED, in that order,
  without ticking the node (as BT.CPP's ``checkPreConditions``);
- while it runs: ``_while`` false halts it (``_onHalted`` runs) and it returns SKIPPED;
- after it (also when a pre-condition gave the status, as in BT.CPP's ``executeTick``):
  ``_onSuccess`` when it returned SUCCESS, ``_onFailure`` when FAILURE, ``_post`` after
  either; ``_onHalted`` when it is halted while RUNNING.

SKIPPED is BT.CPP's: the node stays IDLE and its parent learns it was skipped
(:data:`canguard.bt.nodes.base.SKIPPED`; sequences and fallbacks go on to the next child,
a control whose children were all skipped is skipped itself). A script that fails while
it runs counts as false (pre) or is skipped (post) and the node's feedback says why.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING, Any

import py_trees

from canguard.bt.nodes.base import FAILURE, INVALID, RUNNING, SKIPPED, SUCCESS, mark_skipped
from canguard.bt.scripting import ScriptError

if TYPE_CHECKING:
    from canguard.bt.nodes.builtins import TreeBlackboard
    from canguard.bt.scripting import Script

PRE = ("_failureIf", "_successIf", "_skipIf", "_while")
POST = ("_onSuccess", "_onFailure", "_post", "_onHalted")
ALL = PRE + POST


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
            problems.append(f"{attr}: script {text!r}: {exc}")
    return scripts, problems


def _holds(node: py_trees.behaviour.Behaviour, script: Script, board: TreeBlackboard, attr: str) -> bool:
    try:
        return bool(script.condition(board))
    except ScriptError as exc:
        node.feedback_message = f"{attr}: {exc}"
        return False


def _run(node: py_trees.behaviour.Behaviour, script: Script | None, board: TreeBlackboard, attr: str) -> None:
    if script is None:
        return
    try:
        script.run(board)
    except ScriptError as exc:
        node.feedback_message = f"{attr}: {exc}"


def _preconditions(node: py_trees.behaviour.Behaviour, scripts: Mapping[str, Script], board: Any) -> Any:
    """The status a pre-condition gives the node instead of ticking it (None: tick it), as BT.CPP's
    ``checkPreConditions``: ``_failureIf``, ``_successIf``, ``_skipIf`` before a tick, ``_while`` always."""
    if node.status != RUNNING:
        for attr, status in (("_failureIf", FAILURE), ("_successIf", SUCCESS), ("_skipIf", SKIPPED)):
            script = scripts.get(attr)
            if script is not None and _holds(node, script, board, attr):
                return status
    script = scripts.get("_while")
    if script is not None and not _holds(node, script, board, "_while"):
        return SKIPPED  # a running node is halted (mark_skipped stops it: _onHalted runs)
    return None


def _postconditions(node: py_trees.behaviour.Behaviour, scripts: Mapping[str, Script], board: Any) -> None:
    """As BT.CPP's executeTick: the post-conditions follow a completed status, substituted or ticked."""
    if getattr(node, "skipped", False):
        return
    if node.status == SUCCESS:
        _run(node, scripts.get("_onSuccess"), board, "_onSuccess")
    elif node.status == FAILURE:
        _run(node, scripts.get("_onFailure"), board, "_onFailure")
    if node.status in (SUCCESS, FAILURE):
        _run(node, scripts.get("_post"), board, "_post")


def install(node: py_trees.behaviour.Behaviour, scripts: Mapping[str, Script]) -> None:
    """Wrap ``node``'s tick and stop with its conditions (instance attributes: the class is untouched)."""
    if not scripts:
        return
    from canguard.bt.nodes.builtins import TreeBlackboard  # with the scripts: only for nodes that have some

    board = TreeBlackboard(getattr(node, "_subtree_namespace", None) or "/")
    tick, stop = node.tick, node.stop

    def tick_with_conditions() -> Iterator[py_trees.behaviour.Behaviour]:
        substituted = _preconditions(node, scripts, board)
        if substituted is SKIPPED:
            mark_skipped(node)
            yield node
            return
        if substituted is not None:
            stop(substituted)
            yield node
        else:
            yield from tick()
        _postconditions(node, scripts, board)

    def stop_with_conditions(new_status: Any = INVALID) -> None:
        halted = new_status == INVALID and node.status == RUNNING
        stop(new_status)
        if halted:
            _run(node, scripts.get("_onHalted"), board, "_onHalted")

    node.tick = tick_with_conditions  # type: ignore[method-assign]
    node.stop = stop_with_conditions  # type: ignore[method-assign]
