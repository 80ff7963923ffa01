"""``canguard run``: the live engine, as a systemd service.

The loop and what it tells systemd: docs/deploy.md."""

from __future__ import annotations

import dataclasses
import gc
import logging
import math
import os
import queue
import signal
import sys
import threading
import time
import uuid
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import can
import numpy as np
import py_trees
from py_trees.blackboard import Blackboard

from canguard.bt.context import FrameSink
from canguard.config.monitor import with_overrides
from canguard.config.schema import Config
from canguard.engine.core import Engine
from canguard.engine.events import EventJournal
from canguard.engine.gate import BusSink, TaskGate
from canguard.engine.ratelimit import held_note
from canguard.engine.stats import EventSink
from canguard.errors import CanguardError, ConfigError
from canguard.io.block import Block
from canguard.io.bus import BusReader, receive_keys
from canguard.io.clock import BootClock, LiveClock
from canguard.io.outputs import check_config_outputs, load_run_config
from canguard.protect.state import HeatStore
from canguard.service.systemd import Notifier, watchdog_hold

log = logging.getLogger(__name__)

SWITCH_INTERVAL_S = 0.0005
"""GIL switch interval while the daemon runs: at Python's default 5 ms a frame a bus thread (or the monitor's)
received could wait that long for the loop."""

LIVE_SKEW_S = 0.5
"""A frame timestamp further than this from the daemon's clock is replaced by the receive time."""
OVERRUN_FLOOR_S = 0.05
"""The shortest wait between arrival and the engine that counts as falling behind (jitter is below it)."""
DRAIN = 512
"""Frames received after the first, at most, before the engine advances to now."""
DRAIN_DIRECT = 32
"""The same where the loop reads the sockets itself (a tripping frame waits for the reads after it in its batch)."""


def guarding(cfg: Config) -> str:
    """What the daemon guards, for STATUS= and the start log: ``guarding main (socketcan can0); 6 sources``."""
    buses = ", ".join(f"{name} ({b.interface} {b.channel})" if b.channel else f"{name} ({b.interface})"
                      for name, b in cfg.buses.items())
    return f"guarding {buses}; {len(cfg.sources)} sources" + ("; simulation" if cfg.simulation else "")


def refuse_unguarded(cfg: Config) -> None:
    """Under systemd, ConfigError for all-``virtual`` buses (READY=1 and a fed watchdog while guarding no motor),
    unless the config says ``simulation: true`` (a bench)."""
    if not os.environ.get("NOTIFY_SOCKET") or cfg.simulation or not cfg.buses:
        return
    if all(b.interface == "virtual" for b in cfg.buses.values()):
        names = ", ".join(cfg.buses)
        raise ConfigError(f"{cfg.path}: buses: every bus ({names}) is interface: virtual, so this service would guard "
                          "no real bus while systemd reports it healthy. For the robot set interface: socketcan and "
                          "channel: can0 (see docs/deploy.md); to run a simulation as a service on purpose, add "
                          "'simulation: true' to the config")


