"""The daemon live: in-process on python-can's virtual bus, and ``canguard run`` as a subprocess.

The subprocess tests talk to ``canguard run`` over python-can's ``udp_multicast``
bus with python-can's own tools as the peers: ``python -m can.player`` replays a
candump -L file written by the test, ``python -m can.logger`` records every frame
on the bus (the player's and canguard's) in arrival order. Each test uses its own
multicast group and port, its own virtual channel, and its own temporary files,
so runs in parallel do not collide. Every child process is killed at teardown.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import json
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import can
import cantools
import pytest
import yaml

from canguard.service.daemon import Daemon
from canguard.service.systemd import Notifier
from checkout import REPO, SRC
from waitkit import WAIT_S, join_or_stacks, receive_until, wait_until

BUNDLED = REPO / "config" / "canguard.yaml"
DBC = REPO / "dbc" / "robot.dbc"

BMS_ID = 0x18FF50E5
ESTOP_IDS = {node << 5 | 0x02 for node in range(4)}
SET_STATE_IDS = {node << 5 | 0x07 for node in range(4)}
CLOSED_LOOP = (8).to_bytes(4, "little")
SENT_BY_CANGUARD = ESTOP_IDS | SET_STATE_IDS


# -- frames ----------------------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def _db() -> Any:
    return cantools.database.load_file(str(DBC))


def bms_data(current_a: float) -> bytes:
    """The payload of BMS_Status with ``current_a`` on the pack, battery present."""
    msg = _db().get_message_by_name("BMS_Status")
    return bytes(msg.encode({"Pack_Current": current_a, "Pack_Voltage": 48.0, "State_Of_Charge": 80.0,
                             "Present": 1, "Fault": 0, "Alive_Counter": 0}))


def iq_data(current_a: float) -> bytes:
    """The payload of AxisN_Get_Iq with ``Iq_Measured = current_a``."""
    msg = _db().get_message_by_name("Axis0_Get_Iq")
    return bytes(msg.encode({"Iq_Setpoint": current_a, "Iq_Measured": current_a}))


def pack_current(data: bytes) -> float:
    """Pack_Current of a BMS_Status payload."""
    return float(_db().get_message_by_name("BMS_Status").decode(data)["Pack_Current"])


def write_candump(path: Path, phases: Sequence[tuple[float, float, float | None]],
                  step_s: float = 0.01) -> None:
    """A candump -L file: per (start_s, end_s, pack_a), BMS + axis0 Iq frames every step (None: silence)."""
    t0 = 1_700_000_000.0
    lines = []
    for start, end, pack_a in phases:
        if pack_a is None:
            continue
        n = round((end - start) / step_s)
        for i in range(n):
            t = t0 + start + i * step_s
            lines.append(f"({t:.6f}) can0 {BMS_ID:08X}#{bms_data(pack_a).hex().upper()}")
            lines.append(f"({t + 0.0005:.6f}) can0 {0x14:03X}#{iq_data(0.5).hex().upper()}")
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


# -- configs ---------------------------------------------------------------------------------
def write_config(tmp: Path, bus: dict[str, Any], name: str = "canguard.yaml",
                 edit: Callable[[dict[str, Any]], None] | None = None) -> Path:
    """The bundled config on ``bus`` with absolute paths and events / state files in ``tmp``."""
    doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
    doc["dbc"] = [str(DBC)]
    doc["tree"]["file"] = str((BUNDLED.parent / doc["tree"]["file"]).resolve())
    doc["buses"] = {"main": bus}
    doc["events"] = str(tmp / "events.jsonl")
    doc["state"]["file"] = str(tmp / "i2t_state.json")
    if edit is not None:
        edit(doc)
    path = tmp / name
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def unique_udp() -> dict[str, Any]:
    """A udp_multicast bus on a group and port no other test (or run) uses."""
    rnd = random.SystemRandom()
    group = f"239.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}.{rnd.randint(1, 254)}"
    return {"interface": "udp_multicast", "channel": group, "port": rnd.randint(20000, 60000)}


def read_events(path: Path) -> list[dict[str, Any]]:
    """Every complete line of the journal (a line being written is not yet complete)."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return []
    return [json.loads(line) for line in text.splitlines(keepends=True) if line.endswith("\n")]


