"""A configured message on one bus, and the runs its rows feed (live and replay).

:func:`take_runs` is the one way a frame's samples change anything: each source's health and each
protection model advances over the run of its own samples, up to the first row where one of them changed
state (an edge: the engine ticks the tree there). A live frame is a run of one.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Sequence
from itertools import chain
from typing import TYPE_CHECKING, Any

from canguard.protect.staleness import ROW_ROLES

if TYPE_CHECKING:
    from canguard.bt.context import Context
    from canguard.decode.decoder import DecodeCounters
    from canguard.decode.message import MessageDecoder
    from canguard.engine.stats import EngineStats
    from canguard.io.frame import Sample
    from canguard.protect.staleness import SourceHealth


class MessagePlan:
    """One configured message on one bus: its column decode, and what its rows feed."""

    def __init__(self, entry: MessageDecoder, counters: DecodeCounters, ctx: Context, stats: EngineStats) -> None:
        self.entry = entry
        self.counters = counters
        self.stats = stats
        self.ctx = ctx
        self.names = [(out.source, out.role) for out in entry.outputs]  # in a decoded row's order
        self.outputs = [(role, ctx.health[source], tuple(ctx.subscribers(source, role)), ctx.journals(source, role))
                        for source, role in self.names]
        """(role, health, models, journalled: a CANopen drive's NMT / EMCY) of each configured signal."""
        self.keys = tuple((source, (source, role)) for source, role in self.names)  # where :meth:`flush` counts
        self.counter = any(role in ROW_ROLES for _source, role in self.names)
        """An alive counter or a drive's health role: every row goes to the frame decoder (its journal events)."""
        healths: dict[int, tuple[SourceHealth, list[str], list[int]]] = {}
        for j, (role, health, _models, _journalled) in enumerate(self.outputs):
            _health, roles, js = healths.setdefault(id(health), (health, [], []))
            roles.append(role)
            js.append(j)
        self.healths = tuple((health, tuple(roles), tuple(js)) for health, roles, js in healths.values())
        """Each source the message feeds: (its health, its roles here, their outputs), in output order."""
        self.single = len(self.outputs) == 1  # one configured signal (most messages)
        self.one_source = self.healths[0][:2] if self.single else None  # its (health, roles)
        self.models = tuple((j, model) for j, (_role, _health, models, _j) in enumerate(self.outputs)
                            for model in models)
        """(output, model) of every protection model a row feeds."""
        self.seen = 0
        self.empty = 0
        self.tops = [-1.0] * len(self.outputs)  # each output's largest valid |value| since :meth:`flush`
        self.sampled = [0] * len(self.outputs)  # each output's :meth:`take_samples` since :meth:`flush`
        self.index = {name: j for j, name in enumerate(self.names)}  # by (source, role)

    # -- one row ------------------------------------------------------------------------
    def take_row(self, values: tuple[float, ...], t: float) -> bool:
        """One row whole and valid at ``t`` (one value per output): a run of one for each health and model
        (:func:`take_runs` of one row); True on an edge."""
        self.seen += 1
        ts = (t,)
        tops = self.tops
        if self.single:  # one output (most messages): its value straight through
            v = values[0]
            health, roles = self.one_source  # type: ignore[misc]
            edge = health.advance(roles, ts, ((v,),)).changed
            for _j, model in self.models:
                if model.advance(ts, (v,)).changed:
                    edge = True
            a = -v if v < 0.0 else v
            if a > tops[0]:
                tops[0] = a
            return edge
        edge = False
        for health, roles, js in self.healths:
            if health.advance(roles, ts, [(values[j],) for j in js]).changed:
                edge = True
        for j, model in self.models:
            if model.advance(ts, (values[j],)).changed:
                edge = True
        for j, v in enumerate(values):
            a = -v if v < 0.0 else v
            if a > tops[j]:
                tops[j] = a
        return edge

    # -- frames the frame decoder read ------------------------------------------------
    def take_samples(self, samples: Sequence[Sample]) -> bool:
        """Take the samples the frame decoder made of one frame of this message (any reason, any subset of the
        outputs, in output order), each a run of one; True on an edge."""
        edge = False
        index, outputs, tops = self.index, self.outputs, self.tops
        for sample in samples:
            j = index[sample.source, sample.signal]
            role, health, models, journalled = outputs[j]
            reason, v, t = sample.reason, sample.value, sample.t
            if journalled:
                self.ctx.drive_event(sample, health)
            if health.advance((role,), (t,), ((v,),), ((reason,),)).changed:
                edge = True
            self.sampled[j] += 1
            if reason:
                continue
            for model in models:
                if model.advance((t,), (v,)).changed:
                    edge = True
            a = -v if v < 0.0 else v
            if a > tops[j]:
                tops[j] = a
        return edge

    def count_empty(self, rows: int) -> None:
        """``rows`` decoded rows that carried none of the configured signals (counted at :meth:`flush`)."""
        self.empty += rows

    def flush(self) -> None:
        """Add the rows and samples taken since the last flush to the decoder's and the engine's counters."""
        seen = self.seen
        rows = seen + self.empty
        if rows:
            counters = self.counters
            counters.frames += rows
            counters.decoded += rows
            self.stats.frames += rows
            self.seen = self.empty = 0
        elif not any(self.sampled):
            return  # nothing taken since the last flush (most plans, most blocks)
        sampled, tops = self.sampled, self.tops
        stats = self.stats
        max_abs, counts = stats.max_abs, stats.samples
        for j, (source, key) in enumerate(self.keys):
            n = seen + sampled[j]
            if n:
                counts[source] = counts.get(source, 0) + n
                top = tops[j]
                if top > max_abs.get(key, -1.0):
                    max_abs[key] = top
                tops[j] = -1.0
                sampled[j] = 0


_Unit = tuple[Any, Any, Any]
"""One health or model of :func:`take_runs`: (it, the rows it takes (ascending), what it advances over: a model's
(times, values); a health's (roles, times, columns, rows) sub-runs, one per message that feeds it)."""


def take_runs(runs: Sequence[tuple[MessagePlan, Any, Any, list[Any]]]) -> tuple[int, bool]:
    """Take the rows whole and valid of a stretch of a block (``runs``: (plan, rows ascending, their times, each
    output's column)) up to the first row with an edge: (the last row taken, True when it is an edge). Each health
    and model advances to its own first edge; one that went past the earliest goes back to its mark and up to it.
    A source fed by several messages takes their runs whole when each is quiet, else their rows in time order."""
    if len(runs) == 1 and len(runs[0][1]) == 1:  # one row (a live frame): a run of one for each
        plan, rows, ts, columns = runs[0]
        return int(rows[0]), plan.take_row(tuple(map(float, next(zip(*columns, strict=True)))), float(ts[0]))
    units: list[_Unit] = []
    health_units: dict[int, _Unit] = {}
    last = -1
    for plan, rows, ts, columns in runs:
        if rows[-1] > last:
            last = int(rows[-1])
        for health, roles, js in plan.healths:
            part = (roles, ts, [columns[j] for j in js], rows)
            unit = health_units.get(id(health))
            if unit is None:
                unit = health_units[id(health)] = (health, rows, [part])
                units.append(unit)
            else:
                unit[2].append(part)
        for j, model in plan.models:
            units.append((model, rows, (ts, columns[j])))
    for key, (health, _rows, parts) in health_units.items():
        if len(parts) > 1:  # several messages of one source: every row of theirs, in order
            at = next(i for i, unit in enumerate(units) if unit[0] is health)
            every = sorted(chain.from_iterable(_ints(part[3]) for part in parts))
            units[at] = health_units[key] = (health, every, parts)
    bound, edge = _advance_units(units, last)
    for plan, rows, _ts, columns in runs:
        m = len(rows) if bound == last else bisect_right(rows, bound)
        if not m:
            continue
        plan.seen += m
        tops = plan.tops
        for j, column in enumerate(columns):
            top = _top(column if m == len(rows) else column[:m])
            if top > tops[j]:
                tops[j] = top
    return int(bound), edge


def _top(column: Any) -> float:
    """The largest |value| of a column (valid values: finite), a list or a numpy column."""
    if type(column) is list or type(column) is tuple:
        return max(map(abs, column))
    return float(abs(column).max())


def _in_order(parts: list[tuple[Any, Any, list[Any], Any]]) -> list[tuple[Any, Any, list[Any], list[int]]]:
    """Sub-runs of one source from several messages, cut into stretches of one message each, in time order."""
    order = sorted((k, p, i) for p, part in enumerate(parts) for i, k in enumerate(_ints(part[3])))
    out = []
    start = 0
    while start < len(order):
        p = order[start][1]
        end = start
        while end < len(order) and order[end][1] == p:
            end += 1
        roles, ts, columns, _ks = parts[p]
        first, last = order[start][2], order[end - 1][2] + 1
        out.append((roles, ts[first:last], [c[first:last] for c in columns], [k for k, _p, _i in order[start:end]]))
        start = end
    return out


def _ints(rows: Any) -> list[int]:
    """Row positions (a list or a numpy column) as a list of ints."""
    return rows if type(rows) is list else rows.tolist()


def _advance_units(units: list[_Unit], last: int) -> tuple[int, bool]:
    """Advance every unit up to the first edge row of any (see :func:`take_runs`); (that row or ``last``, edge)."""
    bound, edge = last, False
    went: list[tuple[_Unit, Any, int]] = []
    final = len(units) - 1
    for u, unit in enumerate(units):
        obj, ks, _what = unit
        m = len(ks) if bound == last else bisect_right(ks, bound)
        if not m:
            continue
        mark = obj.mark() if u < final else None
        at = _advance(unit, m, True)
        if at is None:
            went.append((unit, mark, ks[m - 1]))
        else:
            went.append((unit, mark, at))
            bound, edge = at, True
    if edge:
        for unit, mark, upto in went:
            if upto > bound:  # past the first edge: back, and up to it
                unit[0].rewind(mark)
                m = bisect_right(unit[1], bound)
                if m:
                    _advance(unit, m, False)
    return bound, edge


def _advance(unit: _Unit, m: int, until_edge: bool) -> int | None:
    """Advance one unit over its first ``m`` rows; the row of its edge (with ``until_edge``: the first), or None."""
    obj, ks, what = unit
    if type(what) is tuple:  # a model: (times, values)
        ts, values = what
        if m < len(ks):
            ts, values = ts[:m], values[:m]
        run = obj.advance(ts, values, until_edge=until_edge)
        return ks[int(run.index[0])] if run.changed else None
    parts = what
    if len(parts) > 1:  # several messages of one source: whole when quiet, else their rows in time order
        if m < len(ks):
            upto = ks[m - 1]
            parts = [_upto(part, upto) for part in parts]
        if obj.take_quiet([part[:3] for part in parts if len(part[3])]):
            return None
        parts = _in_order(parts)
    left = m
    for roles, ts, columns, rows in parts:
        if left <= 0:
            break
        if left < len(rows):
            ts, columns, rows = ts[:left], [c[:left] for c in columns], rows[:left]
        left -= len(rows)
        ran = obj.advance(roles, ts, columns, until_edge=until_edge)
        if ran.changed:
            return rows[int(ran.index[0])]
    return None


def _upto(part: tuple[Any, Any, list[Any], Any], row: int) -> tuple[Any, Any, list[Any], Any]:
    """A message's sub-run up to row ``row`` (included)."""
    roles, ts, columns, rows = part
    k = bisect_right(rows, row)
    return roles, ts[:k], [c[:k] for c in columns], rows[:k]