class Daemon:
    """Owns the buses, the journal, the engine and the signals of one ``canguard run``."""

    refuse_virtual = True
    """``canguard run`` refuses all-virtual buses under systemd; the realtime replay bench does not."""
    watch = True
    """The config's ``monitor:`` is served; the realtime replay bench serves none."""
    filters = True
    """Each bus receives the frames the config reads (``filter:``); the realtime replay bench counts every frame."""

    def __init__(self, config_path: Path, *, metrics_addr: str | None = None,
                 notifier: Notifier | None = None, cfg: Config | None = None, state_dir: Path | None = None,
                 http: str | None = None, groot2: str | None = None) -> None:
        self.config_path = config_path
        self.state_dir = state_dir
        """``--state-dir``: the journal and the I²t state file go there, at start and at every reload."""
        self.cfg: Config = cfg if cfg is not None else load_run_config(config_path, state_dir)
        if self.refuse_virtual:
            refuse_unguarded(self.cfg)
        check_config_outputs(self.cfg)
        self.clock = LiveClock()
        self.notifier = notifier if notifier is not None else Notifier()
        self.metrics: Any = None
        if metrics_addr:
            from canguard.service.metrics import Metrics

            self.metrics = Metrics()
            self.metrics.start(metrics_addr)
        self.journal = EventJournal(self.cfg.events, sync_in_background=True)  # the loop never waits for a disk
        self.events: EventSink = self.journal
        self.monitor: Any = None
        """The status page / Groot2 monitor (:mod:`canguard.service.monitor`, imported only when configured)."""
        watched = with_overrides(self.cfg.monitor, http=http, groot2=groot2)  # --http / --groot2
        if self.watch and (watched.http or watched.groot2):
            from canguard.service.monitor import Monitor

            self.monitor = self.events = Monitor(watched, self.journal)
        self._stop = threading.Event()
        self._reload = threading.Event()
        self._published_at = time.monotonic()
        self._counts: dict[str, tuple[int, int, int]] = {}
        """Per bus, the decoder's (frames, decoded, invalid) at the last STATUS=."""
        self._down: set[str] = set()
        self._watchdog_held = ""
        self._bus_errors: queue.SimpleQueue[tuple[str, str]] = queue.SimpleQueue()
        self.exit_reason = "exit"
        self.reader = BusReader(self.cfg.buses, on_error=self._bus_error, direct=True, wanted=self.wanted(self.cfg))
        self.sink: FrameSink = BusSink(
            self.reader.send, on_error=self.metrics.send_error if self.metrics is not None else None,
            on_refused=self._send_refused,
        )
        try:
            self.engine = self.build_engine(self.cfg)
        except BaseException:
            if self.monitor is not None:
                self.monitor.close()
            self.journal.close()  # and its sync thread
            raise
        self.overrun_limit_s = overrun_limit(self.cfg)
        """A frame that waited longer since it arrived stops the task (:meth:`Engine.overrun`)."""
        self.setup: Any = None
        """The CANopen drives canguard configures over SDO (:mod:`canguard.service.canopen_setup`), when any."""

    def build_engine(self, cfg: Config, previous: Engine | None = None) -> Engine:
        heat = HeatStore(cfg.state.file, cfg.state.on_corrupt, clock=BootClock())
        before = set(Blackboard.clients)
        try:
            engine = Engine(cfg, self.clock, self.sink, events=self.events, durable=True,
                            metrics=self.metrics, heat=heat, previous=previous)
            if self.monitor is not None:
                self.monitor.attach(engine)
            return engine
        except BaseException:
            release_clients(set(Blackboard.clients) - before)  # a tree built half-way leaves no keys behind
            raise

    def wanted(self, cfg: Config) -> dict[str, frozenset[int] | None]:
        """Per bus, the id keys of the frames received (:func:`~canguard.io.bus.receive_keys`; None: every frame)."""
        return receive_keys(cfg) if self.filters else {}

    # -- signals ---------------------------------------------------------------------------
    def install_signals(self) -> None:
        """SIGTERM / SIGINT stop the daemon cleanly; SIGHUP reloads the config."""
        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, lambda num, _frame: self.request_stop(signal.Signals(num).name))
        signal.signal(signal.SIGHUP, lambda _num, _frame: self._reload.set())

    def request_stop(self, reason: str = "stop requested") -> None:
        """Ask the loop to end (tests, the demo)."""
        self.exit_reason = reason
        self._stop.set()

    # -- the loop --------------------------------------------------------------------------
    def run(self, duration_s: float | None = None) -> int:
        """Run until SIGTERM (or ``duration_s``); returns the exit code. What start built (engine, tree, DBC) is
        collected once and frozen out of the collector's walks: a full collection in the loop then walks only
        what came after (one took 13-20 ms, in the middle of whatever frame's allocation tripped it)."""
        gc.collect()  # before any bus is open: no frame waits for it
        gc.freeze()
        try:
            return self._run(duration_s)
        finally:
            gc.unfreeze()

    def _run(self, duration_s: float | None) -> int:
        engine = self.engine
        if self.monitor is not None:
            self.monitor.start()
        self.reader.start()
        engine.start(self.clock.now())
        self.setup = drive_setup(self.cfg)
        self.notifier.ready()
        log.info("%s", guarding(self.cfg))
        self.notifier.status(f"running: {engine.status_line()}; {guarding(self.cfg)}")
        wd_interval = self.notifier.watchdog_interval_s()
        next_wd = 0.0
        next_status = time.monotonic() + 1.0
        end = time.monotonic() + duration_s if duration_s is not None else math.inf
        receive = self.reader.receive
        batch = DRAIN_DIRECT if self.reader.direct else DRAIN + 1
        previous_switch = sys.getswitchinterval()
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        try:
            while not self._stop.is_set() and time.monotonic() < end:
                engine = self.engine
                now = self.clock.now()
                items = receive(min(max(0.0, engine.next_due() - now), 0.05), batch)
                if items:
                    self.take_received(engine, items)
                engine.advance(self.clock.now())
                self._watch_buses(engine)
                if self.setup is not None:
                    journal_setup(engine, self.setup)
                mono = time.monotonic()
                if wd_interval is not None and mono >= next_wd and self._watchdog_ok(engine):
                    self.notifier.watchdog()
                    next_wd = mono + wd_interval / 4
                if mono >= next_status:
                    self._publish(engine, mono)
                    next_status = mono + 1.0
                if self._reload.is_set():
                    self._reload.clear()
                    self.reload()
        finally:
            sys.setswitchinterval(previous_switch)
            self.notifier.stopping()
            self.engine.finish(reason=self.exit_reason)
            if self.setup is not None:
                self.setup.stop()
            self.reader.stop()
            self.journal.close()
            if self.monitor is not None:
                self.monitor.close()
        return 0

    def _publish(self, engine: Engine, mono: float) -> None:
        """Once a second: STATUS= with state, trips and frame rates; counters to the metrics."""
        dt = max(1e-3, mono - self._published_at)
        self._published_at = mono
        fps = []
        for bus, c in engine.decoder.per_bus.items():
            counts = (c.frames, c.decoded, c.invalid)
            last = self._counts.get(bus, (0, 0, 0))
            if c.frames < last[0]:  # a reload started a fresh decoder
                last = (0, 0, 0)
            self._counts[bus] = counts
            fps.append(f"{bus} {(c.frames - last[0]) / dt:.0f} fps")
            if self.metrics is not None:
                self.metrics.frames(bus, *(n - m for n, m in zip(counts, last, strict=True)))
        if self.metrics is not None:
            self.metrics.set_stop_state(engine.gate.state == TaskGate.STOPPED)
        self.notifier.status(f"{engine.status_line()}; {', '.join(fps)}; {guarding(self.cfg)}")

    def take_received(self, engine: Engine, items: list[tuple[str, can.Message, float]]) -> None:
        """The messages received, one block in arrival order into :meth:`Engine.take`, cut where a frame's wait starts
        or ends an overrun; a stamp further than :data:`LIVE_SKEW_S` from now becomes the receive time."""
        mono = time.monotonic()
        now = self.clock.now()
        limit = self.overrun_limit_s
        names, msgs, arrivals = zip(*items, strict=True)
        target: str | None = names[0]
        if names.count(target) != len(names):
            target = None  # several buses in one block: each row's channel names its bus
        block = Block.of_messages(msgs, names if target is None else target)
        stamps = block.times
        sane = min(stamps) >= now - LIVE_SKEW_S and max(stamps) <= now + LIVE_SKEW_S
        if sane and not mono - min(arrivals) > limit and "overrun" not in engine.gate.inhibits:
            engine.take(target, block)  # the usual batch (no overrun starts, stamps sane): one block
            return
        if not sane:  # insane stamps: the receive time (a NaN stamp is kept)
            times = block.time_s
            block = dataclasses.replace(block, time_s=np.where(np.abs(times - now) > LIVE_SKEW_S, now, times))
        start = 0
        for i, received in enumerate(arrivals):
            waited = mono - received
            held = "overrun" in engine.gate.inhibits
            behind = not held and waited > limit  # its data is older than the config allows
            back = held and waited < limit / 2
            if i > start and (behind or back):
                engine.take(target, block.select(slice(start, i)))
                start = i
            if behind:
                engine.overrun(waited, limit)
            elif back:
                engine.caught_up(waited)
        engine.take(target, block.select(slice(start, None)))

    def _watchdog_ok(self, engine: Engine) -> bool:
        now = self.clock.now()
        last = None if math.isnan(engine.last_tick_t) else engine.last_tick_t
        held = watchdog_hold(now, last, engine.period_s, engine.stale_unstopped(now), k=4.0)
        if held and held != self._watchdog_held:
            log.warning("watchdog ping held back: %s", held)
        self._watchdog_held = held
        return not held

    # -- reload and errors ------------------------------------------------------------------
    def reload(self) -> bool:
        """Load the config and tree again; keep the running ones when the new ones are bad."""
        self.notifier.reloading()
        try:
            cfg = load_run_config(self.config_path, self.state_dir)  # its outputs in --state-dir, when given
            if dict(cfg.buses) != dict(self.cfg.buses):
                raise CanguardError("buses changed: a bus change needs a restart (systemctl restart canguard)")
            new = self.build_engine(cfg, previous=self.engine)
        except (CanguardError, OSError, ValueError) as exc:
            log.error("reload rejected, keeping the running config: %s", exc)
            self.engine.journal.write({"event": "error", "reason": f"reload rejected: {exc}"})
            self.engine.journal.flush()
            self.notifier.ready()
            return False
        old = self.engine
        now = self.clock.now()
        if dict(cfg.canopen) != dict(self.cfg.canopen):  # drives told something else: tell them anew
            if self.setup is not None:
                self.setup.stop()
            self.setup = drive_setup(cfg)
        old.store_heat(now)  # the new guards start from the heat the old ones had
        self.cfg, self.engine = cfg, new
        self.reader.want(self.wanted(cfg))  # the new sources' frames from now on
        self.overrun_limit_s = overrun_limit(cfg)
        new.start(now)
        # The task's state, the sources' data and the counters carry over: a running task goes on
        # (the new tree judges it at its first tick), a stopped one stays stopped until it recovers.
        new.adopt(old)
        release_clients(tree_clients(old.root))  # py_trees' blackboard is global: drop the old tree's keys
        new.journal.write({"event": "reload", "reason": f"config {self.config_path} reloaded"})
        new.journal.flush()
        self.notifier.ready()
        return True

    def _send_refused(self, bus: str, label: str, origin: str, held: int) -> None:
        """A frame the bus refused (full TX queue, bus-off) into the journal, as often as on stderr (``held``: the
        refusals since): a stop frame that never reached the bus is what a safety engineer asks about first."""
        engine = getattr(self, "engine", None)
        if engine is not None:
            engine.journal.write({"event": "bus_error", "source": bus,
                                  "reason": f"send refused: {label} ({origin}); sent again at the next repeat"
                                            f"{held_note(held)}"})

    def _bus_error(self, bus: str, exc: BaseException) -> None:
        # from a receive thread, to the loop (which owns the journal); the reader reopens the bus with backoff
        self._bus_errors.put((bus, f"{type(exc).__name__}: {exc}"))

    def _watch_buses(self, engine: Engine) -> None:
        """The receive threads' bus errors into the engine; a reopened bus releases the task (the tree decides)."""
        while not self._bus_errors.empty():  # the loop is the one reader
            bus, text = self._bus_errors.get_nowait()
            engine.bus_down(bus, text)
            self._down.add(bus)
        if self._down:
            alive = self.reader.alive()
            for bus in [b for b in self._down if alive.get(b)]:
                self._down.discard(bus)
                engine.bus_up(bus)
                engine.journal.write({"event": "bus_error", "source": bus, "reason": "reopened"})