def event_after(path: Path, name: str, after: int = 0, **fields: Any) -> Callable[[], int | None]:
    """A predicate: the index of the first event ``name`` (with ``fields``) at or after index ``after``."""
    def find() -> int | None:
        for i, e in enumerate(read_events(path)):
            if i >= after and e["event"] == name and all(e.get(k) == v for k, v in fields.items()):
                return i + 1  # truthy even for the first line
        return None
    return find


# -- child processes -------------------------------------------------------------------------
def child_env(**extra: str) -> dict[str, str]:
    """The environment of a child: this checkout's src on PYTHONPATH, unbuffered output."""
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(SRC), env.get("PYTHONPATH", "")) if p)
    env["PYTHONUNBUFFERED"] = "1"
    env.update(extra)
    return env


def bus_args(bus: dict[str, Any]) -> list[str]:
    """python-can CLI arguments (can.player, can.logger) for a udp_multicast bus."""
    # "--bus-kwargs=..." takes exactly one value; "--bus-kwargs port=..." would swallow what follows.
    # python-can before 4.6 (no can.cli) has no --bus-kwargs: it passes unknown "--name=value" options to the bus.
    port = f"--bus-kwargs=port={bus['port']}" if importlib.util.find_spec("can.cli") else f"--port={bus['port']}"
    return ["-i", "udp_multicast", "-c", bus["channel"], port]


def socket_inodes(pid: int) -> set[str]:
    """The inodes of the sockets process ``pid`` holds open."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        with contextlib.suppress(OSError):  # an fd closed meanwhile
            target = os.readlink(fd)
            if target.startswith("socket:["):
                inodes.add(target[len("socket:["):-1])
    return inodes


def read_everything(pid: int) -> bool:
    """True when process ``pid`` sleeps with nothing in the receive queues of its UDP sockets (Linux /proc).

    A process that sleeps with empty queues has taken every datagram delivered so far off its
    sockets and handled it: can.logger has written each to its file, and will lose none on SIGINT.
    """
    state = Path(f"/proc/{pid}/stat").read_text(encoding="ascii").rsplit(")", 1)[1].split()[0]
    inodes = socket_inodes(pid)
    queued = 0
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        with contextlib.suppress(FileNotFoundError):
            for line in Path(table).read_text(encoding="ascii").splitlines()[1:]:
                cols = line.split()  # sl local rem st tx_queue:rx_queue tr:when retrnsmt uid timeout inode ...
                if cols[9] in inodes:
                    queued += int(cols[4].split(":")[1], 16)
    return state == "S" and queued == 0


@contextlib.contextmanager
def watching(bus: dict[str, Any]) -> Iterator[can.BusABC]:
    """A udp_multicast bus of this process on ``bus``: it receives what is sent from now on."""
    watch = can.Bus(interface="udp_multicast", channel=bus["channel"], port=bus["port"])
    try:
        yield watch
    finally:
        watch.shutdown()


class Children:
    """Child processes of one test, each with its output in a file; :meth:`close` kills what still runs."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.procs: list[subprocess.Popen[bytes]] = []
        self._files: list[IO[bytes]] = []

    def start(self, name: str, args: Sequence[str], **env: str) -> subprocess.Popen[bytes]:
        """Start ``args`` with output to ``<tmp>/<name>.out``."""
        out = open(self.tmp / f"{name}.out", "wb")  # noqa: SIM115 - closed in close()
        self._files.append(out)
        proc = subprocess.Popen(list(args), stdout=out, stderr=subprocess.STDOUT, env=child_env(**env))
        self.procs.append(proc)
        return proc

    def output(self, name: str) -> str:
        """What child ``name`` printed so far."""
        path = self.tmp / f"{name}.out"
        return path.read_text(encoding="utf-8", errors="replace") if path.exists() else ""

    def canguard(self, config: Path, **env: str) -> subprocess.Popen[bytes]:
        """``canguard run -c config`` as a subprocess."""
        return self.start("canguard", [sys.executable, "-m", "canguard", "run", "-c", str(config)], **env)

    def logger(self, bus: dict[str, Any], out: Path) -> subprocess.Popen[bytes]:
        """``python -m can.logger`` recording the bus to ``out`` (candump -L); returns once connected."""
        proc = self.start("logger", [sys.executable, "-m", "can.logger", *bus_args(bus), "-f", str(out)])
        wait_until(lambda: "Connected to" in self.output("logger") or proc.poll() is not None,
                   what="can.logger to connect")
        assert proc.poll() is None, self.output("logger")
        return proc

    def player(self, bus: dict[str, Any], log: Path) -> subprocess.Popen[bytes]:
        """``python -m can.player`` replaying ``log`` at its own pace."""
        return self.start("player", [sys.executable, "-m", "can.player", *bus_args(bus), str(log)])

    @staticmethod
    def stop_logger(proc: subprocess.Popen[bytes]) -> None:
        """SIGINT the logger once it has read every frame already on its socket, so it writes them and closes."""
        wait_until(lambda: read_everything(proc.pid), what="can.logger to read the frames waiting on its socket")
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)

    def close(self) -> None:
        """Kill every child still running and reap it."""
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=10)
        for f in self._files:
            f.close()


