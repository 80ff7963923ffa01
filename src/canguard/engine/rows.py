"""Compiled handlers for the configured rows of a replayed candump block (the replay hot path).

:meth:`Engine.run_log <canguard.engine.core.Engine.run_log>` works on plain candump
blocks as text columns (:class:`~canguard.io.logs.Columns`). For the rows of a
configured message it calls the :class:`RowHandler` of that message: one
closure that does, for the common case, exactly what
:meth:`Engine.feed <canguard.engine.core.Engine.feed>` does after its tick check —
decode (struct), :meth:`SourceHealth.observe
<canguard.protect.staleness.SourceHealth.observe>`'s fast path, the subscribed
protection models, the per-source sample counts and largest values — with the
lookups done once, at compile time, and the counters kept in the closure and
added to the engine's at :meth:`RowHandler.flush`.

The common case is: the payload has the DBC length, every value is finite and
in the signal's DBC range, and every role of the message was fresh and valid at
its previous sample, which is not later than this one. Anything else (an
invalid frame, a source coming back after a stale spell, a presence signal, a
multiplexed message decoded by cantools) makes the handler return None
*before changing anything*, and the engine feeds that row as a frame through
the general path. Both paths leave the same state: tests replay the same logs
through both and compare every event and summary byte for byte.
"""

from __future__ import annotations

import math
import struct
import sys
from collections.abc import Callable, Collection, Sequence
from itertools import islice
from operator import itemgetter, sub
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from canguard.bt.context import Context
    from canguard.decode.decoder import DecodeCounters, _Entry
    from canguard.engine.stats import EngineStats

Handle = Callable[[str, float], "bool | None"]
"""(data hex text, t) -> True on an edge, False, or None: not handled, feed the row as a frame."""


class RowHandler:
    """The compiled path of one configured message on one bus: :attr:`handle`, then :meth:`flush`."""

    __slots__ = ("flush", "handle")

    def __init__(self, handle: Handle, flush: Callable[[], None]) -> None:
        self.handle = handle
        self.flush = flush


_BIG = 1.7976931348623157e308
"""The largest float: the default range bounds, so that +-inf fails the range check like NaN does."""


def _value_rule(entry: _Entry, index: int, scale: float, offset: float) -> str:
    """The decoder's value of raw value ``index``, as an expression of ``raw``, ``scale`` and ``offset``.

    :class:`~canguard.decode.decoder.Decoder` gives ``float(raw)`` for an identity signal
    (so -0.0 stays -0.0) and ``float(raw * scale + offset)`` otherwise; the
    ``float()`` is left out where the value is a float already.
    """
    if scale == 1 and offset == 0:
        return "raw" if entry.float_raws[index] else "float(raw)"
    if isinstance(scale, float) or isinstance(offset, float):
        return "raw * scale + offset"
    return "float(raw * scale + offset)"


def _converter(rule: str, scale: float, offset: float) -> Callable[[Any], float] | None:
    """``rule`` as a function of the raw value; None when the raw value is the value."""
    if rule == "raw":
        return None
    convert: Callable[[Any], float] = eval(f"lambda raw: {rule}", {"scale": scale, "offset": offset, "float": float})
    return convert


def compile_row(entry: _Entry, counters: DecodeCounters, ctx: Context, stats: EngineStats) -> RowHandler | None:
    """A :class:`RowHandler` for ``entry``'s frames, or None when its outputs need the general path."""
    if not entry.fast or entry.plan is None or entry.unpack is None:
        return None
    outputs = []
    for source, role, index, scale, offset, _identity, present in entry.plan:
        health = ctx.health.get(source)
        if health is None:
            return None
        lo, hi = health.ranges.get(role, (None, None))
        outputs.append((
            source, role, index, scale, offset, _value_rule(entry, index, scale, offset),
            -_BIG if lo is None else float(lo), _BIG if hi is None else float(hi),
            health, tuple(ctx.subscribers(source, role)), present,
        ))
    if len(outputs) == 1 and not outputs[0][-1]:
        return _single(entry, counters, stats, *outputs[0][:-1])
    return _many(entry, counters, stats, outputs)


def _count(counters: DecodeCounters, stats: EngineStats, rows: int) -> None:
    """Count ``rows`` decoded frames: the decoder's and the engine's counters."""
    counters.frames += rows
    counters.decoded += rows
    stats.frames += rows


def _count_samples(stats: EngineStats, health: Any, source: str, role: str, rows: int, top: float) -> None:
    """Count ``rows`` samples of one signal, with the largest |value| among them."""
    stats.samples[source] = stats.samples.get(source, 0) + rows
    health.samples += rows
    key = (source, role)
    if top > stats.max_abs.get(key, -1.0):
        stats.max_abs[key] = top


