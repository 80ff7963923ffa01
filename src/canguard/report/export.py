"""``replay --export-signals FILE.parquet``: every decoded sample, as a table for pandas / polars.

:class:`SignalExport` sees every sample the models see (whole column blocks, through ``Engine.sample_block``)
and hands :data:`BATCH_ROWS` rows at a time (a Parquet row group) to its table:
memory stays flat. Each log writes its own part file, joined in input order by :func:`combine_parts`.
pyarrow (the ``fleet`` extra) is imported only when used.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from canguard.errors import ConfigError

if TYPE_CHECKING:
    from canguard.engine.core import Engine
    from canguard.io.frame import Sample

FLAG = "--export-signals"
COLUMNS = {"log": "string", "t": "float64", "bus": "string", "source": "string", "signal": "string",
           "value": "float64", "reason": "string"}
"""The exported columns, in order, and their Arrow types."""
BATCH_ROWS = 65_536
"""Rows buffered before they are written as one record batch (a Parquet row group)."""
OUT_OF_RANGE = "out_of_range"


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
    """``--export-signals FILE.mcap``: an MCAP file per log (:mod:`canguard.report.mcapexport`), not Parquet."""
    return path.suffix.lower() == ".mcap"


def part_path(path: Path, index: int) -> Path:
    """Where log number ``index`` of the run writes its rows before :func:`combine_parts`."""
    return path.with_name(f".{path.name}.part{index}")


class SignalExport:
    """Streams every sample an engine decodes into one Parquet file, in bounded memory."""

    def __init__(self, engine: Engine, path: Path, log: str, *, table: SampleTable | None = None) -> None:
        self.batch_rows = BATCH_ROWS
        bus = {name: src.bus for name, src in engine.cfg.sources.items()}
        self.table: SampleTable = table if table is not None else ParquetTable(path, log, bus)
        """Where each batch of rows goes: a Parquet file, or an MCAP export's channels."""
        # The DBC [min|max] the source's health checks: a value outside is rejected as out_of_range
        # by the models although the decoder passed it (the decoder does not check ranges).
        self._ranges = {name: health.ranges for name, health in engine.ctx.health.items()}
        self._chunks: list[tuple[Any, Any, Any]] = []
        """Columns of samples in order (time, code, value arrays), waiting for a batch to be full."""
        self._pending = 0
        self._codes: dict[tuple[str, str, str], int] = {}
        self._keys: list[tuple[str, str, str]] = []
        engine.sample_block = self._block

    def _reason_of(self, s: Sample) -> str:
        """The sample's reason, or ``out_of_range`` for a value the source's DBC range rejects."""
        reason, value = s.reason, s.value
        if not reason and not math.isnan(value):
            lo, hi = self._ranges.get(s.source, {}).get(s.signal, (None, None))
            if (lo is not None and value < lo) or (hi is not None and value > hi):
                return OUT_OF_RANGE
        return reason

    def _block(self, times: Sequence[Any], taken: list[tuple[list[tuple[str, str]], list[int], Sequence[Any]]],
               fed: list[tuple[int, Sample]]) -> None:
        """A replay's column block (``Engine.sample_block``): its samples in row order, as frame by frame.

        ``taken``: per configured message, its outputs' (source, signal), its rows and their decoded values;
        ``fed``: the samples of the rows fed, with their row (a row in both: its samples are the fed ones).
        The column checks pass only valid, in-range values: their reason is "".
        """
        import numpy as np

        from canguard.decode.rows import valued_table

        stamp = np.asarray(times, dtype=np.float64)
        fed_rows = np.array([row for row, _s in fed], dtype=np.intp)
        rows, stamps, values, codes = [], [], [], []
        for names, group, decoded in taken:
            idx = np.asarray(group, dtype=np.intp)
            keep, table = valued_table(decoded, len(names))
            if fed_rows.size:
                keep &= ~np.isin(idx, fed_rows)
            if not keep.any():
                continue
            width, taken_rows = len(names), idx[keep]
            rows.append(np.repeat(taken_rows, width))
            stamps.append(np.repeat(stamp[taken_rows], width))
            values.append(table[keep].ravel())  # row by row, each row's outputs in order
            codes.append(np.tile([self._code(name, "") for name in names], taken_rows.size))
        if fed:
            rows.append(fed_rows)
            stamps.append(np.array([s.t for _row, s in fed], dtype=np.float64))
            values.append(np.array([s.value for _row, s in fed], dtype=np.float64))
            codes.append(np.array([self._code((s.source, s.signal), self._reason_of(s)) for _row, s in fed]))
        if not rows:
            return
        order = np.argsort(np.concatenate(rows), kind="stable")
        self._chunks.append((np.concatenate(stamps)[order], np.concatenate(codes).astype(np.intp)[order],
                             np.concatenate(values).astype(np.float64)[order]))
        self._pending += order.size
        while self._pending >= self.batch_rows:  # the row groups of one sample at a time
            self._flush()

    def _code(self, name: tuple[str, str], reason: str) -> int:
        """A small number for (source, signal, reason), the same for the whole export."""
        key = (*name, reason)
        code = self._codes.get(key)
        if code is None:
            code = self._codes[key] = len(self._keys)
            self._keys.append(key)
        return code

    def _flush(self) -> None:
        """The first :attr:`batch_rows` samples waiting (all of them, when fewer) to the table."""
        import numpy as np

        if not self._chunks:
            return
        t, codes, values = (np.concatenate(cols) for cols in zip(*self._chunks, strict=True))
        n = min(t.size, self.batch_rows)
        self.table.write(t[:n], codes[:n], values[:n], self._keys)
        self._chunks = [(t[n:], codes[n:], values[n:])] if n < t.size else []
        self._pending = t.size - n

    def close(self) -> None:
        """Write what is buffered and close the table (a valid Parquet file even with no rows)."""
        while self._pending:
            self._flush()
        self.table.close()


