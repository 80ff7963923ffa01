"""The engine's block runner: every block of frames, live or recorded, goes through it, one way.

A block's rows of configured messages are found by their id keys (plus channel × :data:`LANE` when its
channels go to several buses), decoded per message at once and taken in time order
(:mod:`canguard.engine.blocks`), the ticks due before a row first; other frames are only counted.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from itertools import pairwise
from operator import itemgetter
from typing import TYPE_CHECKING, Any, Protocol

from canguard.decode.decoder import DecodeCounters
from canguard.decode.rows import EMPTY, ColumnRows
from canguard.engine import blocks
from canguard.engine.blocks import MessagePlan
from canguard.io.block import EXT_KEY, Block
from canguard.io.frame import Frame, Sample
from canguard.protect.columns import SHORT_RUN

MAX_CATCH_UP_S = 2.0
"""Longest stretch of missed ticks the engine replays one by one after a gap (see :meth:`Engine.advance`)."""

_LANE_BITS = 34
LANE = 1 << _LANE_BITS
"""Above every id key (extended ids are below 2**33): one key space per channel of a block."""
_RADIX = 1 << 16
"""Keys of a block spanning fewer values than this are sorted as 16-bit offsets (:func:`_runs_by_key`)."""
_STANDARD = 0x800
"""Standard ids are below this: their configured rows are found through a table of this size."""
_FEW = 16
"""A block of at most this many rows (a live bus's drained queue) is looked up in Python: numpy costs more."""

if TYPE_CHECKING:
    from canguard.bt.context import Context
    from canguard.decode.decoder import Decoder
    from canguard.engine.stats import EngineStats

_Run = tuple["MessagePlan", Any, Any, list[Any]]
"""A message's rows of a block whole and valid: (plan, rows ascending, their times, each output's column)."""
_Keys = tuple[Any, Any, frozenset[int]]  # a plan table's keys (:func:`_key_table`)


class Engine(Protocol):
    """What :class:`LogRun` asks of the engine (:class:`canguard.engine.core.Engine` is one)."""

    decoder: Decoder
    stats: EngineStats
    ctx: Context
    sample_block: Callable[[Any, list[Any], list[tuple[int, Any]]], None] | None
    last_due_run: float
    due: float
    next_tick_t: float
    last_frame_t: float
    drive_clock: Callable[[float], None]

    def edge_tick(self, t: float) -> None: ...
    def runs_until(self, end_t: float, coming: Callable[[], Mapping[tuple[int, str], Any]]) -> float: ...
    def controller_state(self, bus: str, frame: Frame) -> None: ...
    def advance(self, now: float) -> None: ...
    def frame_time(self, t: float) -> None: ...


class LogRun:
    """Takes every block of frames through one engine (see the module docstring); keeps the message plans per bus."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self.decoder = engine.decoder
        self.stats = engine.stats
        self.ctx = engine.ctx
        # per bus (a tuple of one) or channels-to-buses of a block: plans by key (None: no source in the context)
        self._tables: dict[tuple[str, ...], tuple[dict[int, MessagePlan | None], _Keys]] = {}
        self._touched: set[MessagePlan] = set()  # the plans that took rows of this block (flushed at its end)
        self._row = 0  # the row the frame decoder takes (an export keeps its samples with it)
        self._fed: list[tuple[int, Sample]] | None = None  # while a block is exported: the decoder's samples

    def run(
        self, blocks: Iterable[Block], route: Mapping[str, str], default_bus: str | None,
        unmapped: dict[str, int], channels: dict[str, int] | None = None,
    ) -> None:
        """Take a log's blocks: each frame goes to the bus its channel maps to (``route``, else ``default_bus``);
        ``channels``, when given, counts the frames of each channel."""
        cursor = LogCursor(route, default_bus, unmapped, channels)
        engine = self.engine
        for block in blocks:
            self.take(block, cursor)
        last_t = cursor.last_t
        if last_t > -math.inf:
            engine.drive_clock(last_t)
            engine.frame_time(last_t)

    def take(self, block: Block, cursor: LogCursor) -> None:
        """One block of frames through the engine (one whose rows go back in time as its ordered stretches)."""
        try:
            if block.ordered:
                self._run_columns(block, cursor)
            else:
                import numpy as np

                cuts = [0, *(np.flatnonzero(block.time_s[1:] < block.time_s[:-1]) + 1).tolist(), block.n]
                for lo, hi in pairwise(cuts):
                    self._run_columns(block.select(slice(lo, hi)), cursor)
        finally:
            touched = self._touched
            while touched:
                touched.pop().flush()

    def _decoded(self, bus: str, frame: Frame, plan: MessagePlan | None) -> bool:
        """A row the column decoder left to the frame decoder (a wrong length, an invalid value, an alive counter,
        a remote or error frame); True on an edge."""
        engine = self.engine
        self.stats.frames += 1
        if frame.is_error_frame:
            engine.controller_state(bus, frame)
        samples = self.decoder.decode(frame, bus)
        if not samples:
            return False
        fed = self._fed
        if fed is not None:
            row = self._row
            fed.extend((row, sample) for sample in samples)
        assert plan is not None  # the decoder gives samples only of a configured message's data frame
        self._touched.add(plan)
        return plan.take_samples(samples)

    def _run_columns(self, block: Block, cursor: LogCursor) -> None:
        """A block whose rows are in order, as columns: each row to its channel's bus; the first row of a stream
        starts a replay's engine; rows before the latest time of the stream are counted as out of order."""
        if not block.n:
            return
        engine = self.engine
        export = engine.sample_block
        routed = self._route(block, None if block.only_channel is not None else block.channel, cursor)
        if routed is None:
            return
        block, buses = routed
        per_channel = None if block.only_channel is not None else block.channel  # each row's channel, or None
        times: Any = block.time_s
        ts: Any = block.times if block.n <= 16 else times  # a live bus's few rows: a list (read faster)
        t0 = float(ts[0])
        if not cursor.started:
            cursor.started = True
            # The stream's first frame: a replay's engine starts at it (the ticks due then run first), the clock
            # moves to it; then its row is taken as any other.
            engine.frame_time(t0)
            engine.advance(t0)
            engine.drive_clock(t0)
        plans, rows, keys, lanes = self._configured(block, buses, per_channel)
        special = block.special
        if special.size:  # counted by the decoder as remote or error frames, configured or not: fed
            import numpy as np

            rows = np.union1d(rows, special)
        if t0 < cursor.last_t:
            self._count_backward(ts, rows, cursor.last_t)
        picked = len(rows)
        last_row = int(rows[-1]) if picked else -1  # the last row fed or taken by a plan
        taken: list[tuple[MessagePlan, Any, Sequence[Any]]] | None = [] if export is not None else None
        runs, alone = _decode_rows(plans, rows, block, times, keys, taken, self._touched) if picked else ([], [])
        bus = buses[0] if lanes is None else ""
        if not picked:
            pos = 0  # nothing to take: the rows only bring the ticks due among them
        elif taken is None:
            pos = self._walk(block, ts, runs, alone, bus, buses, lanes)
        else:  # --export-signals, a plot: the samples of fed rows kept with their row, for the block's export
            assert export is not None
            fed: list[tuple[int, Sample]] = []
            self._fed = fed
            try:
                pos = self._walk(block, ts, runs, alone, bus, buses, lanes)
            finally:
                self._fed = None  # whatever the block raised
            export(ts, [(plan.names, group, decoded) for plan, group, decoded in taken], fed)
        if pos < block.n:
            self._cross(ts, pos, block.n)
        if per_channel is not None or cursor.channels is not None or picked != block.n:  # else nothing to count
            self._count_lanes(cursor, block, per_channel, buses, rows)
        t_end = float(ts[-1])
        if t_end > cursor.last_t:
            cursor.last_t = t_end
        if last_row >= 0:
            engine.frame_time(float(ts[last_row]))  # the last row fed or taken (not ts[-1])

    def _route(self, block: Block, lanes: Any, cursor: LogCursor) -> tuple[Block, list[str]] | None:
        """(The block's rows on a channel of a bus, the bus of each of its channels); rows of a channel of no bus are
        counted as unmapped (None: no row left). ``lanes``: each row's channel, None when all are on one."""
        route, default_bus, per_bus = cursor.route, cursor.default_bus, self.decoder.per_bus
        if lanes is None:
            channel = block.channels[block.only_channel]  # type: ignore[index]
            routed = route.get(channel, default_bus) if route else default_bus
            if routed is None:
                _count(cursor.unmapped, channel, block.n)
                if cursor.channels is not None:
                    _count(cursor.channels, channel, block.n)
                return None
            if routed not in per_bus:  # a bus the config does not name: its frames counted, none configured
                per_bus[routed] = DecodeCounters()
            return block, [routed]
        found = [route.get(name, default_bus) for name in block.channels]
        for routed in found:
            if routed is not None and routed not in per_bus:
                per_bus[routed] = DecodeCounters()
        if None not in found:
            return block, found  # type: ignore[return-value]
        import numpy as np

        counts = np.bincount(lanes, minlength=len(found)).tolist()
        for name, routed, n in zip(block.channels, found, counts, strict=True):
            if routed is None and n:
                _count(cursor.unmapped, name, n)
                if cursor.channels is not None:
                    _count(cursor.channels, name, n)
        mapped = np.array([routed is not None for routed in found])[lanes]
        if not mapped.any():
            return None
        if not mapped.all():
            block = block.select(mapped)
            return self._route(block, None if block.only_channel is not None else block.channel, cursor)
        somewhere = next(routed for routed in found if routed is not None)
        return block, [somewhere if routed is None else routed for routed in found]  # a channel of no row: any bus

    def _count_backward(self, ts: Sequence[Any], rows: Any, latest: float) -> None:
        """Count the rows of an ordered block out of order: one of ``rows`` (fed or taken by a plan) when before the
        latest frame time the engine took, any other when before ``latest`` (the latest time of its stream)."""
        before = bisect_left(ts, latest, key=float)
        behind = bisect_left(ts, self.engine.last_frame_t, key=float)
        picked = list(rows)
        self.stats.backward_frames += before - bisect_left(picked, before) + bisect_left(picked, behind)

    def _configured(self, block: Block, buses: list[str], lanes: Any) -> tuple[Any, Any, Any, Any]:
        """(plans, the block's configured rows, their lookup keys, each row's index into ``buses`` or None)."""
        keys = block.keys
        if len(buses) == 1 or buses.count(buses[0]) == len(buses):
            plans, table = self._table((buses[0],))
            return plans, _configured_rows(keys, table), keys, None
        plans, table = self._table(tuple(buses))
        keys = keys + lanes.astype(keys.dtype) * LANE  # channels of several buses: a key per (channel, id)
        return plans, _configured_rows(keys, table), keys, lanes

    def _walk(self, block: Block, ts: Sequence[Any], runs_in: list[_Run],
              alone: list[tuple[int, MessagePlan | None]], bus: str, buses: list[str], lanes: Any) -> int:
        """A block's configured rows in time order, the ticks due among them run; the row after the last walked.
        Stretches of ``runs_in`` up to the next due time go as runs (to the first edge), ``alone`` one by one.
        ``bus``: every row's, or "" when ``lanes`` (each row's index into ``buses``) sends them to several."""
        engine = self.engine
        pos, done = self._at_once(ts, runs_in, alone)
        if done:
            return pos
        runs = [[0, *run] for run in runs_in]  # each message's run and where it goes on: [next, plan, rows, ...]
        if pos:
            _drop(runs, pos - 1)
        next_alone, alones = 0, len(alone)
        end_rows = block.n
        end_t = float(ts[-1])
        while True:
            at_alone = alone[next_alone][0] if next_alone < alones else end_rows
            i = _first_row(runs, at_alone)
            if i == end_rows:
                break
            t = float(ts[i])
            if t >= engine.due:
                if pos < i:
                    self._cross(ts, pos, i)  # a tick falls due among the rows before this one, or at it
                if t >= engine.due:
                    engine.advance(t)
            if i == at_alone:  # for the frame decoder (its reason...)
                pos = i + 1
                self._row = i
                engine.drive_clock(t)
                if self._decoded(bus if lanes is None else buses[lanes[i]], block.frame(i), alone[next_alone][1]):
                    engine.edge_tick(t)
                next_alone += 1
                continue
            # the stretch before the engine must act (the next due time, or the end of its quiet ticks)
            until = engine.runs_until(end_t, lambda: _coming(runs))
            stop = end_rows if end_t < until else bisect_left(ts, until, i, end_rows, key=float)
            if at_alone < stop:
                stop = at_alone
            last, edge = blocks.take_runs(_stretch(runs, stop))
            _drop(runs, last)
            t_last = float(ts[last])
            if i < last:
                self._cross(ts, i, last)  # the quiet ticks the stretch spanned, each at its own time
            if t_last >= engine.due:
                engine.advance(t_last)
            pos = last + 1
            if edge:
                engine.edge_tick(t_last)
        return pos

    def _at_once(self, ts: Sequence[float], runs: list[_Run], alone: list[tuple[int, MessagePlan | None]]
                 ) -> tuple[int, bool]:
        """A block whose rows all come before the next due time, none for the frame decoder, as one stretch to
        the first edge: (the row after the last taken, True when all were); (0, False) for any other."""
        engine = self.engine
        if alone or not float(ts[-1]) < engine.due:
            return 0, False
        last, edge = blocks.take_runs(runs)
        if edge:
            engine.edge_tick(float(ts[last]))
        return last + 1, not edge

    def _count_lanes(self, cursor: LogCursor, block: Block, lanes: Any, buses: list[str], rows: Any) -> None:
        """Count a block's rows per channel (``cursor.channels``) and per bus those not in ``rows`` (skipped)."""
        channels = cursor.channels
        if lanes is None:
            tally: Iterable[tuple[int, int]] = [(block.n, len(rows))]
        else:
            import numpy as np

            size = len(block.channels)
            taken = np.bincount(lanes[rows], minlength=size).tolist() if len(rows) else [0] * size
            tally = zip(np.bincount(lanes, minlength=size).tolist(), taken, strict=True)
        for lane, (count, picked) in enumerate(tally):
            if channels is not None:
                _count(channels, block.channels[block.only_channel if lanes is None else lane], count)  # type: ignore[index]
            skipped = count - picked
            if skipped:
                counters = self.decoder.per_bus[buses[lane]]
                counters.frames += skipped
                counters.skipped += skipped
                self.stats.frames += skipped

    def _cross(self, ts: Sequence[Any], lo: int, hi: int) -> None:
        """Rows ``lo..hi-1`` (of no configured message): the first at or after each due time runs the ticks and gate
        deadlines due up to its time and moves the clock and the latest frame time to it."""
        engine = self.engine
        while lo < hi and float(ts[hi - 1]) >= engine.due:
            near = bisect_right(ts, engine.next_tick_t + MAX_CATCH_UP_S, lo, hi, key=float)
            if near > lo and float(ts[near - 1]) >= engine.due:
                # No gap the engine would skip up to MAX_CATCH_UP_S after the next tick: one advance runs every
                # due time these rows bring, each at its own time, as row by row would.
                engine.advance(float(ts[near - 1]))
                k = bisect_left(ts, engine.last_due_run, lo, near, key=float)
            else:
                k = bisect_left(ts, engine.due, lo, hi, key=float)
                engine.advance(float(ts[k]))
            t = float(ts[k])
            engine.drive_clock(t)
            engine.frame_time(t)
            lo = k + 1

    def _table(self, buses: tuple[str, ...]) -> tuple[dict[int, MessagePlan | None], _Keys]:
        """The plans of the messages on ``buses`` (channel ``c``'s key ``k`` at ``k + c * LANE``), and their keys."""
        known = self._tables.get(buses)
        if known is None:
            if len(buses) == 1:  # None: a message with a source not in the tree's context
                counters, health = self.decoder.per_bus[buses[0]], self.ctx.health
                plans = {cid + EXT_KEY if ext else cid: MessagePlan(entry, counters, self.ctx, self.stats)
                         if entry.outputs and all(out.source in health for out in entry.outputs) else None
                         for (bus, cid, ext), entry in self.decoder.entries() if bus == buses[0]}
            else:
                plans = {key + lane * LANE: plan for lane, bus in enumerate(buses)
                         for key, plan in self._table((bus,))[0].items()}
            known = self._tables[buses] = (plans, _key_table(plans))
        return known


def _first_row(runs: list[list[Any]], first: int) -> int:
    """The first row not taken yet of any message's run (``[next, plan, rows, ...]``), or an earlier ``first``."""
    for at, _plan, rows, _times, _columns in runs:
        if at < len(rows) and rows[at] < first:
            first = int(rows[at])
    return first


def _coming(runs: list[list[Any]]) -> dict[tuple[int, str], Any]:
    """The times of each source signal's rows not taken yet, by (``id`` of its health, role)."""
    out: dict[tuple[int, str], Any] = {}
    for at, plan, rows, times, _columns in runs:
        if at < len(rows):
            left = times[at:]
            for health, roles, _js in plan.healths:
                for role in roles:
                    out[id(health), role] = left
    return out


def _stretch(runs: list[list[Any]], stop: int) -> list[tuple[Any, Any, Any, list[Any]]]:
    """Each message's rows not taken yet before row ``stop``, as (plan, rows, times, columns): a short stretch's
    as lists (a few samples go faster over Python floats than numpy's calls), a long one's as numpy columns."""
    out = []
    for at, plan, rows, times, columns in runs:
        if at < len(rows) and rows[at] < stop:
            k = bisect_left(rows, stop, at) if type(rows) is list else int(rows.searchsorted(stop))
            if k - at <= SHORT_RUN and type(times) is not list:
                few = rows[at:k] if type(rows) is list else rows[at:k].tolist()
                out.append((plan, few, times[at:k].tolist(), [c[at:k].tolist() for c in columns]))
            elif at == 0 and k == len(rows):
                out.append((plan, rows, times, columns))
            else:
                out.append((plan, rows[at:k], times[at:k], [c[at:k] for c in columns]))
    return out


def _drop(runs: list[list[Any]], last: int) -> None:
    """Each message's rows up to row ``last`` were taken: its run goes on after them."""
    for run in runs:
        at, rows = run[0], run[2]
        if at < len(rows) and rows[at] <= last:
            if rows[-1] <= last:
                run[0] = len(rows)
                continue
            if type(rows) is not list:  # cut within: a list from now on (bisected at every stretch of the block)
                rows = run[2] = rows.tolist()
            run[0] = bisect_right(rows, last, at)


def _count(counts: dict[str, int], name: str, n: int) -> None:
    """Add ``n`` to ``counts[name]``."""
    counts[name] = counts.get(name, 0) + n


@dataclass
class LogCursor:
    """Where a stream of blocks is (a log, or a live bus): routing, counts, the latest time."""

    route: Mapping[str, str]
    default_bus: str | None
    unmapped: dict[str, int]
    channels: dict[str, int] | None
    last_t: float = -math.inf
    started: bool = False


def _key_table(plans: Mapping[int, Any]) -> _Keys:
    """The keys of ``plans``: a table of the standard ones per channel; all, sorted; all, as a set."""
    import numpy as np

    known = list(plans)
    table = np.zeros(_STANDARD * (1 + max((k // LANE for k in known), default=0)), dtype=bool)
    table[[k // LANE * _STANDARD + k % LANE for k in known if k % LANE < _STANDARD]] = True
    return table, np.array(sorted(known), dtype=np.int64), frozenset(known)


def _configured_rows(keys: Any, tables: _Keys) -> Any:
    """The rows of a block whose key has a plan, ascending: a list for a block of a few rows, else an index array."""
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


def _runs_by_key(keys: Any, rows: Any) -> list[tuple[int, Any]]:
    """``rows`` of a block (a list of a few, or an index array) grouped by key in key order, each group in row
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
    """Keys ordered as ``of``, as 16-bit integers where they fit, which numpy sorts stably by radix (~3x faster
    than int64 keys): offsets from the lowest, or (channel, standard id) packed."""
    import numpy as np

    low = int(of.min())
    if int(of.max()) - low < _RADIX:
        return (of - low).astype(np.uint16)
    ids = of & (LANE - 1)
    if int(ids.max()) < _STANDARD and int(of.max()) < LANE * (_RADIX // _STANDARD):
        return ((of >> _LANE_BITS) * _STANDARD + ids).astype(np.uint16)
    return of


def _decode_rows(
    plans: Mapping[int, MessagePlan | None], rows: Any, block: Block, ts: Sequence[Any], keys: Any,
    taken: list[tuple[MessagePlan, Any, Sequence[Any]]] | None, touched: set[MessagePlan],
) -> tuple[list[_Run], list[tuple[int, MessagePlan | None]]]:
    """Each configured message's rows whole and valid, as columns, and the rows for the frame decoder in row
    order with their plan (None: a remote or error frame). ``taken`` receives each (plan, rows, decoded values)."""
    special = block.special
    if len(rows) == 1 and not special.size:  # one row (a live frame): nothing to group
        groups: dict[MessagePlan | None, Any] = {plans[keys.item(rows[0])]: rows}
    else:
        groups = _groups(plans, rows, keys, special)
    whole: list[_Run] = []
    fed: list[tuple[int, MessagePlan | None]] = []
    for plan, group in groups.items():
        if plan is None:
            fed.extend((int(i), None) for i in group)
            continue
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
    """``rows`` by plan, each in row order; the remote and error frames among them (``special``) under None."""
    groups: dict[MessagePlan | None, Any] = {}
    if special.size:
        import numpy as np

        picked = np.asarray(rows, dtype=np.intp)
        odd = np.isin(picked, special)
        groups[None] = picked[odd]
        rows = picked[~odd]
    for key, same in _runs_by_key(keys, rows):
        plan = plans[key]
        group = groups.get(plan)
        groups[plan] = same if group is None else sorted([*group, *same])  # a second id without a plan
    return groups


def _split(plan: MessagePlan, group: Any, decoded: Sequence[Any], ts: Any, block: Block,
           fed: list[tuple[int, MessagePlan | None]]) -> _Run | None:
    """A message's decoded rows: those whole and valid as a run of columns (None: none), those for the frame
    decoder added to ``fed``, the EMPTY ones counted."""
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
