"""``replay --export-signals FILE.mcap``: what the engine saw and did, as MCAP channels Foxglove plots as they are.

In the log's time base, as ROS 2 CDR messages with their ``.msg`` schemas; the channels: docs/commands.md.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from canguard.io.mcapwrite import McapWriter, ns_of
from canguard.io.rosmsgs import cdr_frame, frame_type, full_definition
from canguard.report.export import SignalExport

if TYPE_CHECKING:
    from canguard.engine.core import Engine
    from canguard.io.frame import Frame

SAMPLE = ("canguard_msgs/msg/Sample", "float64 value\nbool valid\n")
GUARD = ("canguard_msgs/msg/Guard", "float64 value\nfloat64 threshold\nfloat64 level_pct\nbool tripped\n")
_CDR_LE = np.array([0, 1, 0, 0], dtype=np.uint8)
_FLUSH = 65_536
"""Guard states buffered before they are written."""


def topic_name(*parts: str) -> str:
    """A ROS topic name under ``/canguard`` of ``parts`` (a source named ``/battery_state`` as ``battery_state``;
    characters a topic name may not hold as ``_``)."""
    clean = ["".join(c if c.isalnum() or c == "_" else "_" for c in p.strip("/")) or "_" for p in parts]
    return "/canguard/" + "/".join(clean)


def _cdr(*columns: np.ndarray) -> np.ndarray:
    """Messages of float64 columns then bool columns, as CDR lays them out: one row of bytes per message."""
    n = columns[0].size
    parts = [np.broadcast_to(_CDR_LE, (n, 4))]
    for col in columns:
        parts.append(col.astype("<f8").view(np.uint8).reshape(n, 8) if col.dtype != np.bool_
                     else col.astype(np.uint8).reshape(n, 1))
    return np.ascontiguousarray(np.hstack(parts))


class _Samples:
    """:class:`SignalExport`'s rows as one channel per source and role (a :class:`SampleTable`)."""

    def __init__(self, writer: McapWriter) -> None:
        self.writer = writer
        self.schema = writer.schema(SAMPLE[0], "ros2msg", SAMPLE[1])
        self.channels: dict[tuple[str, str], int] = {}
        self._lanes: list[int] = []
        """Per sample code: its channel."""
        self._valid: list[bool] = []
        """Per sample code: a valid value (no reason)."""

    def write(self, t: Any, codes: Any, values: Any, keys: Sequence[tuple[str, str, str]]) -> None:
        """A batch of samples, each (source, signal)'s on its channel."""
        for key in keys[len(self._lanes):]:  # codes met since the last batch
            channel = self.channels.get(key[:2])
            if channel is None:
                channel = self.channels[key[:2]] = self.writer.channel(topic_name("samples", *key[:2]), self.schema,
                                                                       "cdr")
            self._lanes.append(channel)
            self._valid.append(not key[2])
        lanes = np.asarray(self._lanes, dtype=np.int64)[codes]
        valid = np.asarray(self._valid, dtype=bool)[codes]
        times = ns_of(t)
        for channel in np.unique(lanes).tolist():
            rows = np.flatnonzero(lanes == channel)
            self.writer.messages(channel, times[rows], _cdr(values[rows], valid[rows]))

    def close(self) -> None:
        """Nothing of its own: the export closes the file."""


class McapExport:
    """Everything an engine does on a replay, into one MCAP file (see the module docstring)."""

    def __init__(self, engine: Engine, path: Path, log: str) -> None:
        self.engine = engine
        self.writer = McapWriter(path, profile="ros2")
        self.signals = SignalExport(engine, path, log, table=_Samples(self.writer))
        w = self.writer
        guard_schema = w.schema(GUARD[0], "ros2msg", GUARD[1])
        self._guards = [(g, w.channel(topic_name("guards", g.node), guard_schema, "cdr")) for g in engine.guards()]
        self._states: list[list[float]] = [[] for _ in self._guards]
        self._ticks: list[float] = []
        events = w.schema("canguard.Event", "jsonschema", json.dumps({"type": "object"}))
        self._events = w.channel("/canguard/events", events, "json")
        self._frames: dict[bool, int] = {}
        self._out: list[Frame] = []
        engine.listen(self._event)

    def publish(self, engine: Any, now: float) -> None:
        """A tick that ran (a :class:`~canguard.engine.stats.TickObserver`: ticks proven to repeat the last one are
        not run, and not recorded; a tick hook would have them all run): each guard's state."""
        self._ticks.append(now)
        for (guard, _channel), states in zip(self._guards, self._states, strict=True):
            snap = guard.snapshot()
            states.extend((snap.value, snap.threshold, snap.level_pct, 1.0 if snap.tripped else 0.0))
        if len(self._ticks) >= _FLUSH:
            self._flush_guards()

    def _flush_guards(self) -> None:
        times = ns_of(self._ticks)
        for (_guard, channel), states in zip(self._guards, self._states, strict=True):
            table = np.asarray(states, dtype=np.float64).reshape(-1, 4)
            self.writer.messages(channel, times, _cdr(table[:, 0], table[:, 1], table[:, 2], table[:, 3] != 0))
            states.clear()
        self._ticks.clear()

    def _event(self, ev: dict[str, Any]) -> None:
        t = float(ev.get("t", math.nan))
        if math.isfinite(t):  # JSON has no NaN: a value the event could not give is null
            fields = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in ev.items()}
            text = json.dumps(fields, default=str, sort_keys=True)
            self.writer.message(self._events, int(ns_of(t)), text.encode("utf-8"))

    def sent(self, frames: list[Frame]) -> None:
        """Frames canguard sent, as ROS CAN frame messages (written a batch at a time)."""
        self._out.extend(frames)
        if len(self._out) >= _FLUSH:
            self._flush_frames()

    def _flush_frames(self) -> None:
        """The frames sent so far, each distinct frame serialised once and stamped per send by numpy."""
        if not self._out:
            return
        stamps = ns_of([f.t for f in self._out])
        groups: dict[tuple[Any, ...], list[int]] = {}
        for i, f in enumerate(self._out):
            groups.setdefault(f[1:6], []).append(i)  # channel, id, data, extended, fd: one message but its stamp
        for (name, cid, data, extended, fd), rows in groups.items():
            at = np.asarray(rows, dtype=np.intp)
            ns = stamps[at]
            template = np.frombuffer(cdr_frame(0, name, cid, bytes(data), extended=extended, fd=fd), np.uint8)
            table = np.tile(template, (at.size, 1))
            sec, nanosec = np.divmod(ns, 1_000_000_000)
            table[:, 4:8] = sec.astype("<i4").view(np.uint8).reshape(-1, 4)
            table[:, 8:12] = nanosec.astype("<u4").view(np.uint8).reshape(-1, 4)
            self.writer.messages(self._frame_channel(fd), ns, table)
        self._out.clear()

    def _frame_channel(self, fd: bool) -> int:
        channel = self._frames.get(fd)
        if channel is None:
            msgtype = frame_type(fd)
            schema = self.writer.schema(msgtype, "ros2msg", full_definition(msgtype))
            topic = "/canguard/frames_out_fd" if fd else "/canguard/frames_out"
            channel = self._frames[fd] = self.writer.channel(topic, schema, "cdr")
        return channel

    def close(self) -> None:
        """Write what is left and end the file."""
        try:
            self.signals.close()
            self._flush_guards()
            self._flush_frames()
        finally:
            self.writer.close()

