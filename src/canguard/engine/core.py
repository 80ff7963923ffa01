"""The engine: frames -> decode -> protection models -> blackboard -> tree -> frames out.

One engine for the daemon and for replay; they differ only in where frames come
from and in the clock (live: :class:`~canguard.io.clock.LiveClock`; replay: a
:class:`~canguard.io.clock.ManualClock` driven by the log's timestamps). Nothing
here asks which one it is.

Tick policy (the same live and in replay):

- the tree ticks on a fixed grid of ``1 / tick_hz`` in the clock's time; ticks
  due before a frame's time run, at their own time, before that frame;
- a sample that changes a protection model's state (an edge) ticks the tree at
  once, at the sample's time, so a trip reaches the bus without waiting for the
  next period;
- periodic task / stop frames and the stop confirmation deadline are serviced at
  their own times between ticks.

A gap in time (a daemon stall, a gap in a log) longer than ``MAX_CATCH_UP_S``
does not replay every missed tick: the grid jumps forward and the jump is counted.
"""

from __future__ import annotations

import logging
import math
import time
from bisect import bisect_left
from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import compress, repeat
from operator import itemgetter
from typing import TYPE_CHECKING, Any, Protocol

import py_trees

from canguard.bt.context import Context, FrameSink
from canguard.config.schema import Config
from canguard.decode.decoder import Decoder
from canguard.engine.gate import TaskGate
from canguard.io.clock import Clock, PinnedClock
from canguard.io.frame import Frame
from canguard.protect.base import LatchedModel

if TYPE_CHECKING:
    from canguard.bt.loader import GuardView
    from canguard.engine.rows import Batch, Handle
    from canguard.io.logs import Columns

log = logging.getLogger(__name__)

MAX_KEPT_TRIPS = 100_000
"""Trip events kept in memory for summaries and the live view; later ones are only counted."""

MAX_CATCH_UP_S = 2.0
"""Longest stretch of missed ticks the engine replays one by one after a gap."""


class EventSink(Protocol):
    """What the engine writes events to (:class:`~canguard.engine.events.EventJournal` is one)."""

    def write(self, event: Mapping[str, Any]) -> None:
        """Append one event."""
        ...

    def flush(self) -> None:
        """Make every written event durable."""
        ...


@dataclass
class EngineStats:
    """Counters of one engine run (the replay summary and the daemon's STATUS read them)."""

    frames: int = 0
    ticks: int = 0
    edge_ticks: int = 0
    skipped_ticks: int = 0
    tick_errors: int = 0
    backward_frames: int = 0
    trips: list[dict[str, Any]] = field(default_factory=list)
    """Every trip event, up to :data:`MAX_KEPT_TRIPS` (a guard flapping for days must not eat the memory)."""
    trip_count: int = 0
    """Every trip, kept or not."""
    samples: dict[str, int] = field(default_factory=dict)
    """Samples decoded per source."""
    max_abs: dict[tuple[str, str], float] = field(default_factory=dict)
    """Largest |value| seen per (source, role): for the lowest margin to each threshold."""
    max_level_pct: dict[str, float] = field(default_factory=dict)
    """Largest accumulator level (% of trip) per guard node, sampled at ticks."""


