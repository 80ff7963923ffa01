"""The engine's block runner: every block of frames, live or recorded, goes through it.

:class:`LogRun` is what :meth:`Engine.take <canguard.engine.core.Engine.take>` (the live
daemon's blocks, a frame on a quiet bus) and :meth:`Engine.run_log
<canguard.engine.core.Engine.run_log>` (a recorded log's blocks, each channel routed to a
bus) call. A block is frames, or a column block (plain candump text, numpy byte blocks, or
python-can formats through :mod:`canguard.io.pycan_blocks`) whose configured rows are
decoded per message at once. Frames of no configured message are counted without decoding
while nothing is due; every configured row takes its message's row step
(:mod:`canguard.engine.blocks`), with the ticks and gate deadlines due before it run
first and a tick at once after an edge. It talks to the engine through its public interface only.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from canguard.engine.blockrows import decode_rows
from canguard.engine.lanes import LANE, configured_rows, key_table, lane_plans
from canguard.io.block import EXT_KEY, Block
from canguard.io.frame import Frame
from canguard.protect.columns import SHORT_RUN

MAX_CATCH_UP_S = 2.0
"""Longest stretch of missed ticks the engine replays one by one after a gap (see :meth:`Engine.advance`)."""

if TYPE_CHECKING:
    import py_trees

    from canguard.bt.context import Context
    from canguard.config.schema import Config
    from canguard.decode.decoder import Decoder
    from canguard.engine.blocks import MessagePlan
    from canguard.engine.stats import EngineStats
    from canguard.io.clock import PinnedClock


class Engine(Protocol):
    """What :class:`LogRun` asks of the engine (:class:`canguard.engine.core.Engine` is one)."""

    cfg: Config
    decoder: Decoder
    stats: EngineStats
    ctx: Context
    metrics: Any
    clock: PinnedClock
    sample_hook: Callable[[Any], None] | None
    sample_block: Callable[[Any, list[Any], list[tuple[int, Any]]], None] | None
    last_due_run: float

    due: float
    @property
    def next_tick_t(self) -> float: ...
    def arrive(self, t: float) -> None: ...
    def edge_tick(self, t: float) -> None: ...
    def runs_until(self, end_t: float, coming: Callable[[], Mapping[tuple[int, str], Any]]) -> float: ...
    def controller_state(self, bus: str, frame: Frame) -> None: ...
    def advance(self, now: float) -> None: ...
    def tick(self, now: float) -> py_trees.common.Status: ...
    def drive_clock(self, t: float) -> None: ...
    def frame_time(self, t: float) -> None: ...


class LogRun:
    """Feeds a recorded log to one engine (see the module docstring); it keeps its message plans per bus."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self.decoder = engine.decoder
        self.stats = engine.stats
        self.ctx = engine.ctx
        self._wanted = frozenset(self.decoder.keys())
        self._plans: dict[str, dict[int, MessagePlan | None]] = {}
        """Per bus: id key -> the message's plan (see :mod:`canguard.engine.blocks`)."""
        self._plan_tables: dict[str, tuple[Any, Any]] = {}
        """Per bus: the keys of :attr:`_plans`, as blocks look them up (:func:`.lanes.key_table`)."""
        self._lane_plans: dict[tuple[str, ...], tuple[dict[int, MessagePlan | None], tuple[Any, Any]]] = {}
        """Per channels-to-buses of a block that mixes buses: its plans and their key table (:mod:`.lanes`)."""
        self._by_key: dict[tuple[str, int, bool], MessagePlan] = {}
        """Every plan by the decoder's key, ``(bus, arbitration_id, is_extended_id)``: a frame's plan in one lookup."""
        self._touched: set[MessagePlan] = set()
        """The plans that took rows of this block (flushed at its end)."""

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
        """One block of frames through the engine, whatever its source: a live bus's queue drained, a log's block.

        Taken as columns (:meth:`_run_columns`) when its rows are in order; else row by row
        (:meth:`_run_frames`). Either way each configured row takes its message's row step
        (:func:`~canguard.engine.blocks.take_runs` /
        :meth:`~canguard.engine.blocks.MessagePlan.take_samples`), and the counts are added at the end.
        """
        try:
            if not self._run_columns(block, cursor):
                self._run_frames(block.frames(), cursor)
        finally:
            touched = self._touched
            while touched:
                touched.pop().flush()

    def _run_frames(self, frames: Iterable[Frame], cursor: LogCursor) -> None:
        """:meth:`run` over frames one by one.

        A frame of no configured message before anything is due is counted without decoding; such frames are
        counted together (:meth:`_count_skipped`) before the next frame that is fed, and at the end.
        """
        engine = self.engine
        wanted = self._wanted
        per_bus = self.decoder.per_bus
        route, default_bus, channels = cursor.route, cursor.default_bus, cursor.channels
        last_t, started = cursor.last_t, cursor.started
        last_channel: str | None = None
        run = 0
        due = engine.due  # only feeding a frame (arrive, its row step, an edge tick) moves it
        counted: str | None = None  # the bus of the skipped frames not yet counted
        skipped = backward = 0
        try:
            for frame in frames:  # what a frame reads once is not bound before the loop: a block of one is live
                channel = frame.channel
                if channels is not None:
                    if channel == last_channel:
                        run += 1
                    else:
                        if last_channel is not None:
                            channels[last_channel] = channels.get(last_channel, 0) + run
                        last_channel, run = channel, 1
                bus = route.get(channel, default_bus) if route else default_bus
                if bus is None:
                    cursor.unmapped[channel] = cursor.unmapped.get(channel, 0) + 1
                    continue
                t = frame.t
                if (
                    started
                    and t < due
                    and (bus, frame.arbitration_id, frame.is_extended_id) not in wanted
                    and not frame.is_error_frame
                    and not frame.is_remote_frame
                    and bus in per_bus
                ):
                    if bus != counted:
                        if skipped:
                            self._count_skipped(counted, skipped, backward)
                        counted, skipped, backward = bus, 0, 0
                    skipped += 1
                    if t >= last_t:
                        last_t = t
                    else:
                        backward += 1
                    continue
                if skipped:
                    self._count_skipped(counted, skipped, backward)
                    skipped = backward = 0
                started = True
                engine.arrive(t)  # the ticks due before it first, then its row step, then a tick at once on an edge
                if self._decoded(bus, frame):
                    engine.edge_tick(t)
                if t > last_t:
                    last_t = t
                due = engine.due
        finally:
            if skipped:
                self._count_skipped(counted, skipped, backward)
        if channels is not None and last_channel is not None:
            channels[last_channel] = channels.get(last_channel, 0) + run
        cursor.last_t, cursor.started = last_t, started

    def _count_skipped(self, bus: str | None, frames: int, backward: int) -> None:
        """Count ``frames`` frames of bus ``bus`` taken without decoding (``backward`` of them out of order), as
        the decoder would have counted them."""
        assert bus is not None
        counters = self.decoder.per_bus[bus]
        counters.frames += frames
        counters.skipped += frames
        stats = self.stats
        stats.frames += frames
        stats.backward_frames += backward

    def _decoded(self, bus: str, frame: Frame) -> bool:
        """A frame through its message's row step; True on an edge.

        A data frame of a configured message takes :meth:`MessagePlan.take_payload
        <canguard.engine.blocks.MessagePlan.take_payload>`: a block of one through its message's kernel,
        counted by its plan (a row that is not valid as its samples with their reasons). Any other (error
        and remote frames, unconfigured ids, a message with an alive counter or health roles, a sample hook)
        goes to the frame decoder (:meth:`Decoder.decode`: every reason counted) and its samples to the
        plan's row step.
        """
        engine = self.engine
        plan = None if frame.is_error_frame or frame.is_remote_frame else self._plan_of(bus, frame)
        if plan is not None and engine.sample_hook is None:
            edge = plan.take_payload(frame.data, frame.t)
            if edge is not None:
                self._touched.add(plan)
                return edge
        self.stats.frames += 1
        if frame.is_error_frame:
            engine.controller_state(bus, frame)
        samples = self.decoder.decode(frame, bus)
        if not samples:
            return False
        hook = engine.sample_hook
        if hook is not None:
            for sample in samples:
                hook(sample)
        assert plan is not None  # the decoder gives samples only of a configured message's data frame
        self._touched.add(plan)
        return plan.take_samples(samples)

    def _plan_of(self, bus: str, frame: Frame) -> MessagePlan | None:
        """The plan of a frame's message on ``bus`` (its bus's plans made at its first frame); None: not configured."""
        key = (bus, frame.arbitration_id, frame.is_extended_id)
        plan = self._by_key.get(key)
        if plan is None and key in self._wanted and bus not in self._plans:
            self._plans[bus] = self._compile_plans(bus)
            plan = self._by_key.get(key)
        return plan

    def _run_columns(self, block: Block, cursor: LogCursor) -> bool:
        """:meth:`run` over a block as columns; False (nothing done) when it must go frame by frame.

        A block may mix channels: each row then goes to its channel's bus, with the plans of that
        bus (one key per channel and id when the buses differ).
        """
        engine = self.engine
        export = engine.sample_block
        if not block.ordered or (engine.sample_hook is not None and export is None):
            return False
        ts: Any = block.time_s  # a list is made only for rows that go one by one
        if float(ts[0]) < cursor.last_t:
            return False  # back in time across blocks: the frame-by-frame rules count it
        per_channel = None if block.only_channel is not None else block.channel  # each row's channel, or None
        buses = self._route(block, per_channel, cursor)
        if type(buses) is bool:
            return buses
        assert isinstance(buses, list)
        first = 0
        if not cursor.started:
            self._run_frames((block.frame(0),), cursor)  # the first frame is fed: it starts the engine's clock
            first = 1
        plans, rows, keys, lanes = self._configured(block, buses, per_channel)
        special = block.special
        if special.size:  # counted by the decoder as remote or error frames, configured or not: fed
            import numpy as np

            rows = np.union1d(rows, special)
        if first and len(rows) and rows[0] == 0:
            rows = rows[1:]
        tally = _lane_tally(block, per_channel, rows, first)
        last_row = int(rows[-1]) if len(rows) else -1  # the last row frame by frame would see, whatever path takes it
        taken: list[tuple[MessagePlan, Any, Sequence[Any]]] | None = [] if export is not None else None
        runs, alone = decode_rows(plans, rows, block, ts, keys, taken, self._touched) if len(rows) else ([], [])
        if len(rows):
            ts = block.times  # read row by row below: as floats
        walk = _Walk(block, ts, runs, alone, buses[0] if lanes is None else "", buses, lanes)
        if taken is None:
            pos = self._walk(walk, first, None)
        else:  # --export-signals: the samples of fed rows kept with their row, for the block's export
            assert export is not None
            fed: list[tuple[int, Any]] = []
            pos = self._walk(walk, first, fed)
            export(ts, [(plan.names, group, decoded) for plan, group, decoded in taken], fed)
        self._cross(ts, pos, block.n)
        self._count_lanes(cursor, block, per_channel, buses, tally, first)
        cursor.last_t = float(ts[-1])
        if last_row >= 0:
            engine.frame_time(float(ts[last_row]))  # as frame by frame: the last row fed (not ts[-1])
        return True

    def _route(self, block: Block, lanes: Any, cursor: LogCursor) -> list[str] | bool:
        """The bus of each of a block's channels (``lanes``: each row's channel, None when all rows are on
        one), or of its one channel; True: the block's one channel maps to no bus (its rows counted as
        unmapped: done); False: it must go frame by frame."""
        if lanes is not None:
            buses: list[str] = []
            for name in block.channels:
                found = cursor.route.get(name, cursor.default_bus)
                if found is None or found not in self.decoder.per_bus:
                    return False  # a channel of no bus: its rows do not move time; frame by frame
                buses.append(found)
            return buses
        channel = block.channels[int(block.channel[0])]
        routed = cursor.route.get(channel, cursor.default_bus)
        if routed is None:
            n = block.n
            if cursor.channels is not None:
                cursor.channels[channel] = cursor.channels.get(channel, 0) + n
            cursor.unmapped[channel] = cursor.unmapped.get(channel, 0) + n
            return True
        return [routed] if routed in self.decoder.per_bus else False

    def _configured(self, block: Block, buses: list[str], lanes: Any) -> tuple[Any, Any, Any, Any]:
        """(plans, the block's rows of configured messages, the keys its plans are looked up by, each row's
        channel (an index into ``buses``) when its channels go to several buses, else None)."""
        for b in set(buses):
            if b not in self._plans:
                self._plans[b] = self._compile_plans(b)
        keys = block.keys
        if len(set(buses)) == 1:  # one bus
            bus = buses[0]
            plans = self._plans[bus]
            table = self._plan_tables.get(bus)
            if table is None:
                table = self._plan_tables[bus] = key_table(plans)
            return plans, configured_rows(keys, table), keys, None
        assert lanes is not None  # channels of several buses: a key per (channel, id)
        lane = self._lane_plans.get(tuple(buses))
        if lane is None:
            joined = lane_plans([self._plans[b] for b in buses])
            lane = self._lane_plans[tuple(buses)] = (joined, key_table(joined))
        keys = keys + lanes.astype(keys.dtype) * LANE
        return lane[0], configured_rows(keys, lane[1]), keys, lanes

    def _walk(self, walk: _Walk, first: int, fed: list[tuple[int, Any]] | None) -> int:
        """A block's configured rows in time order: the ticks due among them, each stretch of rows whole and valid
        up to the next due time taken as runs (:func:`~canguard.engine.blocks.take_runs`: to the first edge, where
        the tree ticks), the rows for the frame decoder one by one (``fed``: the samples of fed rows, with their
        row, for ``--export-signals``); the row after the last row walked."""
        from canguard.engine.blocks import take_runs

        engine = self.engine
        if fed is not None:
            at = [0]
            hook, engine.sample_hook = engine.sample_hook, lambda sample: fed.append((at[0], sample))
        decoded, frame, ts = self._decoded, walk.block.frame, walk.ts
        bus, buses, lanes = walk.bus, walk.buses, walk.lanes
        # each message's run and where it goes on: [next, plan, rows (a list: bisected at every stretch), times,
        # columns]
        runs = [[0, plan, rows if type(rows) is list else rows.tolist(), times, columns]
                for plan, rows, times, columns in walk.runs]
        alone, next_alone = walk.alone, 0
        end_rows = walk.block.n
        end_t = float(ts[end_rows - 1])
        pos = first
        try:
            while True:
                i = _first_row(runs, alone[next_alone][0] if next_alone < len(alone) else end_rows)
                if i == end_rows:
                    break
                t = float(ts[i])
                if t >= engine.due:
                    self._cross(ts, pos, i)  # a tick falls due among the rows before this one, or at it
                    if t >= engine.due:
                        engine.advance(t)
                if next_alone < len(alone) and alone[next_alone][0] == i:  # for the frame decoder (its reason...)
                    pos = i + 1
                    next_alone += 1
                    if fed is not None:
                        at[0] = i
                    engine.drive_clock(t)
                    if decoded(bus if lanes is None else buses[lanes[i]], frame(i)):
                        engine.edge_tick(t)
                    continue
                # the stretch before the engine must act (the next due time, or the end of its quiet ticks)
                until = engine.runs_until(end_t, lambda: _coming(runs))
                stop = end_rows if end_t < until else bisect_left(ts, until, i, end_rows, key=float)
                if next_alone < len(alone) and alone[next_alone][0] < stop:
                    stop = alone[next_alone][0]
                last, edge = take_runs(_stretch(runs, stop))
                _drop(runs, last)
                t_last = float(ts[last])
                self._cross(ts, i, last)  # the quiet ticks the stretch spanned, each at its own time
                if t_last >= engine.due:
                    engine.advance(t_last)
                pos = last + 1
                if edge:
                    engine.edge_tick(t_last)
        finally:
            if fed is not None:
                engine.sample_hook = hook  # the export's own hook back, whatever the block raised
        return pos

    def _count_lanes(self, cursor: LogCursor, block: Block, lanes: Any, buses: list[str],
                     tally: list[tuple[int, int]], first: int) -> None:
        """Count a block's rows per channel (``cursor.channels``) and its skipped rows (neither fed nor taken
        by a plan) per bus, as frame by frame counts them."""
        channels = cursor.channels
        for lane, (count, taken) in enumerate(tally):
            if channels is not None:
                name = block.channels[int(block.channel[0])] if lanes is None else block.channels[lane]
                own_first = first if lanes is None or lane == int(lanes[0]) else 0  # counted by _run_frames
                channels[name] = channels.get(name, 0) + count - own_first
            skipped = count - taken
            counters = self.decoder.per_bus[buses[lane]]
            counters.frames += skipped
            counters.skipped += skipped
            self.stats.frames += skipped

    def _cross(self, ts: Sequence[Any], lo: int, hi: int) -> None:
        """Rows ``lo..hi-1`` (ordered, of no configured message): the first at or after the due time brings the ticks.

        What :meth:`Engine.arrive` does for such a frame, without decoding it; repeated while
        another due time falls among the rows left.
        """
        engine = self.engine
        while lo < hi and float(ts[hi - 1]) >= engine.due:
            last = float(ts[hi - 1])
            if last - engine.next_tick_t <= MAX_CATCH_UP_S:
                # No gap among these rows: one advance runs every due time they bring, each at its own
                # time, as row by row would (the rows change nothing else); the clock and the last
                # frame time end at the row that brought the last of them.
                engine.advance(last)
                k = bisect_left(ts, engine.last_due_run, lo, hi, key=float)
            else:
                k = bisect_left(ts, engine.due, lo, hi, key=float)
                engine.advance(float(ts[k]))
            t = float(ts[k])
            engine.drive_clock(t)
            engine.frame_time(t)  # as arrive: not before it (ordered, from cursor.last_t on)
            lo = k + 1

    def _compile_plans(self, bus: str) -> dict[int, MessagePlan | None]:
        """Every message configured on ``bus`` by its id key (:attr:`Block.keys <canguard.io.block.Block.keys>`),
        with its plan, or None."""
        from canguard.engine.blocks import compile_plan

        counters = self.decoder.per_bus[bus]
        plans: dict[int, MessagePlan | None] = {}
        for (b, cid, ext), entry in self.decoder.entries():
            if b != bus:
                continue
            plan = compile_plan(entry, counters, self.ctx, self.stats)
            if plan is not None:
                self._by_key[b, cid, ext] = plan
            plans[cid + EXT_KEY if ext else cid] = plan
        return plans

