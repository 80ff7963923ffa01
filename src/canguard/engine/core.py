"""The engine: frames -> decode -> protection models -> blackboard -> tree -> frames out.

One engine for the daemon and for replay: only the frames' source and the clock differ. The tree ticks
on a grid of ``1 / tick_hz`` (ticks due before a frame run first, at their own times) and at once at an
edge (a sample that changed a model's state: a trip reaches the bus without waiting for the next period);
the gate's deadlines run at their own times between ticks. A gap longer than ``MAX_CATCH_UP_S`` is not
ticked through: the grid jumps forward and the jump is counted.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import py_trees

from canguard.bt.context import Context, FrameSink
from canguard.config.schema import Config
from canguard.decode.decoder import Decoder
from canguard.engine.gate import TaskGate
from canguard.engine.logrun import MAX_CATCH_UP_S, LogCursor, LogRun
from canguard.engine.quiet import QuietTicks
from canguard.engine.stats import EngineStats, EventSink, Journal, TickObserver
from canguard.io.block import Block
from canguard.io.clock import Clock, PinnedClock
from canguard.protect.base import LatchedModel

if TYPE_CHECKING:
    from canguard.bt.loaded import GuardView

log = logging.getLogger(__name__)

MAX_KEPT_TRIPS = 100_000
"""Trip events kept in memory for summaries and the live view; later ones are only counted."""

CAN_ERR_CRTL = 0x004
"""linux/can/error.h: the error class of controller problems (the state is in data[1])."""
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40
"""The controller is back to error-active."""

_NO_ROUTE: Mapping[str, str] = MappingProxyType({})
"""The live cursor's route while a block is given for one bus: every frame goes to that bus."""


