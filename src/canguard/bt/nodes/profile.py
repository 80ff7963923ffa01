"""Profile: a transparent decorator that times its child's tick (design note 003).

The one real clock in nodes/: it measures CPU work (in replay the context's clock stands still
during a tick), the child's subtree ticked to completion inside the measured interval.
"""

from __future__ import annotations

from time import perf_counter
from typing import Any

import py_trees

from canguard.bt.nodes.base import RUNNING, DecoratorNode, end_as, halted, port_info


class Profile(DecoratorNode):
    """transparent: times its child's tick, outputs last/avg/max ms and count; resets on halt"""

    OUTPUT_PORTS = {  # noqa: RUF012
        "last_ms": port_info(float, "duration of the child's last tick (ms)", required=False),
        "avg_ms": port_info(float, "mean duration since the last reset (ms)", required=False),
        "max_ms": port_info(float, "longest duration since the last reset (ms)", required=False),
        "count": port_info(int, "ticks measured since the last reset", required=False),
    }

    def __init__(self, name: str, child: py_trees.behaviour.Behaviour, **kwargs: Any) -> None:
        super().__init__(name=name, child=child, **kwargs)
        self._outputs: tuple[str, ...] = ()
        self.reset_stats()

    def reset_stats(self) -> None:
        """Forget every measurement."""
        self.last_ms = 0.0
        self.total_ms = 0.0
        self.max_ms = 0.0
        self.count = 0

    @property
    def avg_ms(self) -> float:
        """Mean duration since the last reset (ms); 0 before any tick."""
        return self.total_ms / self.count if self.count else 0.0

    def setup_ports(self, *args: Any, **kwargs: Any) -> None:
        """Register ports, then pick the wired outputs once."""
        super().setup_ports(*args, **kwargs)
        self._outputs = tuple(p for p in ("last_ms", "avg_ms", "max_ms", "count") if self.is_wired(p))

    def tick(self) -> Any:
        if self.status != RUNNING:
            self.initialise()
        t0 = perf_counter()
        nodes = list(self.decorated.tick())
        ms = (perf_counter() - t0) * 1000.0
        yield from nodes
        self.last_ms = ms
        self.count += 1
        self.total_ms += ms
        if ms > self.max_ms:
            self.max_ms = ms
        for name in self._outputs:
            self.write(name, getattr(self, name))
        yield end_as(self, self.decorated.status)

    def terminate(self, new_status: py_trees.common.Status) -> None:
        if halted(self, new_status):
            self.reset_stats()
