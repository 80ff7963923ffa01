"""A column block's configured rows, decoded message by message (the replay hot path; issue 16).

:func:`decode_rows` is what :meth:`LogRun._run_columns <canguard.engine.logrun.LogRun._run_columns>`
asks of a block: each configured message's rows decoded together
(:meth:`MessagePlan.decode <canguard.engine.blocks.MessagePlan.decode>`), each row then
taken in time order by the block runner.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from itertools import groupby
from typing import TYPE_CHECKING, Any

from canguard.decode.rows import ColumnRows
from canguard.engine.lanes import runs_by_key

if TYPE_CHECKING:
    from canguard.engine.blocks import MessagePlan
    from canguard.io.candump import Columns
    from canguard.io.candump_np import ByteColumns


def decode_rows(
    plans: Mapping[str | int, MessagePlan | None], rows: Any, cols: Columns | ByteColumns, ts: Sequence[Any],
    keys: Any = None, taken: list[tuple[MessagePlan, Any, Sequence[Any]]] | None = None,
) -> list[tuple[MessagePlan | None, tuple[float, ...] | None] | None]:
    """Per row of the block: its plan and decoded values (values None: the frame decoder takes it), or None
    (a row without a configured signal: only counted).

    Each message's rows are decoded together (:meth:`MessagePlan.decode`); remote rows go to the frame
    decoder. ``ts``: the block's times (a numpy block's array). ``taken``, when given, receives each
    message's (plan, rows, decoded values) (``--export-signals``).
    """
    from canguard.decode.rows import EMPTY  # imported when a block is first decoded

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
    active: list[tuple[MessagePlan, Any, Sequence[tuple[float, ...] | None]]] = []
    together = _decoded_together(cols, groups) if keys is not None else {}
    for plan, group in groups.items():
        if plan is None:
            for i in list(group):
                slots[i] = (None, None)
            continue
        decoded = together[plan] if plan in together else plan.decode(cols, group)
        if taken is not None:
            taken.append((plan, group, decoded))
        active.append((plan, group, decoded))
    for plan, group, decoded in active:
        empty = 0
        for i, values in zip(group if type(group) is list else group.tolist(), decoded, strict=True):
            if values is EMPTY:
                empty += 1
            else:
                slots[i] = (plan, values)
        plan.count_empty(empty)
    return slots


def _decoded_together(cols: Any, groups: dict[MessagePlan | None, Any]) -> dict[MessagePlan, Sequence[Any]]:
    """The decoded rows of the block's messages decoded together with others (a numpy block's): those read from
    their payloads cut together (:func:`_cut_payloads`), those read from their fields decoded as one
    (:func:`_shared_fields`)."""
    decoded = _shared_fields(cols, groups)
    for plan, payload in _cut_payloads(cols, groups).items():
        decoded[plan] = plan.decode(cols, groups[plan], payload)
    return decoded


def _cut_payloads(cols: Any, groups: dict[MessagePlan | None, Any]
                  ) -> dict[MessagePlan, tuple[list[int] | None, bytes]]:
    """The payloads of the block's messages that are decoded from them (:meth:`MessagePlan.cuts_payloads`), cut
    together per payload size when several are: one numpy pass instead of one slice-and-join each (on a log of
    many ids, ~20 messages of ~20 rows in a block)."""
    by_size: dict[int, list[tuple[MessagePlan, Any]]] = {}
    for plan, group in groups.items():
        if plan is not None and plan.cuts_payloads(group):
            by_size.setdefault(plan.hex_size, []).append((plan, group))
    cut: dict[MessagePlan, tuple[list[int] | None, bytes]] = {}
    for size, members in by_size.items():
        if len(members) > 1:
            for (plan, _group), payload in zip(members, cols.payloads([g for _p, g in members], size), strict=True):
                cut[plan] = payload
    return cut


def _shared_fields(cols: Any, groups: dict[MessagePlan | None, Any]) -> dict[MessagePlan, Sequence[Any]]:
    """The decoded rows of the block's messages that are read from their signals' bytes in the same way
    (:meth:`MessagePlan.fields_key`) as others: each such set decoded as one message over all their rows, then
    cut per message (four drives' messages of one layout: one decode, not four)."""
    alike: dict[tuple[Any, ...], list[tuple[MessagePlan, Any]]] = {}
    for plan, group in groups.items():
        if plan is not None and (key := plan.fields_key(group)) is not None:
            alike.setdefault(key, []).append((plan, group))
    decoded: dict[MessagePlan, Sequence[Any]] = {}
    for members in alike.values():
        if len(members) < 2:
            continue
        import numpy as np

        lead = members[0][0]
        assert lead.entry.spans is not None
        rows = np.concatenate([group for _plan, group in members])
        good, cells = cols.byte_fields(rows, lead.hex_size, lead.entry.spans)
        if good is not None:
            continue  # a row of another length among them: each message decoded on its own
        together = lead.entry.decode(cells, len(rows))
        assert isinstance(together, ColumnRows)
        for (plan, _group), part in zip(members, together.split([len(g) for _p, g in members]), strict=True):
            decoded[plan] = part
    return decoded
