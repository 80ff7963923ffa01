"""Which rows of a block the engine looks at, and on which bus: numpy over the block's id keys.

A :class:`~canguard.io.block.Block` carries its ids as integer keys
(:attr:`~canguard.io.block.Block.keys`) and, when it mixes channels, each row's channel
(``lanes``). The engine's plans are per bus; a block whose channels go to several buses is
looked up with one key per (channel, id): the id key plus the channel's index times :data:`LANE`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

_LANE_BITS = 34
LANE = 1 << _LANE_BITS
"""Above every id key (extended ids are below 2**33): one key space per channel of a block."""

_RADIX = 1 << 16
"""Keys of a block spanning fewer values than this are sorted as 16-bit offsets (:func:`runs_by_key`)."""

_STANDARD = 0x800
"""Standard ids are below this: their configured rows are found through a table of this size."""

_FEW = 16
"""A block of at most this many rows (a live bus's drained queue) is looked up row by row in Python: numpy's calls
cost more than the rows."""


def key_table(plans: Mapping[Any, Any]) -> tuple[Any, Any, frozenset[int]]:
    """The integer keys of ``plans`` (:attr:`Block.keys <canguard.io.block.Block.keys>`, plus a channel's
    :data:`LANE`s): a table of the standard ones, :data:`_STANDARD` entries per channel; all, sorted; all, as a set."""
    import numpy as np

    known = list(plans)
    table = np.zeros(_STANDARD * (1 + max((k // LANE for k in known), default=0)), dtype=bool)
    table[[k // LANE * _STANDARD + k % LANE for k in known if k % LANE < _STANDARD]] = True
    return table, np.array(sorted(known), dtype=np.int64), frozenset(known)


def configured_rows(keys: Any, tables: tuple[Any, Any, frozenset[int]]) -> Any:
    """The rows of a block whose id key has a plan, ascending: a list for a block of a few rows, else an index
    array."""
    table, every, known = tables
    if keys.size == 1:  # a live frame
        return [0] if keys.item(0) in known else []
    if keys.size <= _FEW:
        rows = []
        for i, key in enumerate(keys.tolist()):
            if key in known:
                rows.append(i)
        return rows
    import numpy as np

    if keys.size:
        top = int(keys.max())
        if top < _STANDARD:
            return np.flatnonzero(table[keys])
        if top < LANE * (table.size // _STANDARD):  # several channels: standard ids on each?
            ids = keys & (LANE - 1)
            if int(ids.max()) < _STANDARD:
                return np.flatnonzero(table[(keys >> _LANE_BITS) * _STANDARD + ids])
    return np.flatnonzero(np.isin(keys, every))


def runs_by_key(keys: Any, rows: Any) -> list[tuple[int, Any]]:
    """``rows`` of a block (a list of a few, or an index array) grouped by id key in key order, each group in row
    order (a list, or an index array: numpy's stable sort)."""
    if not len(rows):
        return []
    if type(rows) is list:  # a few rows (a live bus's block): grouped in Python
        of = keys.tolist()
        groups: dict[int, list[int]] = {}
        for i in rows:
            group = groups.get(of[i])
            if group is None:
                groups[of[i]] = [i]
            else:
                group.append(i)
        return sorted(groups.items()) if len(groups) > 1 else list(groups.items())
    import numpy as np

    picked = np.asarray(rows, dtype=np.intp)
    of = keys[picked]
    order = np.argsort(_radix_keys(of), kind="stable")
    ranked = of[order]
    cuts = (np.flatnonzero(ranked[1:] != ranked[:-1]) + 1).tolist()
    ordered = picked[order]
    bounds = [0, *cuts, len(ordered)]
    return list(zip(ranked[bounds[:-1]].tolist(), map(ordered.__getitem__, map(slice, bounds, bounds[1:])),
                    strict=True))


def _radix_keys(of: Any) -> Any:
    """Keys ordered as ``of`` (id keys, plus :data:`LANE`s), as 16-bit integers where they fit, which numpy sorts
    stably by radix (~3x faster than int64 keys): offsets from the lowest, or (channel, standard id) packed."""
    import numpy as np

    low = int(of.min())
    if int(of.max()) - low < _RADIX:
        return (of - low).astype(np.uint16)
    ids = of & (LANE - 1)
    if int(ids.max()) < _STANDARD and int(of.max()) < LANE * (_RADIX // _STANDARD):
        return ((of >> _LANE_BITS) * _STANDARD + ids).astype(np.uint16)
    return of


def lane_plans(plans_of: list[Mapping[int, Any]]) -> dict[int, Any]:
    """One plan table over the channels of a block: channel ``c``'s id key ``k`` is ``k + c * LANE``."""
    return {key + lane * LANE: plan for lane, plans in enumerate(plans_of) for key, plan in plans.items()}