def drive_setup(cfg: Config) -> Any:
    """A started :class:`~.canopen_setup.DriveSetup` when a drive has ``configure: true``, else None."""
    if not any(d.configure for d in cfg.canopen.values()):
        return None
    from canguard.service.canopen_setup import DriveSetup

    setup = DriveSetup(cfg.canopen.values(), dict(cfg.buses))
    setup.start()
    return setup


def journal_setup(engine: Engine, setup: Any) -> None:
    """The drive configuration's events (``configure``, ``error``) into the journal, made durable at once."""
    events = setup.events()
    for event in events:
        engine.journal.write(event)
    if events:
        engine.journal.flush()


def overrun_limit(cfg: Config) -> float:
    """How long a frame may wait before the engine: the sources' shortest ``max_age`` (older data is stale)."""
    ages = [source.max_age_s for source in cfg.sources.values()]
    return max(OVERRUN_FLOOR_S, min(ages, default=LIVE_SKEW_S))


def tree_clients(root: py_trees.behaviour.Behaviour) -> set[uuid.UUID]:
    """The ids of the blackboard clients of the nodes under ``root`` (py_trees keeps a dropped tree's keys)."""
    return {client.id() for node in root.iterate() for client in node.blackboards}


def release_clients(ids: Iterable[uuid.UUID]) -> None:
    """Remove these clients, and the keys no other client holds, from py_trees' global blackboard."""
    ids = set(ids)
    for key, meta in list(Blackboard.metadata.items()):
        if ids.isdisjoint(meta.read) and ids.isdisjoint(meta.write) and ids.isdisjoint(meta.exclusive):
            continue
        meta.read -= ids
        meta.write -= ids
        meta.exclusive -= ids
        if not (meta.read or meta.write or meta.exclusive):
            del Blackboard.metadata[key]
            Blackboard.storage.pop(key, None)
    for client in ids:
        Blackboard.clients.pop(client, None)
