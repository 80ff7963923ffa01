"""Action nodes: frames handed to the context's sink or task gate.

- **ExecuteTask**: the robot's task. Each tick calls ``ctx.task.run(node, now)``
  (the gate sends the task's enable / heartbeat frames at its period) and returns
  RUNNING; a halt (interrupted while RUNNING, e.g. a ReactiveSequence guard
  failing) calls ``ctx.task.halt(node, now)``, which sends the stop frames.
- **EmitStop**: sends the config's stop frames (``ctx.stop_frames``) once; SUCCESS.
- **ConfiguredAction**: one node type per ``actions:`` entry of the config (the
  node ID is the entry's key, e.g. PerformRecovery): sends its frames with
  ``ctx.sink.send(frames, origin=<node name>)``, writes ``output_time`` = now when
  that port is wired, SUCCESS. The placeholder actions of the design notes
  (PerformDiagnostics, NavigateToPose, ContinueOperation...) are such entries.
"""

from __future__ import annotations

from typing import Any

import py_trees

from ..config import ActionConfig
from .base import RUNNING, SUCCESS, CanguardNode, halted, port_info


class ExecuteTask(CanguardNode, py_trees.behaviour.Behaviour):
    """Runs the task while ticked (RUNNING); stops it when halted."""

    KIND = "Action"
    DESCRIPTION = "run the robot's task (task frames every period) while ticked; halt stops it"
    INPUT_PORTS = {}  # noqa: RUF012 - py_trees reads ports as plain class dicts
    OUTPUT_PORTS = {}  # noqa: RUF012

    def update(self) -> py_trees.common.Status:
        """Keep the task running."""
        self.ctx.task.run(self.name, self.ctx.clock.now())
        return RUNNING

    def terminate(self, new_status: py_trees.common.Status) -> None:
        """A halt (interrupted while RUNNING) stops the task."""
        if halted(self, new_status):
            self.ctx.task.halt(self.name, self.ctx.clock.now())


class EmitStop(CanguardNode, py_trees.behaviour.Behaviour):
    """Sends the config's stop frames; SUCCESS."""

    KIND = "Action"
    DESCRIPTION = "send the config's stop frames once"
    INPUT_PORTS = {}  # noqa: RUF012
    OUTPUT_PORTS = {}  # noqa: RUF012

    def update(self) -> py_trees.common.Status:
        """Hand the stop frames to the sink."""
        frames = self.ctx.stop_frames
        if frames:
            self.ctx.sink.send(frames, origin=self.name)
        return SUCCESS


class ConfiguredAction(CanguardNode, py_trees.behaviour.Behaviour):
    """An ``actions:`` entry of the config: sends its frames; writes output_time when wired; SUCCESS."""

    KIND = "Action"
    DESCRIPTION = "an actions: entry of the config: send its frames"
    INPUT_PORTS = {}  # noqa: RUF012
    OUTPUT_PORTS = {  # noqa: RUF012
        "output_time": port_info(
            float, "receives the time (s) the action ran, e.g. {last_recovery_time}", required=False
        ),
    }

    def __init__(self, name: str, *, action: ActionConfig, **kwargs: Any) -> None:
        super().__init__(name=name, **kwargs)
        self.action = action

    def update(self) -> py_trees.common.Status:
        """Send the frames, note the time."""
        frames = self.action.frames
        if frames:
            self.ctx.sink.send(frames, origin=self.name)
        if self._wired:
            self.write("output_time", float(self.ctx.clock.now()))
        self.feedback_message = f"{self.action.name}: {len(frames)} frame(s)"
        return SUCCESS
