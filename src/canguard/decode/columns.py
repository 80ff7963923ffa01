"""Decode a whole column of payloads of one message at once (numpy), equal to cantools per frame.

The vectorised kernels of :class:`canguard.decode.message.MessageDecoder` (imported only
when a block is large enough to be worth numpy). Given the payloads of one message in a
block (an ``(n, length)`` uint8 array), every signal is extracted for all rows in a few
vectorised operations instead of one decode per frame. Covered: Intel and Motorola byte
order, signed and unsigned, IEEE float (32/64), scale and offset, any length up to 64
bits, classic and CAN FD lengths, simple and extended (nested) multiplexing. The
contract is equality with cantools: ``tests/test_columns_vs_cantools.py`` decodes random
messages of random DBCs both ways and requires identical values.

:func:`checked_rows` checks the configured signals' columns as
:func:`~canguard.decode.message.check_cell` checks one value (:func:`check_column`);
:func:`field_rows` does the same for byte-aligned signals read by numpy from only their
bytes of a numpy block's hex (a 64-byte CAN FD frame of which one signal is configured
costs the 4 hex digits of that signal, not 128). Exactness there: the raw values are
integers of at most 32 bits or IEEE floats, and numpy's float64 product and sum round as
Python's do; where Python computes in exact integers (an integer scale and offset), the
decoder admits the signal only when every product and sum stays below 2**53.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from canguard.decode.rows import ColumnRows, Row

__all__ = ["ColumnSignal", "check_column", "checked_rows", "decode_block", "decode_columns", "field_rows",
           "signal_raw"]

_EXACT = 2.0**53
"""Integers below this convert to float exactly in numpy as in Python."""
_FEW_IDS = 8
"""Up to this many multiplexer ids are matched by one comparison each (:func:`_member`)."""


@dataclass(frozen=True)
class ColumnSignal:
    """A decoded signal over the rows of a block."""

    values: np.ndarray
    """Physical values (float64; int64/uint64 when cantools would give whole numbers: scale 1, offset 0)."""
    valid: np.ndarray
    """Rows where the signal is present (always all rows unless it is multiplexed)."""


def _bytes_to_uint(payload: np.ndarray, first: int, count: int, big_endian: bool) -> list[np.ndarray]:
    """The bytes first..first+count-1 of every row as uint64 columns (most significant first if big-endian)."""
    cols = [payload[:, first + k].astype(np.uint64) for k in range(count)]
    return cols if big_endian else cols[::-1]


def signal_raw(payload: np.ndarray, start: int, length: int, big_endian: bool) -> np.ndarray:
    """The raw unsigned bits of one signal for every row (uint64), cantools' bit numbering."""
    if big_endian:
        # DBC's Motorola start bit is the MSB in "sawtooth" numbering: make it a linear index from byte 0's MSB.
        lin = (start // 8) * 8 + (7 - start % 8)
        first, last = lin // 8, (lin + length - 1) // 8
        drop = (last + 1) * 8 - (lin + length)  # bits below the signal's LSB in the last byte
    else:
        first, last = start // 8, (start + length - 1) // 8
        drop = start % 8
    cols = _bytes_to_uint(payload, first, last - first + 1, big_endian)  # most significant byte first
    # Assemble up to 9 bytes (a 64-bit signal not aligned to a byte) without overflowing uint64:
    # shift out the low `drop` bits byte by byte from the least significant end.
    raw = np.zeros(payload.shape[0], dtype=np.uint64)
    shift = 0
    for col in reversed(cols):  # least significant byte first
        pos = shift - drop
        if pos >= 64:
            break
        if pos >= 0:
            raw |= col << np.uint64(pos)
        else:
            raw |= col >> np.uint64(-pos)
        shift += 8
    if length < 64:
        raw &= np.uint64((1 << length) - 1)
    return raw


def _physical(sig: Any, raw: np.ndarray) -> np.ndarray:
    """cantools' decode of one signal from its raw bits: sign, IEEE float, then raw * scale + offset."""
    if sig.is_float:
        value = raw.astype(np.uint32).view(np.float32).astype(np.float64) if sig.length == 32 else raw.view(np.float64)
    elif sig.is_signed:
        value = raw.view(np.int64)
        if sig.length < 64:
            sign = np.int64(1) << np.int64(sig.length - 1)
            value = (value ^ sign) - sign  # two's complement of the low `length` bits
    else:
        value = raw
    scale, offset = sig.scale, sig.offset
    if scale == 1 and offset == 0:
        return value  # cantools' identity conversion: the raw number as it is (a float -0.0 stays -0.0)
    if not sig.is_float and isinstance(scale, int) and isinstance(offset, int):
        # cantools computes raw * scale + offset in Python integers: exact, whatever the size
        if sig.length + max(abs(scale), 1).bit_length() + 1 < 63 and abs(offset) < 2**61:
            return value.astype(np.int64) * np.int64(scale) + np.int64(offset)
        return value.astype(object) * scale + offset
    return value.astype(np.float64) * scale + offset


def decode_columns(message: Any, payload: np.ndarray) -> dict[str, ColumnSignal]:
    """Every signal of a cantools ``message`` for every row of ``payload`` (``(n, >= message.length)`` uint8).

    Multiplexed signals are valid only in the rows whose multiplexer (and its own
    multiplexer, for extended multiplexing) selects them; their values elsewhere are
    meaningless. A row whose multiplexer holds a value no signal is multiplexed on is
    invalid for every signal (cantools refuses the frame). Choices are not applied
    (as ``decode_choices=False``).
    """
    out, decodable = decode_block(message, payload)
    return {name: ColumnSignal(sig.values, sig.valid & decodable) for name, sig in out.items()}


def decode_block(
    message: Any, payload: np.ndarray, only: Collection[str] | None = None
) -> tuple[dict[str, ColumnSignal], np.ndarray]:
    """The signals ``only`` (default: all) of ``message`` for every row, and the rows cantools would decode.

    As :func:`decode_columns`, but a signal's ``valid`` says only whether its multiplexer
    selects it; the second value is False in the rows cantools refuses whole (a
    multiplexer value no signal is multiplexed on). Only the signals asked for, their
    multiplexers and the multiplexers of the message are extracted.
    """
    if payload.ndim != 2 or payload.dtype != np.uint8:
        raise ValueError(f"payload: expected a 2-D uint8 array, got {payload.dtype} with shape {payload.shape}")
    if payload.shape[1] < message.length:
        raise ValueError(f"payload: rows of {payload.shape[1]} bytes, {message.name} needs {message.length}")
    by_name = {sig.name: sig for sig in message.signals}
    raws: dict[str, np.ndarray] = {}

    def raw(sig: Any) -> np.ndarray:
        got = raws.get(sig.name)
        if got is None:
            got = raws[sig.name] = signal_raw(payload, sig.start, sig.length, sig.byte_order == "big_endian")
        return got

    all_rows = np.ones(payload.shape[0], dtype=bool)

    def valid(sig: Any) -> np.ndarray:
        if not sig.multiplexer_ids:
            return all_rows
        parent = by_name[sig.multiplexer_signal]
        return valid(parent) & _member(raw(parent), sig.multiplexer_ids)

    # cantools refuses a whole frame whose (selected) multiplexer holds a value no signal is multiplexed on
    undecodable = np.zeros(payload.shape[0], dtype=bool)
    for mux in (s for s in message.signals if s.is_multiplexer):
        ids = sorted({i for s in message.signals if s.multiplexer_signal == mux.name for i in s.multiplexer_ids or ()})
        if ids:
            undecodable |= valid(mux) & ~_member(raw(mux), ids)
    out: dict[str, ColumnSignal] = {}
    with np.errstate(invalid="ignore", over="ignore"):  # NaN payloads and huge scales: as cantools, no warning
        for sig in message.signals:
            if only is None or sig.name in only:
                out[sig.name] = ColumnSignal(_physical(sig, raw(sig)), valid(sig))
    return out, ~undecodable


def _member(raw: np.ndarray, ids: Sequence[int]) -> np.ndarray:
    """Which of the raw multiplexer values ``raw`` (uint64) are one of ``ids``: ``np.isin``, but one comparison per
    id for a few (a multiplexer's pages; ``np.isin``'s set-up cost more than its work on a block's rows)."""
    if len(ids) > _FEW_IDS:
        return np.isin(raw, np.asarray(ids, dtype=np.uint64))
    found = np.zeros(raw.shape, dtype=bool)
    for page in ids:
        found |= raw == np.uint64(page)
    return found


def check_column(v: np.ndarray, present: bool, lo: float, hi: float, ok: np.ndarray) -> np.ndarray:
    """:func:`~canguard.decode.message.check_cell` over a column: the values as rows carry them (float64); the
    rows where a value is unusable are cleared in ``ok``."""
    if present:
        ok &= np.isfinite(v) & (v != 0.0)
        v = np.where(v != 0.0, 1.0, 0.0)
    ok &= (lo <= v) & (v <= hi)  # NaN and +-inf fail it, as the scalar check's
    return v


def checked_rows(message: Any, payload: np.ndarray, names: Sequence[str], limits: Sequence[tuple[bool, float, float]],
                 multiplexed: bool) -> ColumnRows:
    """The checked rows of the signals ``names`` of ``message`` (each with its (present, lo, hi)) over ``payload``
    (``(n, length)`` uint8)."""
    rows = payload.shape[0]
    with np.errstate(invalid="ignore", over="ignore"):
        decoded, decodable = decode_block(message, payload, set(names))
        values: list[np.ndarray] = []
        ok = np.ones(rows, dtype=bool)
        present_any = np.zeros(rows, dtype=bool)
        present_all = np.ones(rows, dtype=bool)
        for name, (present, lo, hi) in zip(names, limits, strict=True):
            column = decoded[name]
            values.append(check_column(_as_float(column.values), present, lo, hi, ok))
            present_any |= column.valid
            present_all &= column.valid
        ok &= present_all & decodable
    # a multiplexed message's decodable row with none of our signals on its page: no sample at all (EMPTY)
    return ColumnRows(rows, values, ~ok, ~present_any & decodable if multiplexed else None)


def field_rows(cells: list[np.ndarray], n: int, spec: Sequence[tuple[int, int, str, Any, Any, bool]],
               limits: Sequence[tuple[bool, float, float]]) -> Sequence[Row]:
    """The checked rows of byte-aligned signals from their bytes: ``cells[j]``, the ``n x width`` bytes of output
    ``j`` (spec: byte offset, width, numpy dtype, scale, offset, identity)."""
    if not n:
        return []
    columns: list[np.ndarray] = []
    ok = np.ones(n, dtype=bool)
    with np.errstate(invalid="ignore", over="ignore"):
        for (_at, _width, dtype, scale, offset, identity), (present, lo, hi), cell in zip(
                spec, limits, cells, strict=True):
            v = cell.view(dtype)[:, 0].astype(np.float64)  # a copy: the cells are scratch reused by the next block
            if not identity:
                v = v * scale + offset
            columns.append(check_column(v, present, lo, hi, ok))
    return ColumnRows(n, columns, ~ok, None)


def _as_float(values: np.ndarray) -> np.ndarray:
    """Decoded values as float64, each equal to Python's ``float()`` of cantools' value."""
    if values.dtype == np.float64:
        return values
    if values.dtype.kind in "iu" and (values.size == 0 or float(np.max(np.abs(values.astype(np.float64)))) < _EXACT):
        return values.astype(np.float64)
    return np.array([float(x) for x in values.tolist()], dtype=np.float64)  # huge integers: Python's rounding
