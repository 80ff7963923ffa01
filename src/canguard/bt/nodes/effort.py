"""IsJointEffortNormal (design note 004, section 3.2): every joint's |effort| within a limit, one Threshold each."""

from __future__ import annotations

import math

import py_trees

from canguard.bt.nodes.base import FAILURE, SUCCESS, port_info
from canguard.bt.nodes.current import GuardNode
from canguard.config.schema import SourceConfig
from canguard.protect.base import REASON_NO_DATA, ProtectionModel
from canguard.protect.threshold import Threshold


class IsJointEffortNormal(GuardNode):
    """SUCCESS while every joint's |effort| <= max_effort and every joint is fresh and finite"""

    INPUT_PORTS = {  # noqa: RUF012 - py_trees reads ports as plain class dicts
        "topic_name": port_info(str, "source name (joints kind) from the config"),
        "max_effort": port_info(float, "maximum allowed |effort| of any joint (N·m or N)", 100.0),
    }
    SOURCE_KINDS = ("joints",)
    _NAMES = {"max_value": "max_effort"}  # noqa: RUF012
    failed_joint = ""  # the first failing joint, named by the feedback

    def _build(self, source: SourceConfig) -> None:
        limit = self.port("max_effort")
        self.models: list[tuple[str, Threshold]] = []
        for role in source.value_roles:
            model = Threshold(limit)
            self.ctx.subscribe(source.name, role, model)
            self.models.append((role, model))

    def guarded(self) -> list[tuple[str, ProtectionModel, str]]:
        """One ``(joint, model, "threshold")`` per joint."""
        return [(role, model, "threshold") for role, model in self.models]

    def update(self) -> py_trees.common.Status:
        now = self._clock.now()
        self.judged_t = now  # the engine checks that a running task's guards keep being ticked (T4)
        bad = self._reread(("max_effort",), (m for _, m in self.models), lambda m: (m.max_value,), Threshold.set_max)
        failed: tuple[str, str, float, float] | None = None
        for role, model in self.models:
            snap = model.poll(now)  # poll every joint: each latch restarts at every tick
            reason = "" if failed is not None else self._why(now, role, snap, bad)
            if reason:
                failed = (role, reason, snap.value, snap.threshold)
        if not self.models:
            failed = ("", REASON_NO_DATA, math.nan, math.nan)
        ok = failed is None
        # Another joint failing for the same reason is a new cause too (its feedback names the joint).
        if ok is not self.ok or (failed is not None and (failed[1], failed[0]) != (self.reason, self.failed_joint)):
            self.failed_joint = failed[0] if failed is not None else ""
            if failed is None:
                seen = [(m.snapshot(), role) for role, m in self.models if m.last_t is not None]
                snap, role = max(seen, key=lambda sr: sr[0].value)
                self._edge(True, "", role, snap.value, snap.threshold)
            else:
                self._edge(False, failed[1], failed[0], failed[2], failed[3])
        return SUCCESS if ok else FAILURE
