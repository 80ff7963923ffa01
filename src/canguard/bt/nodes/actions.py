"""Action nodes: frames handed to the context's sink or task gate (ExecuteTask, EmitStop, ResetStop, config actions).

A config action's ``task`` frames are withheld during a stop, ``recovery`` frames are not.
"""

from __future__ import annotations

from typing import Any

import py_trees

from canguard.bt.nodes.base import RUNNING, SUCCESS, CanguardNode, halted, port_info
from canguard.config.schema import ActionConfig


class ExecuteTask(CanguardNode, py_trees.behaviour.Behaviour):
    """run the robot's task (task frames every period) while ticked; halt stops it"""

    QUIET_RETICK = True

    def update(self) -> py_trees.common.Status:
        self.ctx.task.run(self.name, self.ctx.clock.now())
        return RUNNING

    def terminate(self, new_status: py_trees.common.Status) -> None:
        if halted(self, new_status):
            self.ctx.task.halt(self.name, self.ctx.clock.now())


class EmitStop(CanguardNode, py_trees.behaviour.Behaviour):
    """send the config's stop frames once"""

    def update(self) -> py_trees.common.Status:
        if self.ctx.stop_frames:
            self.ctx.sink.send(self.ctx.stop_frames, origin=self.name)
        return SUCCESS


class ConfiguredAction(CanguardNode, py_trees.behaviour.Behaviour):
    """an actions: entry of the config: send its frames"""

    OUTPUT_PORTS = {  # noqa: RUF012
        "output_time": port_info(float, "receives the time (s) the action ran, e.g. {last_recovery_time}",
                                 required=False),
    }

    def __init__(self, name: str, *, action: ActionConfig, **kwargs: Any) -> None:
        super().__init__(name=name, **kwargs)
        self.action = action
        self.role = "task" if action.role == "auto" else action.role  # auto: see assign_roles

    def update(self) -> py_trees.common.Status:
        frames = self.action.frames
        now = float(self.ctx.clock.now())
        gate_action = getattr(self.ctx.task, "action", None)
        if gate_action is None:  # a context without a task gate (tests of single nodes)
            if frames:
                self.ctx.sink.send(frames, origin=self.name)
            self.feedback_message = f"{self.action.name}: {len(frames)} frame(s)"
        else:
            gate_action(self.name, self.role, frames, now, self._note)
        self.write("output_time", now)
        return SUCCESS

    def _note(self, what: str) -> None:
        self.feedback_message = f"{self.action.name} ({self.role}): {what}"


class ResetStop(CanguardNode, py_trees.behaviour.Behaviour):
    """reset a stop (stop.release: manual): the stop ends at this tick's end if the release rule holds"""

    def update(self) -> py_trees.common.Status:
        reset = getattr(self.ctx.task, "reset", None)
        self.feedback_message = reset(self.name, self.ctx.clock.now()) if reset is not None else "no task gate"
        return SUCCESS


def assign_roles(root: py_trees.behaviour.Behaviour) -> bool:
    """Resolve ``role: auto`` (``recovery`` in a tree with ExecuteTask, else ``task``); True when the tree has a
    task (ExecuteTask or an action of role ``task``)."""
    nodes = list(root.iterate())
    has_execute = any(isinstance(n, ExecuteTask) for n in nodes)
    has_task = has_execute
    for n in nodes:
        if isinstance(n, ConfiguredAction):
            n.role = n.action.role if n.action.role != "auto" else ("recovery" if has_execute else "task")
            has_task = has_task or n.role == "task"
    return has_task
