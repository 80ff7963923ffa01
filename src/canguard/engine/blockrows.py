"""A column block's configured rows, decoded message by message (the replay hot path; issue 16).

:func:`decode_rows` is what :meth:`LogRun._run_columns <canguard.engine.logrun.LogRun._run_columns>`
asks of a block: each configured message's rows decoded together
(:meth:`MessagePlan.decode <canguard.engine.blocks.MessagePlan.decode>`), the rows of a
message nobody reads between ticks taken whole, or, when no configured row can change
what a tick sees, every row of the block (:mod:`canguard.engine.settle`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from itertools import groupby
from operator import itemgetter
from typing import TYPE_CHECKING, Any

from canguard.engine.lanes import runs_by_key

if TYPE_CHECKING:
    from canguard.engine.blocks import MessagePlan
    from canguard.io.candump import Columns
    from canguard.io.candump_np import ByteColumns


def decode_rows(
    plans: Mapping[str | int, MessagePlan | None], rows: Any, cols: Columns | ByteColumns, ts: Sequence[Any],
    settle: bool = False, keys: Any = None, taken: list[tuple[MessagePlan, Any, Sequence[Any]]] | None = None,
    horizon: Callable[[Mapping[int, Mapping[str, float]]], float] | None = None,
) -> list[tuple[MessagePlan | None, tuple[float, ...] | None] | None] | None:
    """Per row of the block: its plan and decoded values when it goes one by one (else None); None: no row left.

    Each message's rows are decoded together (:meth:`MessagePlan.decode`); a message
    nobody reads between ticks may take its rows whole (:meth:`MessagePlan.batch`,
    before any row of the block: it stores its state as at the end of the block,
    which every tick in the block reads as it would have read the row-by-row state);
    rows without a configured signal are only counted; remote rows go to the frame decoder. When no
    configured row of the block can change what a tick sees, every message's rows are
    taken whole (:mod:`canguard.engine.settle`) and None is returned; only with ``settle``
    (the last tick was a fixed point: no tick in the block changes a guard's status by itself).
    ``ts``: the block's times (a numpy block's array). ``taken``, when given, receives each message's
    (plan, rows, decoded values) (``--export-signals``).
    """
    from canguard.decode.rows import EMPTY, count_empty  # imported when a block is first decoded

    groups: dict[MessagePlan | None, Any] = {}  # each message's rows: a list, or a numpy block's index array
    remote = cols.remote
    if remote:
        groups[None] = [i for i in rows if i in remote]
        rows = [i for i in rows if i not in remote]
    # rows by id (a stable sort keeps each id's rows in time order), in C but for one step per id
    if keys is not None:
        runs: Any = runs_by_key(keys, rows)
    else:
        ids: Sequence[Any] = cols.ids
        runs = groupby(sorted(rows, key=ids.__getitem__), key=ids.__getitem__)
    for text, same in runs:
        plan = plans[text]
        group = groups.get(plan)
        if group is None:
            groups[plan] = same if keys is not None else list(same)
        else:  # another letter case of the same id, another channel's rows of one bus, a second message without a plan
            groups[plan] = sorted([*group, *same])
    slots: list[tuple[MessagePlan | None, tuple[float, ...] | None] | None] = [None] * cols.n
    active: list[tuple[MessagePlan, Any, Sequence[tuple[float, ...] | None], Callable[[Any], Any]]] = []
    together = _decoded_together(cols, groups) if keys is not None else {}
    for plan, group in groups.items():
        if plan is None:
            for i in list(group):
                slots[i] = (None, None)
            continue
        pick = _picker(group)
        decoded = together[plan] if plan in together else plan.decode(cols, group)
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


def _decoded_together(cols: Any, groups: dict[MessagePlan | None, Any]) -> dict[MessagePlan, Sequence[Any]]:
    """The decoded rows of the block's messages whose payloads are cut together (:func:`_cut_payloads`)."""
    return {plan: plan.decode(cols, groups[plan], payload) for plan, payload in _cut_payloads(cols, groups).items()}


def _cut_payloads(cols: Any, groups: dict[MessagePlan | None, Any]
                  ) -> dict[MessagePlan, tuple[list[int] | None, bytes]]:
    """The payloads of the block's messages, cut together per payload size when several are: one numpy pass
    instead of one slice-and-join each (on a log of many ids, ~20 messages of ~20 rows in a block)."""
    by_size: dict[int, list[tuple[MessagePlan, Any]]] = {}
    for plan, group in groups.items():
        if plan is not None and not plan.counter:
            by_size.setdefault(plan.hex_size, []).append((plan, group))
    cut: dict[MessagePlan, tuple[list[int] | None, bytes]] = {}
    for size, members in by_size.items():
        if len(members) > 1:
            for (plan, _group), payload in zip(members, cols.payloads([g for _p, g in members], size), strict=True):
                cut[plan] = payload
    return cut


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
