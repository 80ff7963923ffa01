"""Suite ``live``: the deployed daemon's trip-to-stop time beside the bus's own echo, and its ingest CPU per frame.

One ``canguard run`` process (the bundled config) on a udp_multicast group of this run's own; a
python-can echo process on the same group (the floor: the same two hops through the same sockets,
with nothing to decide); the peer in this process. Trials take turns, an echo round trip and then a
guard trial, so both meet the same machine. Linux hands a multicast datagram to the group's sockets
newest first, and on two cores the process woken second waits for a CPU behind the first: half the
trials run with the echo process joined after the daemon, half with the mirror order (:func:`rig`), so
neither gets the head start throughout (one order alone moved the echo's wake-up by ~25 µs p50 and the
daemon's by ~17-38 µs, the other way, 2026-11-29):

* **trip to stop**: a normal BMS frame, wait until the task frames resume, a random 0-3 ms pause (off
  the 10 ms tick grid), then a 40 A BMS frame, timed until the first ``Axis0_Estop`` arrives; the echo:
  a request frame until its reply. Without background traffic, and with ``FPS`` frames/s of ids no
  config uses from a process of its own;
* **ingest**: while that background runs, the daemon's CPU per frame received (``/proc``; its idle
  CPU per second, measured before, taken off), beside a process that only receives the same frames
  with python-can (``recv(0)`` until empty, every millisecond: python-can's cost of a frame, not of a
  wake-up; its count is the frames of the window: both read the same multicast datagrams). What
  canguard adds per frame, its wake-ups included, is the difference. Then a second window beside a
  python-can process that waits in ``recv`` for each frame, as a reader that must not lag does (the
  daemon must: the next frame may be the one that trips): what canguard adds to python-can's own
  receive at the same wake-ups;
* **a frame alone**: in a process of its own, the CPU of ``Engine.take`` per frame of a recorded log
  (examples/normal.log.gz on config/examples/robot_guard.yaml: each frame a block of one, as on a
  quiet bus), beside a plain cantools loop decoding the same frames' configured messages.
"""

from __future__ import annotations

import contextlib
import random
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import can
import cantools

from benchmarks import kit
from benchmarks.kit import Options, Table

BMS_ID = 0x18FF50E5
ESTOP0 = 0x02
SET_STATE0 = 0x07
CLOSED_LOOP = (8).to_bytes(4, "little")
ECHO_REQ, ECHO_REP = 0x7E0, 0x7E1

CHILD = """
import signal, sys, threading, time
import can
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *a: stop.set())
bus = can.Bus(interface="udp_multicast", channel={group!r}, port={port})
role, fps = {role!r}, {fps}
print("ready", flush=True)
n, cpu0 = 0, time.process_time()
if role == "echo":
    reply = can.Message(arbitration_id={rep}, data=bytes(8), is_extended_id=False)
    while not stop.is_set():
        msg = bus.recv(0.1)
        if msg is not None and msg.arbitration_id == {req}:
            bus.send(reply)
elif role == "background":
    msgs = [can.Message(arbitration_id=i, data=bytes(8), is_extended_id=False) for i in range(0x600, 0x680)]
    start = time.perf_counter()
    while not stop.is_set():
        due = int((time.perf_counter() - start) * fps)
        while n < due:
            bus.send(msgs[n % len(msgs)])
            n += 1
        time.sleep(0.001)
elif role == "wake":  # python-can's blocking recv: woken by each datagram, as a reader that must not lag is
    recv = bus.recv
    while not stop.is_set():
        if recv(0.1) is not None:
            n += 1
else:  # receive: drain what the kernel holds every millisecond (python-can's recv, not a wake-up per datagram)
    recv = bus.recv
    while not stop.is_set():
        time.sleep(0.001)
        while recv(0) is not None:
            n += 1
print(n, time.process_time() - cpu0, flush=True)
bus.shutdown()
"""
FEED = """
import sys, time
from pathlib import Path
import cantools
from canguard.config.loader import load_config
from canguard.engine.core import Engine
from canguard.engine.gate import LogSink
from canguard.io.block import one_block
from canguard.io.clock import ManualClock
from canguard.io.logs import read_log
cfg = load_config(Path(sys.argv[1]))
frames = list(read_log(Path(sys.argv[2])))[:int(sys.argv[3])]
clock = ManualClock()
engine = Engine(cfg, clock, LogSink(clock.now, cfg.buses, out=None, keep=False), durable=False, save_heat=False)
bus = next(iter(cfg.buses))
db = cantools.database.Database()
for path in cfg.dbc_files:
    db.add_dbc_file(str(path))
ids = {m.frame_id for m in db.messages}
def feed(part):
    t0 = time.process_time()
    for f in part:
        clock.advance_to(f.t)
        engine.take(bus, one_block(f))
    return time.process_time() - t0
def loop(part):
    t0 = time.process_time()
    for f in part:
        if f.arbitration_id in ids:
            db.decode_message(f.arbitration_id, f.data)
    return time.process_time() - t0
warm = len(frames) // 10
feed(frames[:warm]), loop(frames[:warm])
rest = frames[warm:]
print(len(rest), feed(rest) / len(rest) * 1e6, loop(rest) / len(rest) * 1e6)
"""
"""``Engine.take`` of a recorded log's frames one at a time, and a cantools loop over the same frames: frames,
then µs of CPU a frame of each."""


