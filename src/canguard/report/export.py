"""``replay --export-signals`` and ``--fleet-summary``: what a replay saw, as files other tools read.

Files and channels: docs/commands.md. Samples go out :data:`BATCH_ROWS` at a time (memory stays flat); each
log writes its own Parquet part file, joined in input order by :func:`combine_parts`.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from canguard.errors import ConfigError
from canguard.io.frame import INVALID_RANGE, Frame, Sample
from canguard.io.mcapwrite import McapWriter, ns_of
from canguard.io.rosmsgs import cdr_frame, frame_type, full_definition

if TYPE_CHECKING:
    from canguard.engine.core import Engine

FLAG = "--export-signals"
COLUMNS = {"log": "string", "t": "float64", "bus": "string", "source": "string", "signal": "string",
           "value": "float64", "reason": "string"}
"""The exported columns, in order, and their Arrow types."""
BATCH_ROWS = 65_536
"""Rows buffered before they are written as one record batch (a Parquet row group)."""


def require_pyarrow(flag: str = FLAG) -> tuple[Any, Any]:
    """``(pyarrow, pyarrow.parquet)``, or a ConfigError (exit 2) naming the flag and the extra."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise ConfigError(f"{flag}: writing Parquet needs pyarrow, an optional extra: "
                          "pip install 'canguard[fleet]' (or pip install pyarrow)") from None
    return pa, pq


def schema(pa: Any, columns: dict[str, str] = COLUMNS) -> Any:
    """The Arrow schema of ``columns`` (name: type name)."""
    return pa.schema([(name, getattr(pa, kind)()) for name, kind in columns.items()])


def check_export(path: Path, *, dask: bool = False) -> None:
    """Everything ``--export-signals`` needs, checked before any log is replayed (ConfigError: exit 2)."""
    if dask:
        raise ConfigError(f"{FLAG} cannot be combined with --dask: the workers of a cluster cannot write "
                          f"beside {path} on this machine; use --jobs N (local processes) instead")
    # Found, not imported: pyarrow starts a thread (jemalloc's) at import, and a process running other
    # threads is not forked for --jobs (canguard.cli.fleet._pool_context). The parts' writers import it.
    import importlib.util

    if not is_mcap(path) and importlib.util.find_spec("pyarrow") is None:
        require_pyarrow()  # raises: named, not imported
    from canguard.io.outputs import check_output

    check_output(path, FLAG, beside=True, expected="a file name such as signals.parquet in a writable directory")


def is_mcap(path: Path) -> bool:
    """``--export-signals FILE.mcap``: an MCAP file per log (:class:`McapExport`), not Parquet."""
    return path.suffix.lower() == ".mcap"