@pytest.fixture
def children(tmp_path: Path) -> Iterator[Children]:
    """Child processes that are killed when the test ends, whatever happened."""
    kids = Children(tmp_path)
    try:
        yield kids
    finally:
        kids.close()


def recorded(path: Path) -> list[can.Message]:
    """The frames can.logger recorded, in arrival order."""
    with can.LogReader(str(path)) as reader:
        return list(reader)


def is_bms(m: can.Message, current_a: float) -> bool:
    """True for a BMS_Status frame carrying ``current_a``."""
    return m.arbitration_id == BMS_ID and pack_current(bytes(m.data)) == pytest.approx(current_a)


def first(msgs: Sequence[can.Message], pred: Callable[[can.Message], bool], start: int = 0) -> int:
    """Index of the first message at or after ``start`` matching ``pred`` (len(msgs) when none)."""
    return next((i for i in range(start, len(msgs)) if pred(msgs[i])), len(msgs))


def last(msgs: Sequence[can.Message], pred: Callable[[can.Message], bool]) -> int:
    """Index of the last message matching ``pred`` (-1 when none)."""
    return next((i for i in range(len(msgs) - 1, -1, -1) if pred(msgs[i])), -1)


def ids_between(msgs: Sequence[can.Message], lo: int, hi: int) -> set[int]:
    """Arbitration ids canguard sent between indexes ``lo`` and ``hi``."""
    return {m.arbitration_id for m in msgs[lo:hi] if m.arbitration_id in SENT_BY_CANGUARD}


def is_task(m: can.Message) -> bool:
    """A task frame: Set_Axis_State CLOSED_LOOP_CONTROL."""
    return m.arbitration_id in SET_STATE_IDS and bytes(m.data) == CLOSED_LOOP


def is_stop(m: can.Message) -> bool:
    """A stop frame: AxisN_Estop."""
    return m.arbitration_id in ESTOP_IDS


# -- in-process ------------------------------------------------------------------------------
class BmsFeeder:
    """Sends BMS_Status from a peer bus every 10 ms, with a current the test changes."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.current_a = 10.0
        self.held = threading.Lock()
        """Held by the feeder while it sends; a test that holds it knows no frame of the feeder is being sent."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bms-feeder", daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.01):
            with self.held:
                bms = bms_data(self.current_a)
                self.bus.send(can.Message(arbitration_id=BMS_ID, data=bms, is_extended_id=True))
                self.bus.send(can.Message(arbitration_id=0x14, data=iq_data(0.5), is_extended_id=False))

    def __enter__(self) -> BmsFeeder:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)


@dataclass
class InProcess:
    """A Daemon running in a thread on a virtual channel, and a peer bus on that channel."""

    daemon: Daemon
    peer: can.BusABC
    events: Path


@pytest.fixture
def inproc(tmp_path: Path) -> Iterator[InProcess]:
    """Daemon.run in a thread on a fresh virtual channel; stopped and joined at teardown."""
    channel = f"canguard-test-{uuid.uuid4().hex[:12]}"
    config = write_config(tmp_path, {"interface": "virtual", "channel": channel})
    daemon = Daemon(config, notifier=Notifier(env={}))
    peer = can.Bus(interface="virtual", channel=channel)
    result: list[int] = []
    thread = threading.Thread(target=lambda: result.append(daemon.run()), name="daemon", daemon=True)
    thread.start()
    try:
        yield InProcess(daemon, peer, tmp_path / "events.jsonl")
    finally:
        daemon.request_stop("test over")
        hung = join_or_stacks(thread)
        peer.shutdown()
    assert not hung, f"Daemon.run did not return after request_stop: {hung}"
    assert result == [0]