_SINGLE = """
def handle(text, t):
    global seen, high, low
    data = fromhex(text)
    if len(data) not in lengths:
        return None
    raw = unpack(data)[index]
    v = {value}
    if not lo <= v <= hi:  # NaN, +-inf and out of range all fail this
        return None
    latest = latest_t.get(role)
    if latest is None or t < latest or t - latest > max_age or invalid.get(role):
        return None
    latest_t[role] = t
    value[role] = v
    valid_t[role] = t
    seen += 1
    if v > high:
        high = v
    if v < low:
        low = v
    {models}
"""
"""The handler of a message with one configured signal, specialised by :func:`_single` (value, models)."""

_MODELS = {
    0: "return False",
    1: "return model.update(v, t)",
    2: "edge = False\n    for m in models:\n        if m.update(v, t):\n            edge = True\n    return edge",
}


def _single(
    entry: _Entry, counters: DecodeCounters, stats: EngineStats,
    source: str, role: str, index: int, scale: float, offset: float, rule: str,
    lo: float, hi: float, health: Any, models: tuple[Any, ...],
) -> RowHandler:
    """The handler of a message with one configured signal (most of them), compiled for its value and models.

    Its counters live in the namespace it runs in (``seen``, ``high``, ``low``): one
    dict per handler, read and reset by ``flush``.
    """
    env: dict[str, Any] = {
        "fromhex": bytes.fromhex, "unpack": entry.unpack, "lengths": entry.lengths, "index": index,
        "scale": scale, "offset": offset, "lo": lo, "hi": hi, "role": role, "max_age": health.max_age_s,
        "latest_t": health._latest_t, "invalid": health._invalid, "value": health._value,
        "valid_t": health._valid_t, "models": models, "model": models[0] if models else None,
        "float": float, "len": len, "seen": 0, "high": -_BIG, "low": _BIG,
    }
    exec(_SINGLE.format(value=rule, models=_MODELS[min(len(models), 2)]), env)

    def flush() -> None:
        if env["seen"]:
            _count(counters, stats, env["seen"])
            _count_samples(stats, health, source, role, env["seen"], max(abs(env["high"]), abs(env["low"])))
            env["seen"], env["high"], env["low"] = 0, -_BIG, _BIG

    return RowHandler(env["handle"], flush)


def _many(
    entry: _Entry, counters: DecodeCounters, stats: EngineStats, outputs: list[tuple[Any, ...]],
) -> RowHandler:
    """The handler of a message with several configured signals, or a presence signal.

    Every signal is checked before any is stored. A presence sample always takes
    :meth:`SourceHealth.observe`'s full path, which compares the source's reason
    before and after it; here it is handled only when that comparison cannot find
    an edge: the source was usable at this time (``_ok_since``) and said so last
    (``_last_reason``), and the flag reads 1.
    """
    fromhex = bytes.fromhex
    unpack = entry.unpack
    assert unpack is not None
    lengths = entry.lengths
    checks = tuple(
        (role, index, _converter(rule, scale, offset), lo, hi, health,
         health._latest_t, health._invalid, health.max_age_s, present)
        for _source, role, index, scale, offset, rule, lo, hi, health, _models, present in outputs
    )
    stores = tuple(
        (role, models, health._latest_t, health._value, health._valid_t)
        for _source, role, _i, _s, _o, _rule, _lo, _hi, health, models, _p in outputs
    )
    tops = [-1.0] * len(outputs)
    seen = 0

    def handle(text: str, t: float) -> bool | None:
        nonlocal seen
        data = fromhex(text)
        if len(data) not in lengths:
            return None
        raws = unpack(data)
        values = []
        for role, index, convert, lo, hi, health, latest_t, invalid, max_age, present in checks:
            raw = raws[index]
            v = raw if convert is None else convert(raw)
            if present:
                if not v or health._last_reason or not t - health._ok_since <= max_age:
                    return None
                v = 1.0
            if not lo <= v <= hi:
                return None
            latest = latest_t.get(role)
            if latest is None or t < latest or t - latest > max_age or invalid.get(role):
                return None
            values.append(v)
        seen += 1
        edge = False
        for j, (role, models, latest_t, value, valid_t) in enumerate(stores):
            v = values[j]
            latest_t[role] = t
            value[role] = v
            valid_t[role] = t
            a = -v if v < 0.0 else v
            if a > tops[j]:
                tops[j] = a
            for model in models:
                if model.update(v, t):
                    edge = True
        return edge

    def flush() -> None:
        nonlocal seen
        if not seen:
            return
        _count(counters, stats, seen)
        for j, (source, role, *_rest) in enumerate(outputs):
            _count_samples(stats, outputs[j][8], source, role, seen, tops[j])
            tops[j] = -1.0
        seen = 0

    return RowHandler(handle, flush)