class Engine:
    """Runs one config's tree over frames from any source, on any clock."""

    columns = True
    """:meth:`run_log` works on plain candump blocks as columns (False: frame by frame, the reference path)."""

    def __init__(
        self,
        cfg: Config,
        clock: Clock,
        sink: FrameSink,
        *,
        events: EventSink | None = None,
        durable: bool = True,
        metrics: Any = None,
        heat: Any = None,
        save_heat: bool = True,
        on_event: Callable[[dict[str, Any]], None] | None = None,
        previous: Engine | None = None,
    ) -> None:
        from canguard.bt.loader import load_tree, require_guard_coverage  # the node library pulls in py_trees' parser

        if cfg.tree is None:
            from canguard.errors import ConfigError

            raise ConfigError(f"{cfg.path}: tree: missing, expected {{file: TREE.xml, main: ID, tick_hz: HZ}}")
        self.cfg = cfg
        self.clock = PinnedClock(clock)
        self._drive_clock = clock.advance_to
        """The inner clock's advance (a no-op live): called per frame, so bound once."""
        self._due = -math.inf
        """Earliest time a tick or gate deadline is due: frames before it skip :meth:`advance`."""
        clock = self.clock
        self.sink = sink
        self.events = events
        self.durable = durable
        self.metrics = metrics
        self.heat = heat
        self.save_heat = save_heat
        """False: heat is only restored from the state file, never written (replay reads, never mutates)."""
        self.extra_on_event = on_event
        self.sample_hook: Callable[[Any], None] | None = None
        """Called with every decoded sample (plots); None keeps the hot path lean."""
        self.tick_hook: Callable[[float], None] | None = None
        """Called after every tick with its time (plots)."""
        self.stats = EngineStats()
        self.decoder = Decoder(cfg)
        self.ctx = Context(clock, cfg.sources, sink=sink, actions=cfg.actions, on_event=self._write_event,
                           stop_frames=cfg.stop.frames)
        if previous is not None:
            # A reload: sources configured as before keep their data, so the new tree does not
            # start blind (and fail on "no data") while the robot is running.
            for name, health in previous.ctx.health.items():
                if previous.ctx.sources.get(name) == self.ctx.sources.get(name):
                    self.ctx.health[name] = health
        self.gate = TaskGate(cfg.task, cfg.stop, sink, health=self.ctx.health, on_event=self._gate_event)
        self.ctx.task = self.gate
        self.loaded = load_tree(cfg.tree.file, self.ctx, cfg.tree.main)
        require_guard_coverage(self.loaded)
        self.root: py_trees.behaviour.Behaviour = self.loaded.root
        self._guards = self.loaded.guards()
        self._guard_nodes = self.loaded.guard_nodes()
        self.gate.explain = self._explain
        from canguard.bt.nodes.actions import assign_roles

        self.gate.tree_has_task = assign_roles(self.root)
        read = [cfg.sources[s].max_age_s for s in self.ctx.read_sources if s in cfg.sources]
        self._start_grace_s = max(read, default=0.0)
        ages = [s.max_age_s for s in cfg.sources.values()]
        self._gap_horizon_s = max(ages, default=0.0) + MAX_CATCH_UP_S
        """How much of a gap is ticked through before the rest is jumped: every source goes stale in it."""
        self.period_s = 1.0 / cfg.tree.tick_hz
        self._next_tick = math.nan
        self._stale: dict[str, str] = {}
        self._started_at = math.nan
        self._dirty = False
        self._heat_failed = False
        self._last_frame_t = -math.inf
        self.first_frame_t = math.nan
        self.events_seen: Counter[str] = Counter()
        """How many events of each name were written (summaries count escalations...); bounded, live for weeks."""
        self.last_status = py_trees.common.Status.INVALID
        self.last_tick_t = math.nan
        self._wanted = frozenset(self.decoder.keys())
        self._row_handles: dict[str, dict[str, Handle | None]] = {}
        """Per bus: the compiled row handlers of the replay column path (see :mod:`canguard.engine.rows`)."""
        self._row_flush: dict[str, list[Callable[[], None]]] = {}
        self._row_passive: dict[str, dict[str, Batch]] = {}
        """Per bus: id text -> whole-block path of the messages nobody reads between ticks."""

    # -- life cycle ------------------------------------------------------------------------
    def start(self, now: float | None = None) -> None:
        """Begin: the first tick is due at once; heat is restored from the state file."""
        t = self.clock.now() if now is None else now
        self.clock.advance_to(t)
        self._started_at = t
        self._next_tick = t
        if self.heat is not None:
            self.heat.load(t)
            for key, model in self.ctx.heat_models.items():
                self.heat.restore(key, model, t)
        tree = self.cfg.tree
        self._event({"event": "start", "reason": f"tree {self.loaded.main_id} from {tree.file.name if tree else ''}"})

    def adopt(self, old: Engine) -> None:
        """Take over a running engine's task state, counters and source watch (config reload)."""
        self.gate.adopt(old.gate)
        self._carry_models(old)
        self.stats.trips = old.stats.trips
        self.stats.trip_count = old.stats.trip_count
        self.stats.frames = old.stats.frames
        self._stale = dict(old._stale)
        self._started_at = old._started_at
        self.first_frame_t = old.first_frame_t
        self._last_frame_t = old._last_frame_t
        self._due = min(self._next_tick, self.gate.next_deadline())

    def _carry_models(self, old: Engine) -> None:
        """Each guard of the new tree continues the model state of the same guard in the old tree.

        The same guard: same node name, node type and source. Its new model keeps the new
        parameters and takes over the old model's running state (:meth:`LatchedModel.carry_from`):
        a trip (a hysteresis guard sitting between its thresholds stays tripped), a running
        ``trip_after`` / ``recover_after`` timer, an inrush window, I²t heat. Without it a
        reload that changed a threshold restarted the guard cold (issue 12, item 8).
        """
        old_guards = {g.name: g for g in old._guard_nodes}
        for guard in self._guard_nodes:
            before = old_guards.get(guard.name)
            if before is None or type(before) is not type(guard) or before.topic_name != guard.topic_name:
                continue
            old_models = {role: model for role, model, _ in before.guarded()}
            for role, model, _kind in guard.guarded():
                was = old_models.get(role)
                if was is not None and isinstance(model, LatchedModel):
                    model.carry_from(was)

    def finish(self, reason: str = "end", stop: bool = True) -> None:
        """End: optionally stop the task (frames out), save heat, write the exit event, flush."""
        now = self.clock.now()
        if stop and self.gate.state == TaskGate.RUNNING:
            self.gate.stop(now, reason=reason)
        elif stop and self.gate.state == TaskGate.STOPPED:
            self.gate.resend_stop(now)  # once more on the way out: the drives hear it last
        self._save_heat(now, periodic=False)
        self._event({"event": "exit", "reason": reason})
        self._flush()

    # -- frames in -------------------------------------------------------------------------
    def feed(self, bus: str, frame: Frame) -> None:
        """Process one frame received on ``bus`` at ``frame.t``: ticks due before it run first."""
        t = frame.t
        if t >= self._last_frame_t:
            if self._last_frame_t == -math.inf:
                self.first_frame_t = t
            self._last_frame_t = t
        else:
            self.stats.backward_frames += 1  # out of order: the models' own rules handle it
        if math.isnan(self._next_tick):
            # Not started yet (replay): start at this frame and feed it before the first tick, as live,
            # where the frames queued while the daemon started are fed before its first tick; otherwise
            # every replay began with a "no_data" trip on the very frame that brings the data.
            self.start(t)
        if t >= self._due:  # a tick or a gate deadline is due before this frame
            self.advance(t)
        self._drive_clock(t)  # replay: log time drives the clock; live clocks ignore it
        self.stats.frames += 1
        edge = False
        dispatch = self.ctx.dispatch
        max_abs = self.stats.max_abs
        counts = self.stats.samples
        hook = self.sample_hook
        for sample in self.decoder.decode(frame, bus):
            if dispatch(sample):
                edge = True
            counts[sample.source] = counts.get(sample.source, 0) + 1
            if hook is not None:
                hook(sample)
            if not sample.reason:
                key = (sample.source, sample.signal)
                v = abs(sample.value)
                if v > max_abs.get(key, -1.0):
                    max_abs[key] = v
        if edge:
            self.stats.edge_ticks += 1
            self.tick(self.clock.now())

    def next_due(self) -> float:
        """The next time the engine has something to do (a tick or a gate deadline)."""
        if math.isnan(self._next_tick):
            return -math.inf
        return min(self._next_tick, self.gate.next_deadline())

    def advance(self, now: float) -> None:
        """Run every tick and gate deadline due up to ``now``, each at its own time."""
        if math.isnan(self._next_tick):
            self.start(now)
        if now - self._next_tick > MAX_CATCH_UP_S:
            # A gap: tick through its beginning, where sources go stale and guards trip at their
            # own times (max_age after the last frame); then jump the quiet rest of it.
            self._run_due(min(now, self._next_tick + self._gap_horizon_s))
            missed = math.floor((now - self._next_tick - MAX_CATCH_UP_S) / self.period_s)
            if missed > 0:
                self._next_tick += missed * self.period_s
                self.stats.skipped_ticks += missed
                # The gate's periodic frames skip the gap too: sent one by one, a day-long gap in a
                # log was millions of task frames (a replay that never ended).
                self.gate.skip_to(self._next_tick)
        self._run_due(now)
        self._due = min(self._next_tick, self.gate.next_deadline())
        self._flush()

    def _run_due(self, now: float) -> None:
        """Every tick and gate deadline due up to ``now``, in time order, each at its own time."""
        while True:
            due_gate = self.gate.next_deadline()
            due = min(self._next_tick, due_gate)
            if due > now:
                break
            self.clock.advance_to(due)
            if self._next_tick <= due_gate:
                self.tick(due)
                self._next_tick += self.period_s
            else:
                self.gate.service(self.clock.pin(due))
                self.clock.unpin()

    # -- the tick --------------------------------------------------------------------------
    def tick(self, now: float) -> py_trees.common.Status:
        """Tick the tree once at ``now`` and act on its status."""
        now = self.clock.pin(now)
        try:
            return self._tick(now)
        finally:
            self.clock.unpin()

    def _tick(self, now: float) -> py_trees.common.Status:
        if self.ctx.tree_start is None:
            self.ctx.tree_start = now
        # Sources first: a stale one holds the task before the tree runs, and one that is fine
        # again releases it in time for this tick's ExecuteTask.
        self._watch_sources(now)
        self.gate.begin_tick()
        t0 = time.perf_counter()
        try:
            self.root.tick_once()
            status = self.root.status
        except Exception as exc:  # a node that raises must stop the task, not the daemon
            self.stats.tick_errors += 1
            log.exception("tree tick failed")
            self._event({"event": "error", "reason": f"tree tick raised {type(exc).__name__}: {exc}"})
            status = py_trees.common.Status.FAILURE
        if self.metrics is not None:
            self.metrics.observe_tick(time.perf_counter() - t0)
        self.stats.ticks += 1
        self.last_status = status
        self.last_tick_t = now
        failed = status == py_trees.common.Status.FAILURE
        cause = ("", "")
        if failed:
            tip = self.root.tip()
            node = tip.name if tip is not None else self.root.name
            if not self._starting(now):
                detail = tip.feedback_message if tip is not None else ""
                self.gate.stop(now, reason=f"tree failed at {node}" + (f": {detail}" if detail else ""), node=node)
            cause = self._failure_cause(node)
        # The one place a stop may end (TaskGate._release_rule), and task action frames go out or are withheld.
        self.gate.end_tick(now, failed, cause)
        self._sample_levels()
        if self.tick_hook is not None:
            self.tick_hook(now)
        self.gate.service(now)
        self._save_heat(now, periodic=True)
        self._flush()
        self._due = min(self._next_tick, self.gate.next_deadline())
        return status

    def _save_heat(self, now: float, periodic: bool) -> None:
        """Save I²t heat (periodically, or now); a failing save is an event, never a crash."""
        if self.heat is None or not self.save_heat or not self.ctx.heat_models:
            return
        try:
            if periodic:
                self.heat.maybe_save(self.ctx.heat_models, now, self.cfg.state.save_period_s)
            else:
                self.heat.save(self.ctx.heat_models, now)
        except (OSError, ValueError) as exc:
            if not self._heat_failed:
                log.error("cannot save I²t state: %s", exc)
                self._event({"event": "error", "reason": f"cannot save I²t state: {exc}"})
            self._heat_failed = True
        else:
            self._heat_failed = False

    def _failure_cause(self, tip: str) -> tuple[str, str]:
        """(node, reason) of a failed tick: the failing guards with why, else the node the tree failed at.

        Made of what only changes at an edge (guard feedback is written at trips and reason
        changes), so a ``reason`` event marks a real change, not a new sample.
        """
        failed = py_trees.common.Status.FAILURE
        first = next((g.name for g in self._guard_nodes if g.status == failed), "")
        if first:
            return first, self._explain()
        return tip, f"tree failed at {tip}"

    def _explain(self) -> str:
        """The guards that failed in this tick, with why (for stop events)."""
        failed = py_trees.common.Status.FAILURE
        return "; ".join(
            f"{g.name}: {g.feedback_message}" if g.feedback_message else g.name
            for g in self._guard_nodes if g.status == failed
        )

    def _starting(self, now: float) -> bool:
        """True while the task never ran and the sources still have their first max_age to speak.

        A tree that fails in that window only keeps the task from starting: the
        drives were never enabled, so no stop frames go out (they would latch an
        ESTOP error that needs clearing). After it, a failing tree stops, enabled or not.
        """
        return self.gate.state == TaskGate.IDLE and now - self._started_at < self._start_grace_s

    def _watch_sources(self, now: float) -> None:
        for name, health in self.ctx.health.items():
            reason = health.reason(now)
            if reason == "no_data" and now - self._started_at < self.ctx.sources[name].max_age_s:
                reason = ""  # not yet: every source gets max_age to send its first frame
            prev = self._stale.get(name, "")
            if name in self.ctx.read_sources:
                # Backstop, whatever the tree's shape: a source the tree reads that is stale or
                # invalid holds the task stopped until it is fine again.
                if reason:
                    self.gate.inhibit(f"source {name}", f"source {name}: {reason}", now)
                elif prev:
                    self.gate.release(f"source {name}")
            if reason != prev:
                self._stale[name] = reason
                if reason:
                    self._event({"event": "stale", "source": name, "reason": reason,
                                 "read_by_tree": name in self.ctx.read_sources})
                else:
                    self._event({"event": "fresh", "source": name, "reason": f"{prev} cleared"})
            if self.metrics is not None:
                age = health.age(now, None) if hasattr(health, "age") else math.nan
                self.metrics.set_sample_age(name, age)

    def _sample_levels(self) -> None:
        levels = self.stats.max_level_pct
        for node, model in self.ctx.heat_models.items():
            pct = model.snapshot().level_pct
            if pct > levels.get(node, -1.0):
                levels[node] = pct
            if self.metrics is not None:
                self.metrics.set_i2t_level(node, pct)

    def bus_down(self, bus: str, reason: str) -> None:
        """A bus went away: the task stops (frames out on the buses still up) until :meth:`bus_up`."""
        now = self.clock.now()
        self._event({"event": "bus_error", "source": bus, "reason": reason})
        self.gate.inhibit(f"bus {bus}", f"bus {bus} down: {reason}", now)
        self._due = min(self._due, self.gate.next_deadline())
        self._flush()

    def bus_up(self, bus: str) -> None:
        """The bus is open again: its inhibit is released (the tree decides whether the task resumes)."""
        self.gate.release(f"bus {bus}")

    def guards(self) -> list[GuardView]:
        """Every guarded signal of the tree (node, source, role, kind, model), in tree order."""
        return self._guards

    # -- watchdog and status ---------------------------------------------------------------
    def stale_unstopped(self, now: float) -> list[str]:
        """Sources the tree reads that are stale while the task is not stopped (a blind daemon)."""
        if self.gate.state == TaskGate.STOPPED:
            return []
        return [s for s in self.ctx.read_sources if self.ctx.health[s].reason(now)]

    def status_line(self) -> str:
        """A one-line summary for systemd's STATUS=."""
        d = self.decoder
        return (f"task {self.gate.state}; tree {self.last_status.value}; stops {self.gate.stops}; "
                f"trips {self.stats.trip_count}; frames {self.stats.frames} decoded {d.decoded} "
                f"invalid {d.invalid}")

    # -- events ----------------------------------------------------------------------------
    def _gate_event(self, event: str, now: float, **fields: Any) -> None:
        self._event({"t": now, "event": event, **fields})

    def _write_event(self, event: dict[str, Any]) -> None:
        # A guard failing for "no_data" in the start window (see _starting) only keeps the task from
        # starting: journalled, but not a trip (the live daemon's first tick often precedes the first
        # frame; counted, it made `replay --realtime --fail-on-trip` fail at random on clean logs).
        if event.get("event") == "trip" and not (
            event.get("reason") == "no_data" and self._starting(float(event.get("t", self.clock.now())))
        ):
            self.stats.trip_count += 1
            if len(self.stats.trips) < MAX_KEPT_TRIPS:
                self.stats.trips.append(event)
            if self.metrics is not None:
                self.metrics.trip(str(event.get("node", "")))
        self._event(event)

    def _event(self, event: dict[str, Any]) -> None:
        if "t" not in event:
            event = {"t": self.clock.now(), **event}
        self.events_seen[str(event.get("event"))] += 1
        if self.events is not None:
            self.events.write(event)
            self._dirty = True
        if self.extra_on_event is not None:
            self.extra_on_event(event)

    def _flush(self) -> None:
        if self._dirty and self.durable and self.events is not None:
            self.events.flush()
            self._dirty = False

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
        a plain candump block (:class:`~canguard.io.logs.Columns`) of one channel whose
        timestamps never go back is then worked on as columns: only its configured rows
        become frames, and its other rows are looked at only where a tick falls due among
        them (a bisection over the block's timestamps).
        """
        cursor = _LogCursor(route, default_bus, unmapped, channels)
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

    def _run_columns(self, cols: Columns, cursor: _LogCursor) -> bool:
        """:meth:`run_log` over a plain candump block; False (nothing done) when it must go frame by frame."""
        if not cols.ordered or self.sample_hook is not None:
            return False
        ts = cols.ts
        n = cols.n
        if float(ts[0]) < cursor.last_t:
            return False  # back in time across blocks: the frame-by-frame rules count it
        channel = cols.channel
        if channel is None:
            return False
        bus = cursor.route.get(channel, cursor.default_bus)
        counters = self.decoder.per_bus.get(bus) if bus is not None else None
        if bus is not None and counters is None:
            return False
        if bus is None or counters is None:
            if cursor.channels is not None:
                cursor.channels[channel] = cursor.channels.get(channel, 0) + n
            cursor.unmapped[channel] = cursor.unmapped.get(channel, 0) + n
            return True
        first = 0
        if not cursor.started:
            self._run_frames((cols.frame(0),), cursor)  # the first frame is fed: it starts the engine's clock
            first = 1
        if cursor.channels is not None:
            cursor.channels[channel] = cursor.channels.get(channel, 0) + n - first
        handles = self._row_handles.get(bus)
        if handles is None:
            handles = self._row_handles[bus] = self._compile_rows(bus)
        rows = list(compress(range(n), map(handles.__contains__, cols.ids))) if handles else []
        if first and rows and rows[0] == 0:
            del rows[0]
        skipped = n - first - len(rows)
        last_row = rows[-1] if rows else -1  # the last row feed would see, passive or not
        passive = self._row_passive[bus]
        if passive and rows:
            rows = self._run_passive(passive, rows, cols)
        work: Iterable[tuple[int, float, Handle | None, str]] = ()
        if rows:
            # the configured rows' columns, picked in C
            pick = _picker(rows)
            work = zip(rows, map(float, pick(ts)), map(handles.__getitem__, pick(cols.ids)), pick(cols.data),
                       strict=True)
        feed = self.feed
        frame = cols.frame
        pos = first
        due = self._due  # handlers never change it; advance, feed and tick may
        for i, t, handle, text in work:
            if t >= due:
                self._cross(ts, pos, i)  # a tick falls due among the rows before this one, or at it
                if t >= self._due:
                    self.advance(t)
                due = self._due
            pos = i + 1
            edge = handle(text, t) if handle is not None else None
            if edge is None:
                feed(bus, frame(i))  # the general path: every case, and what the handlers must equal
                due = self._due
            elif edge:
                self._drive_clock(t)
                self.stats.edge_ticks += 1
                self.tick(self.clock.now())
                due = self._due
        self._cross(ts, pos, n)
        for h in self._row_flush[bus]:
            h()
        counters.frames += skipped
        counters.skipped += skipped
        self.stats.frames += skipped
        cursor.last_t = float(ts[-1])
        if last_row >= 0 and float(ts[last_row]) > self._last_frame_t:
            self._last_frame_t = float(ts[last_row])  # as frame by frame: the last row fed (not ts[-1])
        return True

    @staticmethod
    def _run_passive(passive: dict[str, Batch], rows: list[int], cols: Columns) -> list[int]:
        """Take the rows of messages nobody reads between ticks as whole batches; return the rows left to go one by one.

        Runs before any row of the block: a batch stores its message's state as at the
        end of the block, which every tick in the block reads exactly as it would have
        read the row-by-row state (see :func:`canguard.engine.rows.compile_passive`).
        """
        ids = cols.ids
        left: list[int] = []
        # one list per passive message (shared by its id's spellings); rows dealt out in C
        lists: dict[Batch, list[int]] = {batch: [] for batch in set(passive.values())}
        to = {text: lists[batch] for text, batch in passive.items()}
        pick = _picker(rows)
        deque(map(list.append, map(to.get, pick(ids), repeat(left)), rows), maxlen=0)
        groups = {batch: group for batch, group in lists.items() if group}
        ts, data = cols.ts, cols.data
        back = False
        for batch, group in groups.items():
            pick = _picker(group)
            if not batch(pick(ts), pick(data)):
                left.extend(group)
                back = True
        if back:
            left.sort()
        return left

    def _cross(self, ts: list[str], lo: int, hi: int) -> None:
        """Rows ``lo..hi-1`` (ordered, of no configured message): the first at or after the due time brings the ticks.

        What :meth:`feed` does for such a frame, without decoding it; repeated while
        another due time falls among the rows left.
        """
        while lo < hi and float(ts[hi - 1]) >= self._due:
            k = bisect_left(ts, self._due, lo, hi, key=float)
            t = float(ts[k])
            self.advance(t)
            self._drive_clock(t)
            self._last_frame_t = t  # as feed: not before it (ordered, from cursor.last_t on)
            lo = k + 1

    def _compile_rows(self, bus: str) -> dict[str, Handle | None]:
        """Every id text (any letter case) of a message configured on ``bus``, with its row handler or None."""
        from canguard.engine.rows import compile_passive, compile_row
        from canguard.io.logs import candump_id_texts

        counters = self.decoder.per_bus[bus]
        handles: dict[str, Handle | None] = {}
        flushes = self._row_flush.setdefault(bus, [])
        passive = self._row_passive.setdefault(bus, {})
        # the stop confirmation reads its source between ticks: not passive
        readers = set(self.ctx.read_sources)
        if self.cfg.stop.confirm is not None:
            readers.add(self.cfg.stop.confirm.source)
        for (b, cid, ext), entry in self.decoder.entries():
            if b != bus:
                continue
            handler = compile_row(entry, counters, self.ctx, self.stats)
            if handler is not None:
                flushes.append(handler.flush)
            batch = compile_passive(entry, counters, self.ctx, self.stats, readers) if self.metrics is None else None
            for text in candump_id_texts(cid, ext):
                handles[text] = handler.handle if handler is not None else None
                if batch is not None:
                    passive[text] = batch
        return handles


def _picker(rows: list[int]) -> Callable[[Sequence[Any]], tuple[Any, ...]]:
    """``itemgetter(*rows)`` that gives a tuple for one row too (itemgetter then gives the bare value)."""
    if len(rows) == 1:
        only = rows[0]
        return lambda seq: (seq[only],)
    return itemgetter(*rows)


@dataclass
class _LogCursor:
    """Where :meth:`Engine.run_log` is in a log: routing, counts, the latest time."""

    route: Mapping[str, str]
    default_bus: str | None
    unmapped: dict[str, int]
    channels: dict[str, int] | None
    last_t: float = -math.inf
    started: bool = False