class TestDaemonInProcess:
    """Daemon.run in a thread on python-can's virtual bus, a peer bus on the same channel."""

    def test_overcurrent_from_peer_sends_estops_and_recovery_resumes(self, inproc: InProcess) -> None:
        """A peer's overcurrent BMS frame brings every axis' Estop; back to normal, task frames resume."""
        with BmsFeeder(inproc.peer) as feeder:
            receive_until(inproc.peer, is_task, "task frame while the current is normal")
            feeder.current_a = 40.0
            seen = {receive_until(inproc.peer, is_stop, "Estop after overcurrent").arbitration_id}
            while seen != ESTOP_IDS:
                seen.add(receive_until(inproc.peer, is_stop, "every axis' Estop").arbitration_id)
            feeder.current_a = 10.0
            receive_until(inproc.peer, is_task, "task frame after recovery")
        # The frames go first; the journal records the events of their tick when it is over.
        def recorded() -> list[str] | None:
            names = [e["event"] for e in read_events(inproc.events)]
            return names if "resume" in names else None

        names = wait_until(recorded, what="the resume recorded after the task frames")
        assert names.index("trip") < names.index("stop") < names.index("recover") < names.index("resume")

    def test_one_frame_spike_inside_a_burst_still_stops(self, inproc: InProcess) -> None:
        """Frames queued together are taken as one block, and a one-frame overcurrent in its middle still trips."""
        daemon = inproc.daemon
        with BmsFeeder(inproc.peer) as feeder:
            receive_until(inproc.peer, is_task, "task frame")
            with feeder.held:  # no feeder frame newer than the burst may come between its frames
                t0, queued = daemon.clock.now(), time.monotonic()
                for k in range(101):  # put at once: the loop drains them as one block
                    current_a = 40.0 if k == 60 else 10.0
                    msg = can.Message(timestamp=t0 + k * 1e-5, arbitration_id=BMS_ID, data=bms_data(current_a))
                    daemon.reader.queue.put(("main", msg, queued))
            receive_until(inproc.peer, is_stop, "Estop after the one-frame spike")
            wait_until(event_after(inproc.events, "recover"), what="the recovery at the next frame")
        trips = [e for e in read_events(inproc.events) if e["event"] == "trip"]
        assert [e["node"] for e in trips] == ["IsCurrentSafe"] and "40" in json.dumps(trips[0])

    def test_request_stop_sends_stop_frames_and_writes_exit(self, tmp_path: Path) -> None:
        """Stopping a running daemon sends the stop frames and ends the journal with an exit event."""
        channel = f"canguard-test-{uuid.uuid4().hex[:12]}"
        daemon = Daemon(write_config(tmp_path, {"interface": "virtual", "channel": channel}),
                        notifier=Notifier(env={}))
        peer = can.Bus(interface="virtual", channel=channel)
        thread = threading.Thread(target=daemon.run, daemon=True)
        try:
            thread.start()
            with BmsFeeder(peer):
                receive_until(peer, is_task, "task frame")
                daemon.request_stop("maintenance")
                thread.join(10)
                receive_until(peer, is_stop, "Estop on stop")
        finally:
            daemon.request_stop()
            thread.join(10)
            peer.shutdown()
        events = read_events(tmp_path / "events.jsonl")
        assert events[-1]["event"] == "exit" and events[-1]["reason"] == "maintenance"


# -- subprocess: the scenario ---------------------------------------------------------------
@dataclass
class Scenario:
    """What one ``canguard run`` over a scripted scenario left behind."""

    frames: list[can.Message]
    events: list[dict[str, Any]]
    returncode: int
    output: str


NORMAL_A, OVER_A, RECOVERED_A, LATER_A = 10.0, 40.0, 12.0, 14.0


@pytest.fixture(scope="class")
def scenario(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Scenario]:
    """Normal, overcurrent, recovery, silence (stale BMS), normal again, SIGTERM; recorded by can.logger."""
    tmp = tmp_path_factory.mktemp("scenario")
    kids = Children(tmp)
    try:
        bus = unique_udp()
        config = write_config(tmp, bus)
        events = tmp / "events.jsonl"
        write_candump(tmp / "scenario.log", [
            (0.0, 0.6, NORMAL_A), (0.6, 0.9, OVER_A), (0.9, 1.5, RECOVERED_A),
            (1.5, 2.6, None),  # silence: the BMS goes stale 0.5 s after its last frame
            (2.6, 8.0, LATER_A),
        ])
        logger = kids.logger(bus, tmp / "recorded.log")
        daemon = kids.canguard(config)
        wait_until(event_after(events, "start"), what="the start event")
        kids.player(bus, tmp / "scenario.log")
        stale = wait_until(event_after(events, "stale", source="/battery_state",
                                                                reason="stale"), what="the stale event")
        wait_until(event_after(events, "resume", after=stale), what="the task to resume after the stale BMS")
        with watching(bus) as watch:
            receive_until(watch, is_task, "a task frame after the resume")
        daemon.send_signal(signal.SIGTERM)
        rc = daemon.wait(timeout=WAIT_S)
        kids.stop_logger(logger)
        yield Scenario(recorded(tmp / "recorded.log"), read_events(events), rc, kids.output("canguard"))
    finally:
        kids.close()