Batch = Callable[[Sequence[str], Sequence[str]], bool]
"""(timestamp texts, data hex texts) of one message's rows in a block -> True: taken whole; False: go row by row."""


def _strided(entry: _Entry, indexes: list[int]) -> list[tuple[Any, int, int]] | None:
    """(memoryview format, first item, stride) of each raw value, when every one can be read off joined payloads.

    That is: a fixed-length message of the struct path whose fields are native,
    aligned little-endian numbers on a little-endian host. Else None.
    """
    if not entry.fields or entry.lengths != {entry.length} or sys.byteorder != "little":
        return None
    out = []
    for index in indexes:
        offset, code, order = entry.fields[index]
        width = struct.calcsize("<" + code)
        if order != "<" or struct.calcsize("@" + code) != width or offset % width or entry.length % width:
            return None
        out.append((code, offset // width, entry.length // width))
    return out


def compile_passive(
    entry: _Entry, counters: DecodeCounters, ctx: Context, stats: EngineStats, readers: Collection[str]
) -> Batch | None:
    """A whole-block path for a message nobody looks at between ticks, or None.

    Such a message feeds only sources no tree node reads (``readers``: the sources
    the tree reads and the stop confirmation's), no protection model, and no
    presence signal: what it changes is seen only through its sources' reasons at
    ticks (``stale`` / ``fresh`` events) and through counters. When every row of a
    block is valid, in the DBC range, and no two rows (nor the first row and the
    previous sample) lie more than ``max_age`` apart, every reason at every tick in
    the block is "" and the state at the end of the block is that of its last row:
    the batch stores that state at once (before the block's ticks, which then read
    "fresh" as they would have) and counts the rows in C-level passes. Anything
    else returns False having changed nothing, and the rows go one by one.
    """
    if not entry.fast or entry.plan is None or entry.unpack is None:
        return None
    outputs = []
    for source, role, index, scale, offset, _identity, present in entry.plan:
        health = ctx.health.get(source)
        if present or health is None or source in readers or ctx.subscribers(source, role):
            return None
        lo, hi = health.ranges.get(role, (None, None))
        convert = _converter(_value_rule(entry, index, scale, offset), scale, offset)
        outputs.append((source, role, index, convert, entry.float_raws[index],
                        -_BIG if lo is None else float(lo), _BIG if hi is None else float(hi), health))
    fromhex = bytes.fromhex
    unpack = entry.unpack
    lengths = entry.lengths
    isnan = math.isnan
    hex_size = 2 * entry.length
    columns = _strided(entry, [out[2] for out in outputs])
    picks = [itemgetter(out[2]) for out in outputs]

    min_age = min(out[-1].max_age_s for out in outputs)

    def batch(stamps: Sequence[str], texts: Sequence[str]) -> bool:
        raws: list[list[Any]]
        if columns is not None:  # the payloads joined, each field read off them in one strided pass
            if set(map(len, texts)) != {hex_size}:
                return False
            view = memoryview(fromhex("".join(texts)))
            raws = [view.cast(code)[start::step].tolist() for code, start, step in columns]
        else:
            payloads = list(map(fromhex, texts))
            if not set(map(len, payloads)) <= lengths:
                return False
            unpacked = list(map(unpack, payloads))
            raws = [list(map(pick, unpacked)) for pick in picks]
        first, last = float(stamps[0]), float(stamps[-1])
        # rows within max_age of each other from first to last: no gap can exceed it (float subtraction is
        # monotonic); else every gap is computed
        gap = last - first
        if gap > min_age:
            times = list(map(float, stamps))
            gap = max(map(sub, islice(times, 1, None), times), default=0.0)
        found = []
        for values, (source, role, _i, convert, floats, lo, hi, health) in zip(raws, outputs, strict=True):
            latest = health._latest_t.get(role)
            max_age = health.max_age_s
            if latest is None or first < latest or first - latest > max_age or gap > max_age:
                return False
            if health._invalid.get(role):
                return False
            if convert is not None:
                values = list(map(convert, values))
            low, high = min(values), max(values)
            if not (lo <= low and high <= hi) or (floats and any(map(isnan, values))):
                return False  # NaN, +-inf, out of range: the row-by-row path says which and when
            found.append((source, role, health, values[-1], max(abs(low), abs(high))))
        count = len(stamps)
        _count(counters, stats, count)
        for source, role, health, v, top in found:
            health._latest_t[role] = last
            health._value[role] = v
            health._valid_t[role] = last
            _count_samples(stats, health, source, role, count, top)
        return True

    return batch