class Engine:
    """Runs one config's tree over frames from any source, on any clock; stale sources, buses down and a
    receive queue behind each hold the task stopped (an inhibit of the gate), whatever the tree says."""

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
        # the node library pulls in py_trees' parser
        from canguard.bt.checks import halt_ahead, require_guard_coverage
        from canguard.bt.loader import load_tree

        if cfg.tree is None:
            from canguard.errors import ConfigError

            raise ConfigError(f"{cfg.path}: tree: missing, expected {{file: TREE.xml, main: ID, tick_hz: HZ}}")
        self.cfg = cfg
        self.clock = PinnedClock(clock)
        self.drive_clock: Callable[[float], None] = clock.advance_to
        """Replay: a frame at ``t`` moves the clock (live clocks ignore it); called per frame, so bound once."""
        self.due = -math.inf
        """Earliest time a tick or gate deadline is due: a frame before it changes nothing but the models."""
        clock = self.clock
        self.sink = sink
        self.journal = Journal(clock.now, events, durable=durable, on_event=on_event)  # the daemon's events too
        self.metrics = metrics
        self.heat = heat
        self.save_heat = save_heat
        """False: heat is only restored from the state file, never written (replay reads, never mutates)."""
        self.sample_block: Callable[[Any, list[Any], list[tuple[int, Any]]], None] | None = None
        """Called once a block with every sample the models see (``--export-signals``, plots): the block's times,
        each message's ((source, signal) names, rows, decoded values) and the frame decoder's (row, sample)s."""
        self.observer: TickObserver | None = None  # told after every tick (the live monitors)
        self.stats = EngineStats()
        self.decoder = Decoder(cfg)
        self.ctx = Context(clock, cfg.sources, sink=sink, actions=cfg.actions, on_event=self._node_event,
                           stop_frames=cfg.stop.frames)
        self.stats.heat_models = self.ctx.heat_models  # the I²t peaks are the models' own
        if previous is not None:
            # A reload: sources configured as before keep their data (the new tree must not start blind).
            for name, health in previous.ctx.health.items():
                if previous.ctx.sources.get(name) == self.ctx.sources.get(name):
                    self.ctx.health[name] = health
        self.gate = TaskGate(cfg.task, cfg.stop, sink, health=self.ctx.health, on_event=self._gate_event)
        self.ctx.task = self.gate
        self.loaded = load_tree(cfg.tree.file, self.ctx, cfg.tree.main)
        require_guard_coverage(self.loaded)
        self.root: py_trees.behaviour.Behaviour = self.loaded.root
        self._guards = self.loaded.guards()
        self.guard_nodes = self.loaded.guard_nodes()  # in tree order
        self.gate.explain = self._explain
        from canguard.bt.nodes.actions import assign_roles

        self.gate.tree_has_task = assign_roles(self.root)
        self.gate.halts_next = halt_ahead(self.loaded)
        ages = [s.max_age_s for s in cfg.sources.values()]
        self._gap_horizon_s = max(ages, default=0.0) + MAX_CATCH_UP_S
        """How much of a gap is ticked through before the rest is jumped: every source goes stale in it."""
        self.period_s = 1.0 / cfg.tree.tick_hz
        read = [cfg.sources[s].max_age_s for s in self.ctx.read_sources if s in cfg.sources]
        self.start_grace_s = max(read, default=0.0)
        """How long after the start a failing tree only keeps the task from starting (:meth:`starting`)."""
        self.started_at = math.nan
        self.stale: dict[str, str] = {}  # each source's reason as the last tick saw it ("" fresh)
        self._cover: list[Any] = []
        """The guards ticked when the task last started: they must keep being ticked (:meth:`_guards_ticked`)."""
        self.quiet = QuietTicks(self.root, self.ctx, self.gate, self.journal, self)
        self.next_tick_t = math.nan  # NaN before the start
        self._heat_failed = False
        self.last_frame_t = -math.inf  # the latest frame time seen
        self.first_frame_t = math.nan
        self.last_status = py_trees.common.Status.INVALID
        self.last_tick_t = math.nan
        self.last_due_run = -math.inf
        """The time of the last tick or gate deadline run (which row brought it: :meth:`_cross`)."""
        self._blocks = LogRun(self)
        self._live = LogCursor(_NO_ROUTE, None, {}, None)  # where :meth:`take` is
        self._bus_names = {name: name for name in cfg.buses}  # the route of :meth:`take` of None

    @property
    def events_seen(self) -> Counter[str]:
        """How many events of each name were written (summaries count escalations...)."""
        return self.journal.seen

    def listen(self, fn: Callable[[dict[str, Any]], None]) -> None:
        """Also call ``fn`` with every event (plots, exports, the demo's view), before the listeners until now."""
        previous = self.journal.on_event
        if previous is None:
            self.journal.on_event = fn
            return

        def both(ev: dict[str, Any]) -> None:
            fn(ev)
            previous(ev)

        self.journal.on_event = both

    def frame_time(self, t: float) -> None:
        """A frame at ``t`` was taken: the latest frame time moves (the first one is :attr:`first_frame_t`)."""
        if t > self.last_frame_t:
            if self.last_frame_t == -math.inf:
                self.first_frame_t = t
            self.last_frame_t = t

    # -- life cycle ------------------------------------------------------------------------
    def start(self, now: float | None = None) -> None:
        """Begin: the first tick is due at once; heat is restored from the state file."""
        t = self.clock.now() if now is None else now
        self.clock.advance_to(t)
        self.started_at = t
        self.next_tick_t = t
        if self.heat is not None:
            self.heat.load(t)
            for key, model in self.ctx.heat_models.items():
                self.heat.restore(key, model, t)
        tree = self.cfg.tree
        source = tree.file.name if tree else ""
        self.journal.write({"event": "start", "reason": f"tree {self.loaded.main_id} from {source}"})

    def adopt(self, old: Engine) -> None:
        """Take over a running engine's task state, counters, sources' reasons and start (config reload)."""
        self.gate.adopt(old.gate)
        self._carry_models(old)
        self.stats.trips = old.stats.trips
        self.stats.trip_count = old.stats.trip_count
        self.stats.frames = old.stats.frames
        self.stale = dict(old.stale)
        self.started_at = old.started_at
        self.first_frame_t = old.first_frame_t
        self.last_frame_t = old.last_frame_t
        self.due = min(self.next_tick_t, self.gate.next_deadline())

    def _carry_models(self, old: Engine) -> None:
        """Each guard of the new tree (same node name, type and source as an old one) keeps its new parameters and
        takes over the old model's running state (:meth:`LatchedModel.carry_from`): a trip, a running timer, an
        inrush window, I²t heat. Without it a reload that changed a threshold restarted the guard cold."""
        old_guards = {g.name: g for g in old.guard_nodes}
        for guard in self.guard_nodes:
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
        self.store_heat(now, periodic=False)
        self.journal.write({"event": "exit", "reason": reason})
        self.journal.flush()

    # -- frames in -------------------------------------------------------------------------
    def take(self, bus: str | None, block: Block) -> None:
        """Process a block of frames received on ``bus``, in order: the one way frames come in (:class:`LogRun`).
        ``bus`` None: each frame's ``channel`` names its bus (a batch drained from several buses)."""
        cursor = self._live
        if bus is None:
            cursor.route, cursor.default_bus = self._bus_names, None
        else:
            cursor.route, cursor.default_bus = _NO_ROUTE, bus
        self._blocks.take(block, cursor)

    def edge_tick(self, t: float) -> None:
        """A sample at ``t`` changed a model's or a source's state: the tree ticks at once."""
        self.drive_clock(t)
        self.stats.edge_ticks += 1
        now = self.clock.now()
        self.gate.ahead(now)  # a tick that surely halts the task: the stop frames leave first
        self.tick(now)

    def runs_until(self, end_t: float, coming: Callable[[], Mapping[tuple[int, str], Any]]) -> float:
        """Until when a block's rows, the last at ``end_t``, may be taken as runs, the engine idle: the next due
        time, or the end of the quiet ticks the rows still to come keep the sources fresh to (``coming()``:
        :meth:`QuietTicks.reach`). That needs nothing watching each tick, no model state written by a skipped
        tick, no stop waiting for its confirmation (it reads a source between ticks) and no heat save due (a
        save writes the heat of its tick's time). An edge in the runs still ticks at once."""
        due = self.due
        if end_t < due:
            return due
        quiet = self.quiet
        if (self.metrics is None and self.observer is None and not quiet.writes
                and not self.gate.confirm_pending and quiet.may_skip(self.next_tick_t) and quiet.until > due):
            until = quiet.until if quiet.until > end_t else quiet.reach(coming())
            if self.heat is not None and self.save_heat and self.ctx.heat_models:  # a save due at a tick
                until = min(until, float(self.heat.next_save_t(self.cfg.state.save_period_s)))
            return max(due, until)
        return due

    def next_due(self) -> float:
        """The next time the engine has something to do (a tick or a gate deadline)."""
        if math.isnan(self.next_tick_t):
            return -math.inf
        return min(self.next_tick_t, self.gate.next_deadline())

    def advance(self, now: float) -> None:
        """Run every tick and gate deadline due up to ``now``, each at its own time."""
        if now < self.due:  # nothing due (due is never later than the next tick or gate deadline): most live calls
            self.journal.flush()
            return
        if math.isnan(self.next_tick_t):
            self.start(now)
        if now - self.next_tick_t > MAX_CATCH_UP_S:
            # A gap: tick through its beginning, where sources go stale and guards trip at their
            # own times (max_age after the last frame); then jump the quiet rest of it.
            self._run_due(min(now, self.next_tick_t + self._gap_horizon_s))
            missed = math.floor((now - self.next_tick_t - MAX_CATCH_UP_S) / self.period_s)
            if missed > 0:
                self.next_tick_t += missed * self.period_s
                self.stats.skipped_ticks += missed
                # The gate's periodic frames skip the gap too: sent one by one, a day-long gap in a
                # log was millions of task frames (a replay that never ended).
                self.gate.skip_to(self.next_tick_t)
        self._run_due(now)
        self.due = min(self.next_tick_t, self.gate.next_deadline())
        self.journal.flush()

    def _run_due(self, now: float) -> None:
        """Every tick and gate deadline due up to ``now``, in time order, each at its own time."""
        while True:
            due_gate = self.gate.next_deadline()
            due = min(self.next_tick_t, due_gate)
            if due > now:
                break
            self.clock.advance_to(due)
            self.last_due_run = due
            if self.next_tick_t <= due_gate:
                if not self.quiet.may_skip(due):
                    self.tick(due)
                    self.next_tick_t += self.period_s
                else:
                    self._count_quiet(due, 1)
                    self.next_tick_t += self.period_s
                    self._quiet_run(now, due_gate)  # the quiet ticks after it, in one go
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
        events_before = self.journal.written
        # Sources first: a stale one holds the task before the tree runs, and one that is fine
        # again releases it in time for this tick's ExecuteTask.
        self._sources(now)
        self.gate.begin_tick()
        t0 = time.perf_counter()
        try:
            # BT.CPP's tickOnce (re-ticked while a wake-up is pending, bounded); SKIPPED: INVALID, neither stop
            # nor task; with quiet ticks, which nodes the tick reached
            status = self.quiet.tick_root(self.loaded)
        except Exception as exc:  # a node that raises must stop the task, not the daemon
            self.stats.tick_errors += 1
            log.exception("tree tick failed")
            self.journal.write({"event": "error", "reason": f"tree tick raised {type(exc).__name__}: {exc}"})
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
            if not self.starting(now):
                detail = tip.feedback_message if tip is not None else ""
                self.gate.stop(now, reason=f"tree failed at {node}" + (f": {detail}" if detail else ""), node=node)
            cause = self._failure_cause(node)
        # The one place a stop may end (TaskGate._release_rule), and task action frames go out or are withheld.
        was_running = self.gate.state == TaskGate.RUNNING
        self.gate.end_tick(now, failed, cause)
        self._guards_ticked(now, was_running)
        if self.metrics is not None:
            for node, model in self.ctx.heat_models.items():
                self.metrics.set_i2t_level(node, model.snapshot().level_pct)
        self.gate.service(now)
        self.store_heat(now, periodic=True)
        self.journal.flush()
        self.due = min(self.next_tick_t, self.gate.next_deadline())
        self.quiet.after_tick(now, events_before, self.metrics is not None or self.observer is not None)
        if self.observer is not None:
            self.observer.publish(self, now)
        return status

    # -- quiet ticks: counted, not run (canguard.engine.quiet has the proof) ---------------------
    def _quiet_run(self, now: float, until: float) -> None:
        """After a quiet tick: the grid ticks due up to ``now`` and before ``until`` (the gate's next deadline)
        counted in one go, by the same additions as one by one, while the task runs and no heat is saved."""
        gate = self.gate
        if gate.state != TaskGate.RUNNING or (self.heat is not None and self.save_heat):
            return
        counted = gate.counts_only
        nxt, period, last, count = self.next_tick_t, self.period_s, 0.0, 0
        # Task frames only counted (a replay without --emit): counted in one go below; else they end the run.
        quiet_until = self.quiet.until
        until = quiet_until if counted else min(until, quiet_until)
        while nxt <= now and nxt < until:
            last = nxt
            count += 1
            nxt += period
        if count:
            if counted:
                gate.count_task_through(last)
            self.clock.advance_to(last)
            self.last_due_run = last
            self.next_tick_t = nxt
            self._count_quiet(last, count)

    def _count_quiet(self, now: float, count: int) -> None:
        """``count`` quiet grid ticks, the last at ``now``."""
        gate = self.gate
        self.clock.pin(now)
        try:
            self.stats.ticks += count
            self.stats.quiet_ticks += count
            self.last_tick_t = now
            for g in self.quiet.ticked:
                g.quiet_retick(now)
            gate.service(now)
            self.store_heat(now, periodic=True)
            self.journal.flush()
            self.due = min(self.next_tick_t, gate.next_deadline())
        finally:
            self.clock.unpin()

    # -- heat ------------------------------------------------------------------------------
    def store_heat(self, now: float, periodic: bool = False) -> None:
        """Save I²t heat (``periodic``: when its period is due; else now); a failing save is an event, never a crash."""
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
                self.journal.write({"event": "error", "reason": f"cannot save I²t state: {exc}"})
            self._heat_failed = True
        else:
            self._heat_failed = False

    def _failure_cause(self, tip: str) -> tuple[str, str]:
        """(node, reason) of a failed tick, made of what only changes at an edge (a ``reason`` event marks a real
        change, not a new sample)."""
        failed = py_trees.common.Status.FAILURE
        first = next((g.name for g in self.guard_nodes if g.status == failed), "")
        if first:
            return first, self._explain()
        return tip, f"tree failed at {tip}"

    def _explain(self) -> str:
        """The guards that failed in this tick, with why (for stop events)."""
        failed = py_trees.common.Status.FAILURE
        return "; ".join(
            f"{g.name}: {g.feedback_message}" if g.feedback_message else g.name
            for g in self.guard_nodes if g.status == failed
        )

    def guards(self) -> list[GuardView]:
        """Every guarded signal of the tree (node, source, role, kind, model), in tree order."""
        return self._guards

    def status_line(self) -> str:
        """A one-line summary for systemd's STATUS=."""
        d = self.decoder
        return (f"task {self.gate.state}; tree {self.last_status.value}; stops {self.gate.stops}; "
                f"trips {self.stats.trip_count}; frames {self.stats.frames} decoded {d.decoded} "
                f"invalid {d.invalid}")

    # -- events ----------------------------------------------------------------------------
    def _gate_event(self, event: str, now: float, **fields: Any) -> None:
        self.journal.write({"t": now, "event": event, **fields})

    def _node_event(self, event: dict[str, Any]) -> None:
        """An event of a tree node (a guard's trip, recovery...): trips are counted for the summaries."""
        # A guard failing for "no_data" in the start window (:meth:`starting`) only keeps the task from
        # starting: journalled, not a trip (the daemon's first tick often precedes the first frame).
        if event.get("event") == "trip" and not (
            event.get("reason") == "no_data" and self.starting(float(event.get("t", self.clock.now())))
        ):
            self.stats.trip_count += 1
            if len(self.stats.trips) < MAX_KEPT_TRIPS:
                self.stats.trips.append(event)
            if self.metrics is not None:
                self.metrics.trip(str(event.get("node", "")))
        self.journal.write(event)

    # -- the watch over inputs ------------------------------------------------------------------
    def starting(self, now: float) -> bool:
        """True while the task never ran and the sources still have their first max_age to speak: a tree that
        fails then only keeps the task from starting (stop frames to drives never enabled would latch an ESTOP
        error that needs clearing)."""
        return self.gate.state == TaskGate.IDLE and now - self.started_at < self.start_grace_s

    def _sources(self, now: float) -> None:
        """At a tick: each source's reason; a source the tree reads holds the task while it is stale."""
        ctx, gate = self.ctx, self.gate
        for name, health in ctx.health.items():
            reason = health.reason(now)
            if reason == "no_data" and now - self.started_at < ctx.sources[name].max_age_s:
                reason = ""  # not yet: every source gets max_age to send its first frame
            prev = self.stale.get(name, "")
            if name in ctx.read_sources:
                # Backstop, whatever the tree's shape: a stale source the tree reads holds the task stopped.
                if reason:
                    gate.inhibit(f"source {name}", f"source {name}: {reason}", now)
                elif prev:
                    gate.release(f"source {name}")
            if reason != prev:
                self.stale[name] = reason
                if reason:
                    self.journal.write({"event": "stale", "source": name, "reason": reason,
                                        "read_by_tree": name in ctx.read_sources})
                else:
                    self.journal.write({"event": "fresh", "source": name, "reason": f"{prev} cleared"})
            if self.metrics is not None:
                self.metrics.set_sample_age(name, health.age(now))

    def _guards_ticked(self, now: float, was_running: bool) -> None:
        """Safety row T4: a guard not ticked for its source's ``max_age`` (a period at least) while the task runs
        (a RunOnce around it, a branch left) holds the task stopped (inhibit ``guards``) until all are again."""
        gate = self.gate
        if gate.state == TaskGate.RUNNING and not was_running:
            self._cover = list(self.guard_nodes)
        left = [
            g for g in self._cover
            if g.source is not None and now - g.judged_t > max(g.source.max_age_s, self.period_s)
        ]
        if left and gate.state == TaskGate.RUNNING:
            names = ", ".join(g.name for g in left)
            gate.inhibit("guards", f"guards not ticked while the task runs: {names}", now, node=left[0].name)
        elif "guards" in gate.inhibits and all(g.judged_t == now for g in self._cover):
            gate.release("guards")

    def _inhibit(self, key: str, reason: str, event: dict[str, Any]) -> None:
        """Journal ``event`` and hold the task stopped for ``key`` (the stop frames leave before the event is
        recorded); the gate's deadlines are read again."""
        self.journal.write(event)
        self.gate.inhibit(key, reason, self.clock.now())
        self.journal.flush()
        self.due = min(self.due, self.gate.next_deadline())

    def bus_down(self, bus: str, reason: str) -> None:
        """A bus went away: the task stops (frames out on the buses still up) until :meth:`bus_up`."""
        event = {"event": "bus_error", "source": bus, "reason": reason}
        self._inhibit(f"bus {bus}", f"bus {bus} down: {reason}", event)

    def bus_up(self, bus: str) -> None:
        """The bus is open again: its inhibits are released (the tree decides whether the task resumes)."""
        self.gate.release(f"bus {bus}")
        self.gate.release(f"bus {bus} passive")  # a reopened controller starts error-active

    def controller_state(self, bus: str, frame: Any) -> None:
        """An error frame's controller report (``CAN_ERR_CRTL``): error-passive (our stop frames may not get
        through) holds the task (inhibit ``bus NAME passive``) until error-active again or the bus reopens."""
        if not frame.arbitration_id & CAN_ERR_CRTL or len(frame.data) < 2:
            return
        state = frame.data[1]
        key = f"bus {bus} passive"
        if state & (CAN_ERR_CRTL_RX_PASSIVE | CAN_ERR_CRTL_TX_PASSIVE):
            if key not in self.gate.inhibits:
                side = "/".join(s for s, bit in (("rx", CAN_ERR_CRTL_RX_PASSIVE), ("tx", CAN_ERR_CRTL_TX_PASSIVE))
                                if state & bit)
                reason = f"bus {bus}: controller error-passive ({side}): frames may not get through"
                self._inhibit(key, reason, {"event": "bus_error", "source": bus, "reason": reason})
        elif state & CAN_ERR_CRTL_ACTIVE and key in self.gate.inhibits:
            again = f"bus {bus}: controller error-active again"
            self.journal.write({"event": "bus_error", "source": bus, "reason": again})
            self.gate.release(key)

    def overrun(self, waited_s: float, limit_s: float) -> None:
        """Frames waited ``waited_s`` in the receive queue (safety row H2b: old data judged fresh): the task is
        held stopped (inhibit ``overrun``) until :meth:`caught_up`."""
        if "overrun" not in self.gate.inhibits:
            reason = (f"frames waited {waited_s:.3f} s in canguard's receive queue (limit {limit_s:.3f} s): "
                      "the daemon is behind its buses")
            self._inhibit("overrun", reason, {"event": "overrun", "reason": reason})

    def caught_up(self, waited_s: float) -> None:
        """Frames wait no more than ``waited_s`` again: the ``overrun`` inhibit is released."""
        if "overrun" not in self.gate.inhibits:
            return
        self.journal.write({"event": "overrun", "reason": f"caught up: frames wait {waited_s:.3f} s"})
        self.gate.release("overrun")
        self.journal.flush()

    def stale_unstopped(self, now: float) -> list[str]:
        """Sources the tree reads that are stale while the task is not stopped (a blind daemon)."""
        if self.gate.state == TaskGate.STOPPED:
            return []
        return [s for s in self.ctx.read_sources if self.ctx.health[s].reason(now)]

    # -- recorded logs -----------------------------------------------------------------------
    def run_log(
        self, blocks: Iterable[Block], route: Mapping[str, str], default_bus: str | None,
        unmapped: dict[str, int], channels: dict[str, int] | None = None,
    ) -> None:
        """Take a recorded log's blocks, each channel routed to a bus, through :class:`LogRun` (as :meth:`take`)."""
        self._blocks.run(blocks, route, default_bus, unmapped, channels)