@pytest.mark.slow
class TestRunSubprocess:
    """``canguard run`` over udp_multicast, can.player feeding it and can.logger recording the bus."""

    def test_overcurrent_puts_stop_frames_on_the_bus(self, scenario: Scenario) -> None:
        """After the first 40 A BMS frame, every axis' Estop is on the bus before the current recovers."""
        f = scenario.frames
        over = first(f, lambda m: is_bms(m, OVER_A))
        recovered = first(f, lambda m: is_bms(m, RECOVERED_A), over)
        assert over < recovered < len(f), "the logger did not record the scenario"
        assert ids_between(f, over, recovered) >= ESTOP_IDS
        first_stop = first(f, is_stop, over)
        assert not any(is_task(m) for m in f[first_stop:recovered]), "task frames while overcurrent"

    def test_recovery_resumes_task_frames(self, scenario: Scenario) -> None:
        """Once the current is back under the recovery threshold, the task frames of every axis resume."""
        f = scenario.frames
        recovered = first(f, lambda m: is_bms(m, RECOVERED_A))
        silence = last(f, lambda m: is_bms(m, RECOVERED_A))
        task_ids = {m.arbitration_id for m in f[recovered:silence] if is_task(m)}
        assert task_ids == SET_STATE_IDS

    def test_stale_bms_stops_the_task(self, scenario: Scenario) -> None:
        """When the BMS goes silent, Estops go out before it speaks again, with a stale event."""
        f = scenario.frames
        silence = last(f, lambda m: is_bms(m, RECOVERED_A))
        back = first(f, lambda m: is_bms(m, LATER_A))
        assert ids_between(f, silence + 1, back) >= ESTOP_IDS
        stale = [e for e in scenario.events if e["event"] == "stale" and e["source"] == "/battery_state"]
        assert any(e["reason"] == "stale" and e["read_by_tree"] for e in stale)

    def test_sigterm_sends_stop_frames_writes_exit_and_exits_0(self, scenario: Scenario) -> None:
        """SIGTERM while the task runs: the last frames canguard sends are Estops, exit event, exit code 0."""
        assert scenario.returncode == 0, scenario.output
        f = scenario.frames
        back = first(f, lambda m: is_bms(m, LATER_A))
        mine = [m for m in f[back:] if m.arbitration_id in SENT_BY_CANGUARD]
        assert any(is_task(m) for m in mine), "the task did not run before SIGTERM"
        assert {m.arbitration_id for m in mine[-4:]} == ESTOP_IDS
        assert scenario.events[-1]["event"] == "exit" and "SIGTERM" in scenario.events[-1]["reason"]


# -- subprocess: reload ----------------------------------------------------------------------
@pytest.mark.slow
class TestRunReload:
    """SIGHUP reloads the config; a bad one is rejected with an error event and the old one keeps guarding."""

    def test_good_then_bad_reload_and_still_stops_on_overcurrent(self, tmp_path: Path,
                                                                 children: Children) -> None:
        """A good config reloads (reload event); a bad one yields an error naming it, and guarding goes on."""
        bus = unique_udp()
        config = write_config(tmp_path, bus)
        events = tmp_path / "events.jsonl"
        logger = children.logger(bus, tmp_path / "recorded.log")
        daemon = children.canguard(config)
        wait_until(event_after(events, "start"), what="the start event")

        def slower(doc: dict[str, Any]) -> None:
            doc["tree"]["tick_hz"] = 50

        write_config(tmp_path, bus, edit=slower)
        daemon.send_signal(signal.SIGHUP)
        reloaded = wait_until(event_after(events, "reload"), what="the reload event")

        def typo(doc: dict[str, Any]) -> None:
            doc["sources"]["/battery_state"]["message"] = "BMS_Statuz"

        write_config(tmp_path, bus, edit=typo)
        daemon.send_signal(signal.SIGHUP)
        rejected = wait_until(event_after(events, "error", after=reloaded), what="the error event")
        error = read_events(events)[rejected - 1]
        assert "BMS_Statuz" in error["reason"] and "rejected" in error["reason"]
        assert daemon.poll() is None, children.output("canguard")

        write_candump(tmp_path / "over.log", [(0.0, 0.4, NORMAL_A), (0.4, 0.8, OVER_A)])
        children.player(bus, tmp_path / "over.log")
        wait_until(event_after(events, "trip", after=rejected, value=OVER_A), what="a trip after the rejected reload")
        with watching(bus) as watch:  # it hears only what is sent after the trip
            receive_until(watch, is_stop, "an Estop after the trip")
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(timeout=WAIT_S) == 0
        children.stop_logger(logger)
        f = recorded(tmp_path / "recorded.log")
        over = first(f, lambda m: is_bms(m, OVER_A))
        assert ids_between(f, over, len(f)) >= ESTOP_IDS


