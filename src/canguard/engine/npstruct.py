"""Byte-aligned signals of a numpy block decoded by numpy, reading only the bytes the configured signals sit in.

A message of the decoder's struct path (:func:`canguard.decode.decoder._compile_fast`:
byte-aligned signals of standard widths, one byte order) read from a
:class:`~canguard.io.candump_np.ByteColumns` block: each configured signal's bytes
are gathered from the hex text of all the message's rows at once and viewed as the
signal's type, then converted as the per-frame decoder converts them
(``raw * scale + offset``, then float) and checked as :func:`canguard.engine.blocks._struct_rows`
checks them. A 64-byte CAN FD frame of which one signal is configured costs the
4 hex digits of that signal, not 128.

Exactness: the raw values are integers of at most 32 bits or IEEE floats, and numpy's
float64 product and sum round as Python's do. Where Python computes in exact
integers (an integer scale and offset), numpy's float64 is exact too as long as every
product and sum stays below 2**53; :func:`struct_spec` admits only such signals.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from canguard.engine.colrows import ColumnRows, Row

if TYPE_CHECKING:
    import numpy as np

    from canguard.decode.decoder import _Entry
    from canguard.io.candump_np import ByteColumns

_DTYPES = {"b": "i1", "B": "u1", "h": "i2", "H": "u2", "i": "i4", "I": "u4", "l": "i4", "L": "u4",
           "f": "f4", "d": "f8"}
"""struct codes numpy reads the same (standard sizes); 64-bit integers are left to struct."""

MIN_ROWS = 48
"""Fewer rows of a message in a block go the struct way (numpy's calls cost more than they save)."""

_INT_EXACT = 2**20
"""An integer scale and offset below this keep 32-bit raws' products and sums below 2**53."""

Spec = tuple[tuple[int, int, str, Any, Any, bool, bool, float, float], ...]
"""Per configured signal: (byte offset, width, numpy dtype, scale, offset, identity, present, lo, hi)."""


def struct_spec(entry: _Entry, outputs: list[tuple[Any, ...]]) -> Spec | None:
    """How to read ``entry``'s configured signals from a numpy block, or None (the struct path then reads them)."""
    if not entry.fields or entry.plan is None or entry.lengths != {entry.length}:
        return None
    spec = []
    for (_s, _r, index, scale, offset, identity, present), (*_x, lo, hi, _m) in zip(entry.plan, outputs, strict=True):
        at, code, order = entry.fields[index]
        kind = _DTYPES.get(code)
        if kind is None:
            return None
        if not identity and not _exact(scale, offset, kind):
            return None
        width = struct.calcsize(order + code)
        spec.append((at, width, ("<" if order == "<" else ">") + kind, scale, offset, identity, present, lo, hi))
    return tuple(spec)


def _exact(scale: Any, offset: Any, kind: str) -> bool:
    """float64 arithmetic gives what Python's gives for ``raw * scale + offset``."""
    if kind[0] == "f" or (type(scale) is float and type(offset) is float):
        return True  # float arithmetic both ways, operation for operation
    return all(type(x) is float or (type(x) is int and abs(x) < _INT_EXACT) for x in (scale, offset))


def decode_struct(cols: ByteColumns, rows: list[int], size: int, spec: Spec) -> Sequence[Row]:
    """Each row's values (in output order) or None (a row to feed: another length, NaN, out of range, absent)."""
    import numpy as np

    good, cells = cols.byte_fields(rows, size, [(at, width) for at, width, *_ in spec])
    count = len(rows) if good is None else len(good)
    if not count:
        return [None] * len(rows)
    columns: list[np.ndarray] = []
    ok = np.ones(count, dtype=bool)
    with np.errstate(invalid="ignore", over="ignore"):
        for (_at, _width, dtype, scale, offset, identity, present, lo, hi), cell in zip(spec, cells, strict=True):
            v = cell.view(dtype)[:, 0].astype(np.float64)  # a copy: the cells are scratch reused by the next block
            if not identity:
                v = v * scale + offset
            if present:  # NaN, an infinity or 0: the row goes to feed; else the flag reads 1.0
                ok &= np.isfinite(v) & (v != 0.0)
                if not lo <= 1.0 <= hi:
                    ok[:] = False
                columns.append(np.ones(count))
                continue
            ok &= (lo <= v) & (v <= hi)  # NaN and +-inf fail it
            columns.append(v)
    found = ColumnRows(count, columns, ~ok, None)
    if good is None:
        return found
    result: list[Row] = [None] * len(rows)
    for k, row in zip(good, found.rows(), strict=True):
        result[k] = row
    return result
