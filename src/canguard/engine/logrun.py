"""The engine's block runner: every block of frames, live or recorded, goes through it, one way.

:class:`LogRun` is what :meth:`Engine.take <canguard.engine.core.Engine.take>` (the live
daemon's blocks; a frame on a quiet bus is a block of one) and :meth:`Engine.run_log
<canguard.engine.core.Engine.run_log>` (a recorded log's blocks, each channel routed to a
bus) call. A block (:class:`~canguard.io.block.Block`) is taken as columns: its configured
rows decoded per message at once, the frames of no configured message counted without
decoding while nothing is due; every configured row takes its message's row step
(:mod:`canguard.engine.blocks`), with the ticks and gate deadlines due before it run
first and a tick at once after an edge. A block whose rows go back in time is taken as its
ordered stretches, one after another. It talks to the engine through its public interface only.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import TYPE_CHECKING, Any, Protocol

from canguard.decode.decoder import DecodeCounters
from canguard.engine import blocks
from canguard.engine.blockrows import Run, decode_rows
from canguard.engine.lanes import LANE, configured_rows, key_table, lane_plans
from canguard.io.block import EXT_KEY, Block
from canguard.io.frame import Frame, Sample
from canguard.protect.columns import SHORT_RUN

MAX_CATCH_UP_S = 2.0
"""Longest stretch of missed ticks the engine replays one by one after a gap (see :meth:`Engine.advance`)."""

if TYPE_CHECKING:
    from canguard.bt.context import Context
    from canguard.decode.decoder import Decoder
    from canguard.engine.blocks import MessagePlan
    from canguard.engine.stats import EngineStats


class Engine(Protocol):
    """What :class:`LogRun` asks of the engine (:class:`canguard.engine.core.Engine` is one)."""

    decoder: Decoder
    stats: EngineStats
    ctx: Context
    sample_block: Callable[[Any, list[Any], list[tuple[int, Any]]], None] | None
    last_due_run: float

    due: float
    @property
    def next_tick_t(self) -> float: ...
    @property
    def last_frame_t(self) -> float: ...
    def edge_tick(self, t: float) -> None: ...
    def runs_until(self, end_t: float, coming: Callable[[], Mapping[tuple[int, str], Any]]) -> float: ...
    def controller_state(self, bus: str, frame: Frame) -> None: ...
    def advance(self, now: float) -> None: ...
    def drive_clock(self, t: float) -> None: ...
    def frame_time(self, t: float) -> None: ...


class LogRun:
    """Feeds a recorded log to one engine (see the module docstring); it keeps its message plans per bus."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self.decoder = engine.decoder
        self.stats = engine.stats
        self.ctx = engine.ctx
        self._plans: dict[str, dict[int, MessagePlan | None]] = {}
        """Per bus: id key -> the message's plan (see :mod:`canguard.engine.blocks`)."""
        self._plan_tables: dict[str, tuple[dict[int, MessagePlan | None], tuple[Any, Any, frozenset[int]]]] = {}
        """Per bus: its plans and their keys, as blocks look them up (:func:`.lanes.key_table`)."""
        self._lane_plans: dict[tuple[str, ...], tuple[dict[int, MessagePlan | None],
                                                      tuple[Any, Any, frozenset[int]]]] = {}
        """Per channels-to-buses of a block that mixes buses: its plans and their key table (:mod:`.lanes`)."""
        self._touched: set[MessagePlan] = set()
        """The plans that took rows of this block (flushed at its end)."""
        self._row = 0
        """The row the frame decoder takes (an export keeps its samples with it)."""
        self._fed: list[tuple[int, Sample]] | None = None
        """While a block is exported: the frame decoder's samples, with their row."""

    def run(
        self, blocks: Iterable[Block], route: Mapping[str, str], default_bus: str | None,
        unmapped: dict[str, int], channels: dict[str, int] | None = None,
    ) -> None:
        """Feed a recorded log's blocks: each frame goes to the bus its channel maps to (``route``, else
        ``default_bus``); ``channels``, when given, counts the frames of each channel.

        Frames of no configured message (most of a busy bus) are counted as the decoder would
        count them and never decoded. Nothing else changes: ticks and gate deadlines still run
        at their own times, brought up by the first frame at or after them (a bisection over
        the block's times), exactly as if every frame had been fed; the first frame is always
        fed (it starts the engine's clock).
        """
        cursor = LogCursor(route, default_bus, unmapped, channels)
        engine = self.engine
        for block in blocks:
            self.take(block, cursor)
        last_t = cursor.last_t
        if last_t > -math.inf:
            engine.drive_clock(last_t)
            engine.frame_time(last_t)

    def take(self, block: Block, cursor: LogCursor) -> None:
        """One block of frames through the engine, whatever its source: a live bus's queue drained (a frame on a
        quiet bus: a block of one), a log's block.

        Its rows are taken as columns (:meth:`_run_columns`); a block whose rows go back in time, as its
        ordered stretches one after another. Each configured row takes its message's row step
        (:func:`~canguard.engine.blocks.take_runs` / :meth:`~canguard.engine.blocks.MessagePlan.take_samples`),
        and the counts are added at the end.
        """
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
        """A row the column decoder left to the frame decoder (a wrong length, an invalid value with its reason,
        an alive counter or a drive's health roles, a remote or error frame): :meth:`Decoder.decode` counts its
        every reason, its samples go to its plan's row step (:meth:`MessagePlan.take_samples
        <canguard.engine.blocks.MessagePlan.take_samples>`); True on an edge."""
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
        """:meth:`run` over a block whose rows are in order, as columns.

        A block may mix channels: each row then goes to its channel's bus, with the plans of that
        bus (one key per channel and id when the buses differ). The first row of a stream starts a replay's
        engine; rows before the latest time of the stream are counted as out of order.
        """
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
        runs, alone = decode_rows(plans, rows, block, times, keys, taken, self._touched) if picked else ([], [])
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
        """(The block's rows on a channel that maps to a bus, the bus of each of its channels) (``lanes``: each
        row's channel, None when all rows are on one); rows of a channel of no bus are counted as unmapped (None:
        no row left)."""
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
        """Rows of an ordered block that start before ``latest``, the latest time of its stream: out of order.
        A row fed or taken by a plan (``rows``) counts when it is before the latest frame time the engine
        took; any other when it is before ``latest``."""
        before = bisect_left(ts, latest, key=float)
        behind = bisect_left(ts, self.engine.last_frame_t, key=float)
        picked = list(rows)
        self.stats.backward_frames += before - bisect_left(picked, before) + bisect_left(picked, behind)

    def _configured(self, block: Block, buses: list[str], lanes: Any) -> tuple[Any, Any, Any, Any]:
        """(plans, the block's rows of configured messages, the keys its plans are looked up by, each row's
        channel (an index into ``buses``) when its channels go to several buses, else None)."""
        keys = block.keys
        bus = buses[0]
        if len(buses) == 1 or buses.count(bus) == len(buses):  # one bus
            known = self._plan_tables.get(bus)
            if known is None:
                plans = self._plans_of(bus)
                known = self._plan_tables[bus] = (plans, key_table(plans))
            return known[0], configured_rows(keys, known[1]), keys, None
        assert lanes is not None  # channels of several buses: a key per (channel, id)
        lane = self._lane_plans.get(tuple(buses))
        if lane is None:
            joined = lane_plans([self._plans_of(b) for b in buses])
            lane = self._lane_plans[tuple(buses)] = (joined, key_table(joined))
        keys = keys + lanes.astype(keys.dtype) * LANE
        return lane[0], configured_rows(keys, lane[1]), keys, lanes

    def _walk(self, block: Block, ts: Sequence[Any], runs_in: list[Run], alone: list[tuple[int, MessagePlan | None]],
              bus: str, buses: list[str], lanes: Any) -> int:
        """A block's configured rows in time order: the ticks due among them, each stretch of rows whole and valid
        up to the next due time taken as runs (:func:`~canguard.engine.blocks.take_runs`: to the first edge, where
        the tree ticks), the rows for the frame decoder one by one (:attr:`_row`: the row it takes); the row after
        the last row walked. ``runs_in``: each configured message's
        rows whole and valid (:func:`.blockrows.decode_rows`); ``alone``: the rows the frame decoder takes, in order,
        with their plan; ``bus``: the bus of every row, or "" when ``lanes`` (each row's channel, an index into
        ``buses``, the bus of each of the block's channels) sends them to several."""
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

    def _at_once(self, ts: Sequence[float], runs: list[Run], alone: list[tuple[int, MessagePlan | None]]
                 ) -> tuple[int, bool]:
        """A block whose rows come before the next due time, none for the frame decoder: its runs taken as one
        stretch, up to the first edge (the tree ticks there). (The row after the last taken, True when every
        row was taken); (0, False) for any other block."""
        engine = self.engine
        if alone or not float(ts[-1]) < engine.due:
            return 0, False
        last, edge = blocks.take_runs(runs)
        if edge:
            engine.edge_tick(float(ts[last]))
        return last + 1, not edge

    def _count_lanes(self, cursor: LogCursor, block: Block, lanes: Any, buses: list[str], rows: Any) -> None:
        """Count a block's rows per channel (``cursor.channels``) and its skipped rows (neither fed nor taken
        by a plan: not in ``rows``) per bus, as the decoder counts them."""
        channels = cursor.channels
        for lane, (count, taken) in enumerate(_lane_tally(block, lanes, rows)):
            if channels is not None:
                _count(channels, block.channels[block.only_channel if lanes is None else lane], count)  # type: ignore[index]
            skipped = count - taken
            if skipped:
                counters = self.decoder.per_bus[buses[lane]]
                counters.frames += skipped
                counters.skipped += skipped
                self.stats.frames += skipped

    def _cross(self, ts: Sequence[Any], lo: int, hi: int) -> None:
        """Rows ``lo..hi-1`` (ordered, of no configured message): the first at or after the due time brings the ticks.

        The row that brings them runs the ticks and gate deadlines due up to its time, moves the clock
        and the latest frame time to it; repeated while another due time falls among the rows left.
        """
        engine = self.engine
        while lo < hi and float(ts[hi - 1]) >= engine.due:
            near = bisect_right(ts, engine.next_tick_t + MAX_CATCH_UP_S, lo, hi, key=float)
            if near > lo and float(ts[near - 1]) >= engine.due:
                # The rows up to MAX_CATCH_UP_S after the next tick hold no gap the engine would skip: one
                # advance runs every due time they bring, each at its own time, as row by row would (the
                # rows change nothing else); the clock and the last frame time end at the row that brought
                # the last of them.
                engine.advance(float(ts[near - 1]))
                k = bisect_left(ts, engine.last_due_run, lo, near, key=float)
            else:
                k = bisect_left(ts, engine.due, lo, hi, key=float)
                engine.advance(float(ts[k]))
            t = float(ts[k])
            engine.drive_clock(t)
            engine.frame_time(t)
            lo = k + 1

    def _plans_of(self, bus: str) -> dict[int, MessagePlan | None]:
        """Every message configured on ``bus`` by its id key (:attr:`Block.keys <canguard.io.block.Block.keys>`),
        with its plan, or None (made at the bus's first block)."""
        made = self._plans.get(bus)
        if made is not None:
            return made
        counters = self.decoder.per_bus[bus]
        plans: dict[int, MessagePlan | None] = {}
        for (b, cid, ext), entry in self.decoder.entries():
            if b != bus:
                continue
            plan = blocks.compile_plan(entry, counters, self.ctx, self.stats)
            plans[cid + EXT_KEY if ext else cid] = plan
        self._plans[bus] = plans
        return plans


def _first_row(runs: list[list[Any]], first: int) -> int:
    """The first row not taken yet of any message's run (``[next, plan, rows, times, columns]``), or ``first``
    when it comes before them."""
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
    times and columns as lists (the models' and healths' runs of a few samples go sample by sample, faster over
    Python floats than numpy's calls), a long one's as they are (numpy columns: screened with numpy)."""
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


def _lane_tally(block: Block, lanes: Any, rows: Any) -> list[tuple[int, int]]:
    """Per channel of a block (one when ``lanes`` is None): its rows, and those fed or taken by a plan (``rows``)."""
    if lanes is None:
        return [(block.n, len(rows))]
    import numpy as np

    size = len(block.channels)
    per_lane = np.bincount(lanes, minlength=size).tolist()
    taken = np.bincount(lanes[rows], minlength=size).tolist() if len(rows) else [0] * size
    return list(zip(per_lane, taken, strict=True))


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