"""A helper process on the group: ``echo`` answers requests, ``background`` sends ``fps`` frames/s of ids no
config uses, ``receive`` counts what python-can receives; at SIGTERM each prints its count and loop CPU seconds."""


class Child:
    """A :data:`CHILD` process; :meth:`close` gives (count, CPU seconds of its loop)."""

    def __init__(self, role: str, bus: dict[str, Any], src: Path, fps: float = 0.0) -> None:
        code = CHILD.format(group=bus["channel"], port=bus["port"], role=role, fps=fps, req=ECHO_REQ, rep=ECHO_REP)
        self.proc = subprocess.Popen([sys.executable, "-c", code], env=kit.child_env(src), stdout=subprocess.PIPE,
                                     text=True)
        assert self.proc.stdout is not None
        if self.proc.stdout.readline().strip() != "ready":
            raise RuntimeError(f"the {role} process did not start")

    def close(self) -> tuple[int, float]:
        """Stop it: (frames counted, CPU seconds of its loop)."""
        self.proc.send_signal(signal.SIGTERM)
        try:
            out, _ = self.proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.communicate()
            return 0, 0.0
        n, cpu = out.split()
        return int(n), float(cpu)


class Daemon:
    """``canguard run`` on ``bus`` as a subprocess (or ``script run``, with ``env``), config and journal in ``tmp``
    (``monitor:`` as given); its stderr kept (it says there where its monitors listen)."""

    def __init__(self, tmp: Path, bus: dict[str, Any], src: Path, monitor: dict[str, Any] | None = None,
                 script: Path | None = None, env: dict[str, str] | None = None) -> None:
        tmp.mkdir(parents=True, exist_ok=True)
        config = kit.write_config(tmp, bus, monitor)
        cmd = [sys.executable, *([str(script)] if script else ["-m", "canguard"]), "run", "-c", str(config)]
        self.said: list[str] = []
        self.proc = subprocess.Popen(cmd, env=kit.child_env(src, **(env or {})), text=True, stderr=subprocess.PIPE)
        self.relay = threading.Thread(target=self.keep_stderr, daemon=True)
        self.relay.start()
        events = tmp / "events.jsonl"
        deadline = time.monotonic() + 60
        while not (events.exists() and b'"start"' in events.read_bytes()):
            if time.monotonic() > deadline or self.proc.poll() is not None:
                self.stop()
                raise RuntimeError("canguard run did not start: " + "".join(self.said)[-2000:])
            time.sleep(0.02)

    def keep_stderr(self) -> None:
        """Keep each line the daemon writes to stderr."""
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.said.append(line)

    def cpu_s(self) -> float:
        """Its CPU seconds so far."""
        return kit.cpu_of(self.proc.pid)

    def stop(self) -> None:
        """SIGTERM, as systemd stops it."""
        kit.stop_process(self.proc)
        self.relay.join(5)


def bms(current_a: float) -> can.Message:
    """A BMS_Status frame with ``current_a`` on the pack."""
    msg = cantools.database.load_file(str(kit.DBC)).get_message_by_name("BMS_Status")
    data = msg.encode({"Pack_Current": current_a, "Pack_Voltage": 48.0, "State_Of_Charge": 80.0, "Present": 1,
                       "Fault": 0, "Alive_Counter": 0})
    return can.Message(arbitration_id=BMS_ID, data=data, is_extended_id=True)


def recv_until(bus: can.BusABC, want: Callable[[can.Message], bool], timeout_s: float) -> can.Message | None:
    """The first frame ``want`` accepts, None after ``timeout_s``."""
    deadline = time.perf_counter() + timeout_s
    while (left := deadline - time.perf_counter()) > 0:
        msg = bus.recv(left)
        if msg is not None and want(msg):
            return msg
    return None


def drain(bus: can.BusABC) -> None:
    """Drop every frame already received."""
    while bus.recv(0) is not None:
        pass


