"""A column block's configured rows, decoded message by message (the replay hot path).

:func:`decode_rows` is what :meth:`LogRun._run_columns <canguard.engine.logrun.LogRun._run_columns>`
asks of a block: each configured message's rows decoded together
(each by its :class:`~canguard.decode.message.MessageDecoder`), each row then
taken in time order by the block runner.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from operator import itemgetter
from typing import TYPE_CHECKING, Any

from canguard.decode.rows import EMPTY, ColumnRows
from canguard.engine.lanes import runs_by_key

if TYPE_CHECKING:
    from canguard.engine.blocks import MessagePlan
    from canguard.io.block import Block


Run = tuple["MessagePlan", Any, Any, list[Any]]
"""A message's rows of a block whole and valid: (plan, the rows (ascending), their times, each output's column):
numpy columns from a block's column decode, lists from its rows one by one."""


def decode_rows(
    plans: Mapping[int, MessagePlan | None], rows: Any, block: Block, ts: Sequence[Any],
    keys: Any = None, taken: list[tuple[MessagePlan, Any, Sequence[Any]]] | None = None,
    touched: set[MessagePlan] | None = None,
) -> tuple[list[Run], list[tuple[int, MessagePlan | None]]]:
    """Each configured message's rows whole and valid, as columns (taken as runs by the block runner), and the
    rows the frame decoder takes, in row order (with their plan; None: a remote or error frame). Rows without a
    configured signal are only counted.

    Each message's rows are decoded together by its :class:`~canguard.decode.message.MessageDecoder` (a row it
    finds invalid, and every row of a message with an alive counter or a drive's health role, goes to the frame
    decoder). ``ts``: the block's time column; ``keys``: each row's key in ``plans`` (:attr:`Block.keys
    <canguard.io.block.Block.keys>`, plus a channel's lane). ``taken``, when given, receives each message's
    (plan, rows, decoded values) (``--export-signals``); ``touched``, when given, each plan that took rows.
    """
    special = block.special
    if len(rows) == 1 and not special.size:  # one row (a live frame): nothing to group
        groups: dict[MessagePlan | None, Any] = {plans[keys.item(rows[0])]: rows}
    else:
        groups = _groups(plans, rows, keys, special)
    whole: list[Run] = []
    fed: list[tuple[int, MessagePlan | None]] = []
    for plan, group in groups.items():
        if plan is None:
            fed.extend((int(i), None) for i in group)
            continue
        if touched is not None:
            touched.add(plan)
        if plan.counter:  # an alive counter or a drive's health role: every row to the frame decoder (its events)
            decoded: Sequence[Any] = [None] * len(group)
        elif len(group) == block.n:  # every row of the block (a live frame's)
            decoded = plan.entry.decode(block.payload, block.length)
        else:
            decoded = plan.entry.decode(block.payload_rows(group), block.length[group])
        if taken is not None:
            taken.append((plan, group, decoded))
        run = _split(plan, group, decoded, ts, block, fed)
        if run is not None:
            whole.append(run)
    if len(fed) > 1:
        fed.sort(key=itemgetter(0))
    return whole, fed


def _groups(plans: Mapping[int, MessagePlan | None], rows: Any, keys: Any,
            special: Any) -> dict[MessagePlan | None, Any]:
    """``rows`` by plan, each in row order (an index array, or a list of a few); the remote and error frames among
    them (``special``) under None."""
    groups: dict[MessagePlan | None, Any] = {}
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
    return groups


def _split(plan: MessagePlan, group: Any, decoded: Sequence[Any], ts: Any, block: Block,
           fed: list[tuple[int, MessagePlan | None]]) -> Run | None:
    """A message's decoded rows (``ts``: the block's time column): those whole and valid as a run of columns (None:
    none), those for the frame decoder added to ``fed``, the EMPTY ones counted."""
    if type(decoded) is ColumnRows:
        import numpy as np

        at = np.asarray(group, dtype=np.intp)
        if decoded.fed is not None:
            alone = decoded.fed if decoded.empty is None else decoded.fed & ~decoded.empty
            fed.extend((i, plan) for i in at[alone].tolist())
        plan.count_empty(decoded.count_empty())
        keep = None if decoded.clean() else decoded.valued()
        if keep is not None:
            at = at[keep]
        if not at.size:
            return None
        stamps = ts.take(at)
        columns = [c if keep is None else c[keep] for c in decoded.columns]
        return plan, at, stamps, columns  # numpy columns: the models screen long runs of them
    rows: list[int] = group if type(group) is list else group.tolist()
    values: Sequence[Any] = decoded
    if None in decoded or EMPTY in decoded:  # some rows are not whole and valid (most blocks: none)
        rows, values = [], []
        empty = 0
        for i, row in zip(group if type(group) is list else group.tolist(), decoded, strict=True):
            if row is EMPTY:
                empty += 1
            elif row is None:
                fed.append((i, plan))
            else:
                rows.append(i)
                values.append(row)
        if empty:
            plan.count_empty(empty)
        if not rows:
            return None
    if len(rows) == block.n:  # every row of the block (a live frame's): its times as floats, made with it
        return plan, rows, block.times, list(zip(*values, strict=True))
    stamps = []  # loops, not comprehensions: no function object per block (Python < 3.12)
    for i in rows:
        stamps.append(float(ts[i]))
    return plan, rows, stamps, list(zip(*values, strict=True))