class SampleTable(Protocol):
    """Where :class:`SignalExport` writes its rows, a batch at a time: columns of times, codes and values (float64,
    int, float64 arrays); ``keys[code]`` is the row's (source, signal, reason)."""

    def write(self, t: Any, codes: Any, values: Any, keys: Sequence[tuple[str, str, str]]) -> None: ...

    def close(self) -> None: ...


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
        import numpy as np

        source, signal, reason = (np.array([k[i] for k in keys], dtype=object)[codes] for i in range(3))
        bus = np.array([self.bus.get(k[0], "") for k in keys], dtype=object)[codes]
        columns = [[self.log] * len(t), t, bus, source, signal, values, reason]
        self._writer.write_batch(self.pa.RecordBatch.from_arrays(
            [self.pa.array(c, f.type) for c, f in zip(columns, self._schema, strict=True)], schema=self._schema))

    def close(self) -> None:
        """Close the file."""
        self._writer.close()


def discard_parts(parts: Sequence[Path | None]) -> None:
    """Remove the part files that exist (a run that did not finish leaves nothing behind)."""
    for p in parts:
        if p is not None and p.exists():
            p.unlink()


def combine_parts(path: Path, parts: Sequence[Path], ok: Sequence[bool]) -> int:
    """Put the parts of the logs that replayed (``ok``) into ``path``, in order; remove every part; the rows."""
    kept = [p for p, good in zip(parts, ok, strict=True) if good and p.exists()]
    pa, pq = require_pyarrow()
    try:
        if len(kept) == 1:
            rows = int(pq.ParquetFile(kept[0]).metadata.num_rows)
            os.replace(kept[0], path)
            return rows
        rows = 0
        with pq.ParquetWriter(path, schema(pa)) as writer:
            for part in kept:
                source = pq.ParquetFile(part)
                for i in range(source.num_row_groups):  # one row group at a time: memory stays flat
                    table = source.read_row_group(i)
                    writer.write_table(table)
                    rows += table.num_rows
        return rows
    finally:
        discard_parts(parts)