class Peer:
    """The measuring side: trip-to-stop trials against the daemon and round trips through the echo, in turns."""

    def __init__(self, bus: dict[str, Any], seed: int = 1) -> None:
        self.bus = can.Bus(interface="udp_multicast", channel=bus["channel"], port=bus["port"])
        self.bus.set_filters([{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in (ESTOP0, SET_STATE0,
                                                                                             ECHO_REP)])
        self.rnd = random.Random(seed)
        self.normal, self.over = bms(10.0), bms(40.0)
        self.request = can.Message(arbitration_id=ECHO_REQ, data=bytes(8), is_extended_id=False)

    def trip(self) -> float:
        """One guard trial: seconds from the 40 A frame to the first Estop."""
        resumed = lambda m: m.arbitration_id == SET_STATE0 and bytes(m.data) == CLOSED_LOOP  # noqa: E731
        for _ in range(100):  # resent: the daemon may still hold the last trial's stop
            self.bus.send(self.normal)
            if recv_until(self.bus, resumed, 0.1) is not None:
                break
        else:
            raise RuntimeError("the task frames did not resume within 10 s (an overrun stop? the machine too busy)")
        time.sleep(self.rnd.uniform(0.0, 0.003))
        drain(self.bus)
        t0 = time.perf_counter()
        self.bus.send(self.over)
        if recv_until(self.bus, lambda m: m.arbitration_id == ESTOP0, 5.0) is None:
            raise RuntimeError("no Estop within 5 s of the overcurrent frame")
        return time.perf_counter() - t0

    def echo(self) -> float:
        """One round trip through the echo process (a datagram lost on loopback under load is sent again)."""
        for _ in range(20):
            time.sleep(self.rnd.uniform(0.0, 0.003))
            drain(self.bus)
            t0 = time.perf_counter()
            self.bus.send(self.request)
            if recv_until(self.bus, lambda m: m.arbitration_id == ECHO_REP, 0.5) is not None:
                return time.perf_counter() - t0
        raise RuntimeError("the echo process answered none of 20 requests")

    def turns(self, trials: int) -> tuple[list[float], list[float]]:
        """``trials`` of each, taking turns: (trip-to-stop seconds, echo seconds)."""
        trips, echoes = [], []
        for _ in range(trials):
            echoes.append(self.echo())
            trips.append(self.trip())
        return trips, echoes

    def close(self) -> None:
        self.bus.shutdown()


def latency_row(what: str, trips: list[float], echoes: list[float]) -> list[kit.Cell]:
    """A trip-to-stop row: canguard's p50 / p99 beside the echo's, in ms."""
    p99, e99 = kit.percentile(trips, 0.99) * 1e3, kit.percentile(echoes, 0.99) * 1e3
    return [what, len(trips), kit.median(trips) * 1e3, p99, "python-can echo process", kit.median(echoes) * 1e3, e99,
            kit.ratio(p99, e99)]


@contextlib.contextmanager
def running(children: list[Child]) -> Iterator[list[Child]]:
    """Close the children (and their counts are lost) however the block ends."""
    try:
        yield children
    finally:
        for c in children:
            if c.proc.poll() is None:
                c.close()


def ingest_window(daemon: Daemon, receiver: Child, window_s: float, idle_rate: float) -> tuple[int, float, float]:
    """While ``receiver`` takes the background's frames for ``window_s``: (its frames, the daemon's CPU µs a frame
    with ``idle_rate`` CPU seconds a second taken off, the receiver's CPU µs a frame)."""
    cpu0, t0 = daemon.cpu_s(), time.perf_counter()
    time.sleep(window_s)
    cpu1, t1 = daemon.cpu_s(), time.perf_counter()
    frames, got_cpu = receiver.close()
    return frames, (cpu1 - cpu0 - idle_rate * (t1 - t0)) / max(1, frames) * 1e6, got_cpu / max(1, frames) * 1e6


@contextlib.contextmanager
def rig(tmp: Path, bus: dict[str, Any], src: Path, echo_first: bool, **daemon_args: Any
        ) -> Iterator[tuple[Daemon, Peer]]:
    """The daemon (``daemon_args``: :class:`Daemon`'s ``script``, ``env``) and the echo process on ``bus`` in the
    order asked, the peer joined between them: (daemon, peer) while the block runs, all stopped after it. The
    newest socket of the group is woken first (see the module docstring): ``echo_first`` gives the daemon that
    place, else the echo."""
    daemon: Daemon | None = None
    peer: Peer | None = None
    echoes: list[Child] = []
    with running(echoes):
        try:
            if echo_first:
                echoes.append(Child("echo", bus, src))
            else:
                daemon = Daemon(tmp, bus, src, **daemon_args)
            peer = Peer(bus)
            if echo_first:
                daemon = Daemon(tmp, bus, src, **daemon_args)
            else:
                echoes.append(Child("echo", bus, src))
            yield daemon, peer
        finally:
            if peer is not None:
                peer.close()
            if daemon is not None:
                daemon.stop()


def alone_row(opts: Options) -> list[kit.Cell]:
    """A recorded frame fed alone (``Engine.take``: a block of one) beside a cantools loop, CPU µs a frame."""
    args = [str(kit.REPO / "config" / "examples" / "robot_guard.yaml"), str(kit.REPO / "examples" / "normal.log.gz"),
            str(2000 if opts.quick else 20000)]
    runs = [kit.python(FEED, args, opts).out.decode().split()[-3:] for _ in range(1 if opts.quick else opts.rounds)]
    feed_us, loop_us = min(float(r[1]) for r in runs), min(float(r[2]) for r in runs)  # best of the rounds
    return ["a recorded frame fed alone (Engine.take, a block of one): CPU µs a frame", int(runs[0][0]), feed_us,
            None, "cantools decode_message of its frames (same process)", loop_us, None, kit.ratio(feed_us, loop_us)]


def run(opts: Options) -> Table:
    """The live table: trip-to-stop rows worst (highest p99 / echo p99) first, then ingest."""
    trials, fps, window_s = (4, 1000.0, 0.5) if opts.quick else (1000, 8000.0, 10.0)
    table = Table("live", f"`canguard run` (bundled config, udp_multicast) beside python-can alone: trip to stop "
                  f"against an echo process, {trials:,} trials of each in turns (half of them with the echo joined to "
                  f"the group before the daemon); ingest CPU per frame at {fps:,.0f} frames/s",
                  ["measure", "trials / frames", "canguard p50 ms / µs a frame", "canguard p99 ms", "peer",
                   "peer p50 ms / µs a frame", "peer p99 ms", "canguard / peer (p99)"],
                  costs=["canguard p50 ms / µs a frame", "canguard p99 ms"])
    half = max(1, trials // 2)
    quiet: tuple[list[float], list[float]] = ([], [])
    busy: tuple[list[float], list[float]] = ([], [])
    bus = kit.multicast_bus()
    with kit.scratch("live") as d:
        for echo_first in (False, True):  # half the trials in each order (the module docstring); ingest in the last
            with rig(Path(d) / ("echo-first" if echo_first else "daemon-first"), bus, opts.src,
                     echo_first) as (daemon, peer):
                for got, kept in zip(peer.turns(half), quiet, strict=True):
                    kept.extend(got)
                if echo_first:
                    idle0, t0 = daemon.cpu_s(), time.perf_counter()
                    time.sleep(window_s)
                    idle_rate = (daemon.cpu_s() - idle0) / (time.perf_counter() - t0)
                with running([Child("background", bus, opts.src, fps)]):
                    for got, kept in zip(peer.turns(half), busy, strict=True):
                        kept.extend(got)
                    if echo_first:
                        ingest = [ingest_window(daemon, Child(role, bus, opts.src), window_s, idle_rate)
                                  for role in ("receive", "wake")]
    quiet_row = latency_row("trip → stop, no background traffic", *quiet)
    busy_row = latency_row(f"trip → stop, {fps:,.0f} frames/s background", *busy)
    (frames, own, pycan), (woken_frames, woken_own, woken) = ingest
    rows = sorted([quiet_row, busy_row], key=lambda r: -(r[-1] if isinstance(r[-1], float) else 0.0))
    rows.append(["ingest: daemon CPU a frame, idle CPU taken off", frames, own, None,
                 "python-can receive alone (process)", pycan, None, None])
    rows.append(["ingest: canguard's own (daemon − python-can's receive)", frames, own - pycan, None,
                 "python-can receive alone (process)", pycan, None, kit.ratio(own - pycan, pycan)])
    rows.append(["ingest: canguard's own beside a reader woken per frame (daemon − python-can's blocking recv)",
                 woken_frames, woken_own - woken, None, "python-can blocking recv alone (process)", woken, None,
                 kit.ratio(woken_own - woken, woken)])
    rows.append(alone_row(opts))
    table.rows = rows
    table.notes += [f"the daemon's idle CPU: {idle_rate * 100:.1f} % of a core (ticks, task frames), taken off "
                    "the ingest window",
                    "latency rows: p50 / p99 in ms; ingest rows: µs of CPU a frame; the last column of an ingest row "
                    "compares canguard's own share with python-can's receive"]
    if opts.quick:
        table.notes.append("--quick: a few trials, 1,000 frames/s for 0.5 s: checks that the suite runs")
    return table