class SignalExport:
    """Streams every sample an engine decodes into one Parquet file, in bounded memory."""

    def __init__(self, engine: Engine, path: Path, log: str, *, table: _Samples | None = None) -> None:
        bus = {name: src.bus for name, src in engine.cfg.sources.items()}
        self.table: ParquetTable | _Samples = table if table is not None else ParquetTable(path, log, bus)
        """Where each batch of rows goes: a Parquet file, or an MCAP export's channels."""
        # The DBC [min|max] the source's health checks: a value outside is rejected as out_of_range
        # by the models although the decoder passed it (the decoder does not check ranges).
        self._ranges = {name: health.ranges for name, health in engine.ctx.health.items()}
        self._chunks: list[tuple[Any, Any, Any]] = []
        """Columns of samples in order (time, code, value arrays), waiting for a batch to be full."""
        self._pending = 0
        self._codes: dict[tuple[str, str, str], int] = {}
        """A small number per (source, signal, reason), the same for the whole export, in order of first use."""
        engine.sample_block = self._block

    def _reason_of(self, s: Sample) -> str:
        """The sample's reason, or ``out_of_range`` for a value the source's DBC range rejects."""
        reason, value = s.reason, s.value
        if not reason and not math.isnan(value):
            lo, hi = self._ranges.get(s.source, {}).get(s.signal, (None, None))
            if (lo is not None and value < lo) or (hi is not None and value > hi):
                return INVALID_RANGE
        return reason

    def _block(self, times: Sequence[Any], taken: list[tuple[list[tuple[str, str]], list[int], Sequence[Any]]],
               fed: list[tuple[int, Sample]]) -> None:
        """A replay's column block (``Engine.sample_block``): its samples in row order, as frame by frame. ``taken``:
        per message its outputs' (source, signal), rows and values (valid, in range: reason ""); ``fed``: the fed
        rows' samples (a row in both: its samples are the fed ones)."""
        from canguard.decode.rows import valued_table

        stamp = np.asarray(times, dtype=np.float64)
        fed_rows = np.array([row for row, _s in fed], dtype=np.intp)
        rows, values, codes = [], [], []
        for names, group, decoded in taken:
            idx = np.asarray(group, dtype=np.intp)
            keep, table = valued_table(decoded, len(names))
            if fed_rows.size:
                keep &= ~np.isin(idx, fed_rows)
            if not keep.any():
                continue
            width, taken_rows = len(names), idx[keep]
            rows.append(np.repeat(taken_rows, width))
            values.append(table[keep].ravel())  # row by row, each row's outputs in order
            codes.append(np.tile([self._code(name, "") for name in names], taken_rows.size))
        if fed:
            rows.append(fed_rows)
            values.append(np.array([s.value for _row, s in fed], dtype=np.float64))
            codes.append(np.array([self._code((s.source, s.signal), self._reason_of(s)) for _row, s in fed]))
        if not rows:
            return
        every = np.concatenate(rows)
        order = np.argsort(every, kind="stable")  # a sample's time is its row's
        self._chunks.append((stamp[every[order]], np.concatenate(codes).astype(np.intp)[order],
                             np.concatenate(values).astype(np.float64)[order]))
        self._pending += order.size
        while self._pending >= BATCH_ROWS:  # the row groups of one sample at a time
            self._flush()

    def _code(self, name: tuple[str, str], reason: str) -> int:
        return self._codes.setdefault((*name, reason), len(self._codes))

    def _flush(self) -> None:
        """The first :data:`BATCH_ROWS` samples waiting (all of them, when fewer) to the table."""
        if not self._chunks:
            return
        t, codes, values = (np.concatenate(cols) for cols in zip(*self._chunks, strict=True))
        n = min(t.size, BATCH_ROWS)
        self.table.write(t[:n], codes[:n], values[:n], list(self._codes))
        self._chunks = [(t[n:], codes[n:], values[n:])] if n < t.size else []
        self._pending = t.size - n

    def close(self) -> None:
        """Write what is buffered and close the table (a valid Parquet file even with no rows)."""
        while self._pending:
            self._flush()
        self.table.close()


class ParquetTable:
    """The rows as a Parquet file (:data:`COLUMNS`), a record batch (row group) per batch."""

    def __init__(self, path: Path, log: str, bus: dict[str, str]) -> None:
        self.pa, pq = require_pyarrow()
        self.log = log
        self.bus = bus
        self._schema = schema(self.pa)
        self._writer = pq.ParquetWriter(path, self._schema)

    def write(self, t: Any, codes: Any, values: Any, keys: Sequence[tuple[str, str, str]]) -> None:
        """One record batch."""
        source, signal, reason = (np.array([k[i] for k in keys], dtype=object)[codes] for i in range(3))
        bus = np.array([self.bus.get(k[0], "") for k in keys], dtype=object)[codes]
        columns = [[self.log] * len(t), t, bus, source, signal, values, reason]
        self._writer.write_batch(self.pa.RecordBatch.from_arrays(
            [self.pa.array(c, f.type) for c, f in zip(columns, self._schema, strict=True)], schema=self._schema))

    def close(self) -> None:
        """Close the file."""
        self._writer.close()


def discard_parts(parts: Sequence[Path]) -> None:
    """Remove the part files that exist (a run that did not finish leaves nothing behind)."""
    for p in parts:
        p.unlink(missing_ok=True)