# -- subprocess: sd_notify -------------------------------------------------------------------
@pytest.fixture
def notify_socket() -> Iterator[tuple[socket.socket, str]]:
    """A bound unix datagram socket, as systemd's NOTIFY_SOCKET (short path: sun_path has 108 bytes)."""
    d = tempfile.mkdtemp(prefix="cgn")
    path = os.path.join(d, "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        sock.bind(path)
        sock.settimeout(0.2)
        yield sock, path
    finally:
        sock.close()
        shutil.rmtree(d, ignore_errors=True)


def notifications_until(sock: socket.socket, seen: list[str], field: str) -> None:
    """Receive datagrams into ``seen`` (one field per entry) until ``field`` is among them."""

    def arrived() -> bool:
        with contextlib.suppress(TimeoutError):  # the socket's own timeout: look again
            seen.extend(sock.recv(4096).decode().split("\n"))
        return field in seen

    wait_until(arrived, what=f"{field} from sd_notify")


@pytest.mark.slow
class TestRunNotify:
    """sd_notify messages as a real NOTIFY_SOCKET receives them."""

    def test_ready_status_watchdog_stopping(self, tmp_path: Path, children: Children,
                                            notify_socket: tuple[socket.socket, str]) -> None:
        """READY=1 after start, then STATUS= and WATCHDOG=1 (WATCHDOG_USEC set), STOPPING=1 on SIGTERM."""
        sock, path = notify_socket
        daemon = children.canguard(write_config(tmp_path, unique_udp()),
                                   NOTIFY_SOCKET=path, WATCHDOG_USEC="400000")
        seen: list[str] = []
        notifications_until(sock, seen, "READY=1")
        assert not any(f.startswith("WATCHDOG=") for f in seen[: seen.index("READY=1")])
        notifications_until(sock, seen, "WATCHDOG=1")
        status = [f for f in seen if f.startswith("STATUS=")]
        assert status and "task" in status[0], seen
        daemon.send_signal(signal.SIGTERM)
        notifications_until(sock, seen, "STOPPING=1")
        assert daemon.wait(timeout=WAIT_S) == 0
        assert seen.index("READY=1") < seen.index("STOPPING=1")


# -- subprocess: kill -9 ---------------------------------------------------------------------
@pytest.mark.slow
class TestRunKill:
    """The event journal across a kill -9."""

    def test_events_written_before_kill_9_are_intact(self, tmp_path: Path, children: Children) -> None:
        """Every line in the journal before a kill -9 is still there, whole, and parses as JSON."""
        bus = unique_udp()
        events = tmp_path / "events.jsonl"
        phases = [(0.06 * i, 0.06 * i + 0.06, OVER_A if i % 2 else NORMAL_A) for i in range(100)]
        write_candump(tmp_path / "flapping.log", phases)
        daemon = children.canguard(write_config(tmp_path, bus))
        wait_until(event_after(events, "start"), what="the start event")
        children.player(bus, tmp_path / "flapping.log")
        wait_until(lambda: len(read_events(events)) >= 20, what="20 events")
        before = events.read_bytes()
        daemon.kill()
        daemon.wait(timeout=WAIT_S)
        after = events.read_bytes()
        assert after.startswith(before)
        assert after.endswith(b"\n")
        lines = after.decode("utf-8").splitlines()
        assert len(lines) >= 20
        for line in lines:
            assert set(json.loads(line)) >= {"t", "event", "node", "source", "value", "threshold", "reason"}
