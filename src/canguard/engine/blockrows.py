"""A column block's configured rows, decoded message by message (the replay hot path; issue 16).

:func:`decode_rows` is what :meth:`LogRun._run_columns <canguard.engine.logrun.LogRun._run_columns>`
asks of a block: each configured message's rows decoded together
(:meth:`MessagePlan.decode <canguard.engine.blocks.MessagePlan.decode>`), the rows of a
message nobody reads between ticks taken whole, or, when no configured row can change
what a tick sees, every row of the block (:mod:`canguard.engine.settle`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from operator import itemgetter
from typing import TYPE_CHECKING, Any

from canguard.engine.lanes import runs_by_key

if TYPE_CHECKING:
    from canguard.engine.blocks import MessagePlan
    from canguard.io.block import Block


def decode_rows(
    plans: Mapping[int, MessagePlan | None], rows: Any, block: Block, ts: Sequence[Any],
    settle: bool = False, keys: Any = None, taken: list[tuple[MessagePlan, Any, Sequence[Any]]] | None = None,
    horizon: Callable[[Mapping[int, Mapping[str, float]]], float] | None = None,
    touched: set[MessagePlan] | None = None,
) -> list[tuple[MessagePlan | None, tuple[float, ...] | None] | None] | None:
    """Per row of the block: its plan and decoded values when it goes one by one (else None); None: no row left.

    Each message's rows are decoded together (:meth:`MessagePlan.decode`); a message
    nobody reads between ticks may take its rows whole (:meth:`MessagePlan.batch`,
    before any row of the block: it stores its state as at the end of the block,
    which every tick in the block reads as it would have read the row-by-row state);
    rows without a configured signal are only counted; remote and error rows go to the frame decoder. When no
    configured row of the block can change what a tick sees, every message's rows are
    taken whole (:mod:`canguard.engine.settle`) and None is returned; only with ``settle``
    (the last tick was a fixed point: no tick in the block changes a guard's status by itself).
    ``ts``: the block's times; ``keys``: each row's key in ``plans`` (:attr:`Block.keys
    <canguard.io.block.Block.keys>`, plus a channel's lane). ``taken``, when given, receives each message's
    (plan, rows, decoded values) (``--export-signals``); ``touched``, when given, each plan that took rows.
    """
    from canguard.decode.rows import EMPTY, count_empty  # imported when a block is first decoded

    groups: dict[MessagePlan | None, Any] = {}  # each message's rows: an index array
    special = block.special
    if special.size:
        import numpy as np

        picked = np.asarray(rows, dtype=np.intp)
        odd = np.isin(picked, special)
        groups[None] = picked[odd]
        rows = picked[~odd]
    for key, same in runs_by_key(keys, rows):  # rows by id, each in time order
        plan = plans[key]
        group = groups.get(plan)
        groups[plan] = same if group is None else sorted([*group, *same])  # a second id without a plan
    slots: list[tuple[MessagePlan | None, tuple[float, ...] | None] | None] = [None] * block.n
    active: list[tuple[MessagePlan, Any, Sequence[tuple[float, ...] | None], Callable[[Any], Any]]] = []
    for plan, group in groups.items():
        if plan is None:
            for i in list(group):
                slots[i] = (None, None)
            continue
        if touched is not None:
            touched.add(plan)
        pick = _picker(group)
        decoded = plan.decode(block, group)
        if taken is not None:
            taken.append((plan, group, decoded))
        if plan.passive and plan.batch(pick(ts), decoded):
            continue
        active.append((plan, group, decoded, pick))
    if settle and active and None not in groups and _settled(active, ts, horizon):
        for plan, _group, decoded, _pick in active:
            plan.count_empty(count_empty(decoded))
        return None
    for plan, group, decoded, _pick in active:
        empty = 0
        for i, values in zip(group if type(group) is list else group.tolist(), decoded, strict=True):
            if values is EMPTY:
                empty += 1
            else:
                slots[i] = (plan, values)
        plan.count_empty(empty)
    return slots


def _settled(active: list[tuple[MessagePlan, Any, Sequence[Any], Callable[[Any], Any]]],
             ts: Sequence[Any], horizon: Callable[[Mapping[int, Mapping[str, float]]], float] | None) -> bool:
    """Every active message of the block taken whole (:mod:`canguard.engine.settle`), or none of them."""
    from canguard.engine.settle import prepare, settle

    prepared = []
    for plan, _group, decoded, pick in active:
        if not plan.settle_ok:
            return False
        ready = prepare(plan, pick(ts), decoded)
        if ready is None:
            return False
        prepared.append(ready)
    return settle(prepared, float(ts[-1]), horizon)


def _picker(rows: Any) -> Callable[[Any], Sequence[Any]]:
    """The items ``rows`` (a list, or an index array) of a sequence: ``itemgetter(*rows)``, but a tuple for one
    row too (itemgetter then gives the bare value), and ``take`` for a numpy array."""
    if len(rows) == 1:
        only = int(rows[0])
        return lambda seq: (seq[only],)
    if type(rows) is not list:
        return lambda seq: seq.take(rows) if hasattr(seq, "take") else itemgetter(*rows.tolist())(seq)
    getter = itemgetter(*rows)
    return lambda seq: seq.take(rows) if hasattr(seq, "take") else getter(seq)