def combine_parts(path: Path, parts: Sequence[Path], ok: Sequence[bool]) -> None:
    """Put the parts of the logs that replayed (``ok``) into ``path``, in order; remove every part."""
    kept = [p for p, good in zip(parts, ok, strict=True) if good and p.exists()]
    pa, pq = require_pyarrow()
    try:
        if len(kept) == 1:
            os.replace(kept[0], path)
            return
        with pq.ParquetWriter(path, schema(pa)) as writer:
            for part in kept:
                source = pq.ParquetFile(part)
                for i in range(source.num_row_groups):  # one row group at a time: memory stays flat
                    writer.write_table(source.read_row_group(i))
    finally:
        discard_parts(parts)


SAMPLE = ("canguard_msgs/msg/Sample", "float64 value\nbool valid\n")
GUARD = ("canguard_msgs/msg/Guard", "float64 value\nfloat64 threshold\nfloat64 level_pct\nbool tripped\n")
_CDR_LE = np.array([0, 1, 0, 0], dtype=np.uint8)
_FLUSH = 65_536
"""Guard states buffered before they are written."""


def topic_name(*parts: str) -> str:
    """A ROS topic name under ``/canguard`` of ``parts`` (``/battery_state`` as ``battery_state``; other characters
    a topic name may not hold as ``_``)."""
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
    """:class:`SignalExport`'s rows as one channel per source and role (as :class:`ParquetTable` writes them)."""

    def __init__(self, writer: McapWriter) -> None:
        self.writer = writer
        self.schema = writer.schema(SAMPLE[0], "ros2msg", SAMPLE[1])
        self.channels: dict[tuple[str, str], int] = {}
        self._lanes: list[int] = []  # per sample code: its channel, and whether its value is valid
        self._valid: list[bool] = []

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
        """A tick that ran (quiet ticks are not run): each guard's state."""
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
            if fd not in self._frames:
                msgtype = frame_type(fd)
                schema = self.writer.schema(msgtype, "ros2msg", full_definition(msgtype))
                self._frames[fd] = self.writer.channel(f"/canguard/frames_out{'_fd' if fd else ''}", schema, "cdr")
            self.writer.messages(self._frames[fd], ns, table)
        self._out.clear()

    def close(self) -> None:
        """Write what is left and end the file."""
        try:
            self.signals.close()
            self._flush_guards()
            self._flush_frames()
        finally:
            self.writer.close()


FLEET_COLUMNS = {"log": "string", "status": "string", "reason": "string", "frames": "int64", "trips": "int64",
           "stops": "int64", "first_trip_t": "float64", "stopped_s": "float64", "worst_node": "string",
           "worst_signal": "string", "worst_margin_pct": "float64"}
"""The fleet summary's columns, in order, and their Arrow types."""


def fleet_row(log: str, summary: Mapping[str, Any] | None, error: str = "") -> dict[str, Any]:
    """One log's row: from its replay summary, or (``summary`` None) the reason it failed."""
    row: dict[str, Any] = dict.fromkeys(FLEET_COLUMNS)
    row["log"] = log
    if summary is None:
        row.update(status="failed", reason=error.strip().splitlines()[0] if error.strip() else "failed")
        return row
    trips = summary.get("trips") or []
    margins = [m for m in summary.get("margins") or [] if m.get("margin_pct") is not None]
    worst: Mapping[str, Any] = min(margins, key=lambda m: m["margin_pct"], default={})
    row.update(
        status="ok", reason="", frames=(summary.get("frames") or {}).get("read"),
        trips=int(summary.get("trip_count", len(trips))), stops=summary.get("stops"),
        first_trip_t=min((t["t"] for t in trips), default=None), stopped_s=summary.get("stopped_s"),
        worst_node=worst.get("node"), worst_signal=worst.get("signal"), worst_margin_pct=worst.get("margin_pct"),
    )
    return row


def write_fleet_summary(path: Path, rows: Iterable[Mapping[str, Any]]) -> None:
    """Write ``rows``: Parquet when ``path`` ends with ``.parquet`` (pyarrow), else JSON lines."""
    table = [{c: r.get(c) for c in FLEET_COLUMNS} for r in rows]
    if path.suffix.lower() == ".parquet":
        pa, pq = require_pyarrow(f"--fleet-summary {path}")
        pq.write_table(pa.Table.from_pylist(table, schema=schema(pa, FLEET_COLUMNS)), path)
        return
    with open(path, "w", encoding="utf-8") as out:
        out.writelines(json.dumps(r) + "\n" for r in table)