def _first_row(runs: list[list[Any]], first: int) -> int:
    """The first row not taken yet of any message's run (``[next, plan, rows, times, columns]``), or ``first``
    when it comes before them."""
    for at, _plan, rows, _times, _columns in runs:
        if at < len(rows) and rows[at] < first:
            first = rows[at]
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


def _stretch(runs: list[list[Any]], stop: int) -> list[tuple[Any, list[int], Any, list[Any]]]:
    """Each message's rows not taken yet before row ``stop``, as (plan, rows, times, columns): a short stretch's
    times and columns as lists (the models' and healths' runs of a few samples go sample by sample, faster over
    Python floats than numpy's calls), a long one's as they are (numpy columns: screened with numpy)."""
    out = []
    for at, plan, rows, times, columns in runs:
        if at < len(rows) and rows[at] < stop:
            k = bisect_left(rows, stop, at)
            if k - at <= SHORT_RUN and type(times) is not list:
                out.append((plan, rows[at:k], times[at:k].tolist(), [c[at:k].tolist() for c in columns]))
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
            run[0] = bisect_right(rows, last, at)


def _lane_tally(block: Block, lanes: Any, rows: Any, first: int) -> list[tuple[int, int]]:
    """Per channel of a block (one when ``lanes`` is None): its rows, and those fed or taken by a plan
    (``rows``, and the first row when it went frame by frame)."""
    if lanes is None:
        return [(block.n, len(rows) + first)]
    import numpy as np

    size = len(block.channels)
    per_lane = np.bincount(lanes, minlength=size).tolist()
    taken = np.bincount(lanes[rows], minlength=size).tolist() if len(rows) else [0] * size
    if first:
        taken[int(lanes[0])] += 1
    return list(zip(per_lane, taken, strict=True))


@dataclass
class _Walk:
    """A block's rows as :meth:`LogRun._walk` takes them."""

    block: Block
    ts: Any
    runs: Any
    """Each configured message's rows whole and valid: (plan, rows, times, columns) (:func:`.blockrows.decode_rows`)."""
    alone: Any
    """The rows the frame decoder takes, in order: (row, plan or None)."""
    bus: str
    """The bus of every row, or "" when they go to several (``lanes``)."""
    buses: list[str]
    """The bus of each of the block's channels."""
    lanes: Any
    """Each row's channel, an index into :attr:`buses`, when the block's channels go to several buses; else None."""


@dataclass
class LogCursor:
    """Where a stream of blocks is (a log, or a live bus): routing, counts, the latest time."""

    route: Mapping[str, str]
    default_bus: str | None
    unmapped: dict[str, int]
    channels: dict[str, int] | None
    last_t: float = -math.inf
    started: bool = False
