"""Replaying a recorded log through the engine: routing, the unconfigured-frame short path, column blocks.

:class:`LogRunMixin` gives :class:`~canguard.engine.core.Engine` its :meth:`run_log`:
the same :meth:`feed` / :meth:`advance` as live, with frames of no configured message
counted without decoding and column blocks (plain candump text, or python-can
formats through :mod:`canguard.io.pycan_blocks`) worked on as columns, each
configured message's rows decoded together (:mod:`canguard.engine.blocks`). Split
from the engine's core so each stays readable.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from itertools import compress
from typing import TYPE_CHECKING, Any

import py_trees

from canguard.engine.blockrows import decode_rows
from canguard.engine.lanes import LANE, configured_rows, key_table, lane_plans
from canguard.io.frame import Frame

MAX_CATCH_UP_S = 2.0
"""Longest stretch of missed ticks the engine replays one by one after a gap (see :meth:`Engine.advance`)."""

if TYPE_CHECKING:
    from canguard.bt.context import Context
    from canguard.config.schema import Config
    from canguard.decode.decoder import Decoder
    from canguard.engine.blocks import MessagePlan
    from canguard.engine.stats import EngineStats
    from canguard.io.candump_np import ByteColumns
    from canguard.io.clock import PinnedClock
    from canguard.io.logs import Columns


class LogRunMixin:
    """The log-replay half of the engine (see the module docstring)."""

    if TYPE_CHECKING:  # what the engine provides
        cfg: Config
        ctx: Context
        clock: PinnedClock
        decoder: Decoder
        stats: EngineStats
        columns: bool
        _due: float
        _last_frame_t: float
        _drive_clock: Callable[[float], None]
        _wanted: frozenset[tuple[str, int, bool]]
        _plans: dict[str, dict[str | int, MessagePlan | None]]
        _plan_tables: dict[str, tuple[Any, Any]]
        _lane_plans: dict[tuple[str, ...], tuple[dict[int, MessagePlan | None], tuple[Any, Any]]]
        _plan_list: dict[str, list[MessagePlan]]
        _dirty: bool
        durable: bool
        events: Any
        metrics: Any
        extra_on_event: Callable[[dict[str, Any]], None] | None
        sample_hook: Callable[[Any], None] | None
        sample_block: Callable[[Sequence[Any], list[Any], list[tuple[int, Any]]], None] | None
        elide_ticks: bool
        replay_quiet_ticks: bool
        _q_fixed: bool
        _next_tick: float
        last_due_run: float

        def feed(self, bus: str, frame: Frame) -> None: ...
        def advance(self, now: float) -> None: ...
        def tick(self, now: float) -> py_trees.common.Status: ...
        def _block_horizon(self, fresh: Mapping[int, Mapping[str, float]]) -> float: ...

    def run_log(
        self, frames: Iterable[Frame], route: Mapping[str, str], default_bus: str | None,
        unmapped: dict[str, int], channels: dict[str, int] | None = None,
    ) -> None:
        """Feed a recorded log: each frame goes to the bus its channel maps to (``route``, else ``default_bus``).

        Frames of no configured message (most of a busy bus) take a short path: they are
        counted as the decoder would count them and never decoded. Nothing else changes:
        ticks and gate deadlines still run at their own times, brought up by the first
        frame at or after them, exactly as if every frame had been fed; the first frame
        is always fed (it starts the engine's clock). ``channels``, when given, counts
        the frames of each channel.

        ``frames`` may be a reader with a ``chunks()`` method (:func:`canguard.io.logs.read_log`):
        a column block (:class:`~canguard.io.logs.Columns`: plain candump text, or python-can
        messages) of one channel whose timestamps never go back is then worked on as columns: only its configured rows
        become frames, and its other rows are looked at only where a tick falls due among
        them (a bisection over the block's timestamps).
        """
        cursor = _LogCursor(route, default_bus, unmapped, channels)
        self.elide_ticks = self.replay_quiet_ticks  # grid ticks proven to repeat the last one: counted, not run
        if self.columns and hasattr(frames, "chunks"):
            for chunk in frames.chunks():
                if type(chunk) is list:
                    self._run_frames(chunk, cursor)
                elif not self._run_columns(chunk, cursor):
                    self._run_frames(chunk.frames(), cursor)
        else:
            self._run_frames(frames, cursor)
        last_t = cursor.last_t
        if last_t > -math.inf:
            self._drive_clock(last_t)
            if last_t > self._last_frame_t:
                self._last_frame_t = last_t

    def _run_frames(self, frames: Iterable[Frame], cursor: _LogCursor) -> None:
        """:meth:`run_log` over frames one by one."""
        feed = self.feed
        wanted = self._wanted
        per_bus = self.decoder.per_bus
        stats = self.stats
        route, default_bus, unmapped, channels = cursor.route, cursor.default_bus, cursor.unmapped, cursor.channels
        last_t, started = cursor.last_t, cursor.started
        last_channel: str | None = None
        run = 0
        for frame in frames:
            channel = frame.channel
            if channels is not None:
                if channel == last_channel:
                    run += 1
                else:
                    if last_channel is not None:
                        channels[last_channel] = channels.get(last_channel, 0) + run
                    last_channel, run = channel, 1
            bus = route.get(channel, default_bus)
            if bus is None:
                unmapped[channel] = unmapped.get(channel, 0) + 1
                continue
            t = frame.t
            if (
                started
                and (bus, frame.arbitration_id, frame.is_extended_id) not in wanted
                and not frame.is_error_frame
                and not frame.is_remote_frame
                and t < self._due
            ):
                counters = per_bus.get(bus)
                if counters is not None:
                    counters.frames += 1
                    counters.skipped += 1
                    stats.frames += 1
                    if t >= last_t:
                        last_t = t
                    else:
                        stats.backward_frames += 1
                    continue
            started = True
            feed(bus, frame)
            if t > last_t:
                last_t = t
        if channels is not None and last_channel is not None:
            channels[last_channel] = channels.get(last_channel, 0) + run
        cursor.last_t, cursor.started = last_t, started

    def _run_columns(self, cols: Columns | ByteColumns, cursor: _LogCursor) -> bool:
        """:meth:`run_log` over a column block; False (nothing done) when it must go frame by frame.

        A numpy block may mix channels (``lanes``): each row then goes to its channel's bus,
        with the plans of that bus (one key per channel and id when the buses differ).
        """
        export = self.sample_block
        if not cols.ordered or (self.sample_hook is not None and export is None):
            return False
        # The timestamps: a numpy block's as an array (its list is made only for rows that go one by one)
        ts: Any = cols.ts if isinstance(cols, tuple) else cols.stamps
        n = cols.n
        if float(ts[0]) < cursor.last_t:
            return False  # back in time across blocks: the frame-by-frame rules count it
        channel = cols.channel
        lanes = getattr(cols, "lanes", None)
        if channel is None:
            if lanes is None:
                return False
            buses: list[str] = []
            for name in getattr(cols, "channels", ()):
                found = cursor.route.get(name, cursor.default_bus)
                if found is None or found not in self.decoder.per_bus:
                    return False  # a channel of no bus: its rows do not move time; frame by frame
                buses.append(found)
            bus = buses[0] if len(set(buses)) == 1 else ""
        else:
            routed = cursor.route.get(channel, cursor.default_bus)
            if routed is not None and routed not in self.decoder.per_bus:
                return False
            if routed is None:
                if cursor.channels is not None:
                    cursor.channels[channel] = cursor.channels.get(channel, 0) + n
                cursor.unmapped[channel] = cursor.unmapped.get(channel, 0) + n
                return True
            bus = routed
            buses = [bus]
        first = 0
        if not cursor.started:
            self._run_frames((cols.frame(0),), cursor)  # the first frame is fed: it starts the engine's clock
            first = 1
        for b in set(buses):
            if b not in self._plans:
                self._plans[b] = self._compile_plans(b)
        keys = getattr(cols, "keys", None)
        bus_at: list[str] | None = None
        if bus:  # one bus
            plans = self._plans[bus]
            if keys is not None and plans:  # a numpy block: its configured rows found by numpy
                table = self._plan_tables.get(bus)
                if table is None:
                    table = self._plan_tables[bus] = key_table(plans)
                rows = configured_rows(keys, table)
            else:
                rows = list(compress(range(n), map(plans.__contains__, cols.ids))) if plans else []
        else:  # channels of several buses: a key per (channel, id)
            assert lanes is not None and keys is not None
            lane = self._lane_plans.get(tuple(buses))
            if lane is None:
                joined = lane_plans([self._plans[b] for b in buses])
                lane = self._lane_plans[tuple(buses)] = (joined, key_table(joined))
            plans = lane[0]  # type: ignore[assignment]
            keys = keys + lanes * LANE
            rows = configured_rows(keys, lane[1])
            bus_at = list(map(buses.__getitem__, lanes.tolist()))
        # rows: a list, or a numpy block's index array (a list only if its rows go one by one below)
        remote = cols.remote
        if remote:  # counted by the decoder as remote frames, configured or not: fed
            rows = sorted(set(rows if type(rows) is list else rows.tolist()).union(remote))
        if first and len(rows) and rows[0] == 0:
            rows = rows[1:]
        tally = _lane_tally(cols, rows, first)
        last_row = int(rows[-1]) if len(rows) else -1  # the last row feed would see, whatever path takes it
        taken: list[tuple[MessagePlan, Any, Sequence[Any]]] | None = [] if export is not None else None
        slots = decode_rows(plans, rows, cols, ts, self._q_fixed, keys, taken, self._block_horizon) if len(rows) else []
        if slots is None:
            rows = []  # every row taken whole: only the ticks due in the block are left
            slots = []
        elif len(rows):
            ts = cols.ts  # read row by row below: as floats
            if type(rows) is not list:
                rows = rows.tolist()
        feed = self.feed
        frame = cols.frame
        pos = first
        due = self._due  # plans never change it; advance, feed and tick may
        if taken is not None:  # --export-signals: the samples of fed rows kept with their row, for the block's export
            fed: list[tuple[int, Any]] = []
            at = [0]
            hook, self.sample_hook = self.sample_hook, lambda sample: fed.append((at[0], sample))
        try:
            for i in rows:
                item = slots[i]
                if item is None:
                    continue  # taken whole, or without a configured signal: counted by its plan
                plan, values = item
                t = float(ts[i])
                if t >= due:
                    self._cross(ts, pos, i)  # a tick falls due among the rows before this one, or at it
                    if t >= self._due:
                        self.advance(t)
                    due = self._due
                pos = i + 1
                edge = plan.step(values, t) if values is not None and plan is not None else None
                if edge is None:
                    if taken is not None:
                        at[0] = i
                    feed(bus if bus_at is None else bus_at[i], frame(i))  # the general path, what plans must equal
                    due = self._due
                elif edge:
                    self._drive_clock(t)
                    self.stats.edge_ticks += 1
                    self.tick(self.clock.now())
                    due = self._due
        finally:
            if taken is not None:
                self.sample_hook = hook  # the export's own hook back, whatever the block raised
        if taken is not None:
            assert export is not None
            export(ts, [(plan.names, group, decoded) for plan, group, decoded in taken], fed)
        self._cross(ts, pos, n)
        for b in set(buses):
            for plan in self._plan_list[b]:
                plan.flush()
        self._count_lanes(cursor, cols, buses, tally, first)
        cursor.last_t = float(ts[-1])
        if last_row >= 0 and float(ts[last_row]) > self._last_frame_t:
            self._last_frame_t = float(ts[last_row])  # as frame by frame: the last row fed (not ts[-1])
        return True

    def _count_lanes(self, cursor: _LogCursor, cols: Any, buses: list[str], tally: list[tuple[int, int]],
                     first: int) -> None:
        """Count a block's rows per channel (``cursor.channels``) and its skipped rows (neither fed nor taken
        by a plan) per bus, as frame by frame counts them."""
        lanes = getattr(cols, "lanes", None)
        channels = cursor.channels
        for lane, (count, taken) in enumerate(tally):
            if channels is not None:
                name = cols.channel if lanes is None else cols.channels[lane]
                own_first = first if lanes is None or lane == int(lanes[0]) else 0  # counted by _run_frames
                channels[name] = channels.get(name, 0) + count - own_first
            skipped = count - taken
            counters = self.decoder.per_bus[buses[lane]]
            counters.frames += skipped
            counters.skipped += skipped
            self.stats.frames += skipped

    def _cross(self, ts: Sequence[Any], lo: int, hi: int) -> None:
        """Rows ``lo..hi-1`` (ordered, of no configured message): the first at or after the due time brings the ticks.

        What :meth:`feed` does for such a frame, without decoding it; repeated while
        another due time falls among the rows left.
        """
        while lo < hi and float(ts[hi - 1]) >= self._due:
            last = float(ts[hi - 1])
            if last - self._next_tick <= MAX_CATCH_UP_S:
                # No gap among these rows: one advance runs every due time they bring, each at its own
                # time, as row by row would (the rows change nothing else); the clock and the last
                # frame time end at the row that brought the last of them.
                self.advance(last)
                k = bisect_left(ts, self.last_due_run, lo, hi, key=float)
            else:
                k = bisect_left(ts, self._due, lo, hi, key=float)
                self.advance(float(ts[k]))
            t = float(ts[k])
            self._drive_clock(t)
            self._last_frame_t = t  # as feed: not before it (ordered, from cursor.last_t on)
            lo = k + 1

    def _compile_plans(self, bus: str) -> dict[str | int, MessagePlan | None]:
        """Every id text (any letter case) of a message configured on ``bus``, with its plan or None (feed it)."""
        from canguard.engine.blocks import compile_plan
        from canguard.engine.settle import may_settle
        from canguard.io.logs import candump_id_texts
        from canguard.io.logtypes import id_key

        counters = self.decoder.per_bus[bus]
        plans: dict[str | int, MessagePlan | None] = {}
        made = self._plan_list.setdefault(bus, [])
        # the stop confirmation reads its source between ticks: not passive; metrics count per frame
        readers: set[str] | None = set(self.ctx.read_sources)
        confirm = self.cfg.stop.confirm.source if self.cfg.stop.confirm is not None else None
        if confirm is not None:
            assert readers is not None
            readers.add(confirm)
        if self.metrics is not None:
            readers = None
        for (b, cid, ext), entry in self.decoder.entries():
            if b != bus:
                continue
            plan = compile_plan(entry, counters, self.ctx, self.stats, readers)
            if plan is not None:
                plan.settle_ok = may_settle(plan, self.metrics is not None, self.ctx.read_sources)
                plan.confirm_read = any(source == confirm for source, *_rest in plan.outputs)
                made.append(plan)
            for text in candump_id_texts(cid, ext):
                plans[text] = plan
            plans[id_key(cid, ext)] = plan  # the ids of byte blocks (canguard.io.candump_np)
        return plans

def _lane_tally(cols: Any, rows: Any, first: int) -> list[tuple[int, int]]:
    """Per channel of a block (one when it has one): its rows, and those fed or taken by a plan (``rows``,
    and the first row when it went frame by frame)."""
    lanes = getattr(cols, "lanes", None)
    if lanes is None:
        return [(cols.n, len(rows) + first)]
    import numpy as np

    size = len(cols.channels)
    per_lane = np.bincount(lanes, minlength=size).tolist()
    taken = np.bincount(lanes[rows], minlength=size).tolist() if len(rows) else [0] * size
    if first:
        taken[int(lanes[0])] += 1
    return list(zip(per_lane, taken, strict=True))


@dataclass
class _LogCursor:
    """Where :meth:`Engine.run_log` is in a log: routing, counts, the latest time."""

    route: Mapping[str, str]
    default_bus: str | None
    unmapped: dict[str, int]
    channels: dict[str, int] | None
    last_t: float = -math.inf
    started: bool = False
