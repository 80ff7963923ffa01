"""The monitors' own process: a dead one never stops the guard, and it never outlives its daemon."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from canguard.engine.events import EventJournal
from checkout import REPO
from monitorkit import ESTOP_IDS, WAIT_S, running, wait_for, watched_daemon


def gone(pid: int) -> bool:
    """True once no process ``pid`` exists (or only its zombie, which its parent has not reaped yet)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def test_a_killed_monitor_process_is_logged_once_and_the_guard_goes_on(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """SIGKILL to the monitor process: the daemon says so once, and a trip still puts the Estop on the bus."""
    with watched_daemon(tmp_path, groot2=True) as w:
        wait_for("the task to run", lambda: running(w))
        pid = w.daemon.monitor.pid
        os.kill(pid, signal.SIGKILL)

        def said() -> list[str]:
            return [r.getMessage() for r in caplog.records if "monitor process" in r.getMessage()]

        wait_for("the daemon to say the monitor process died", said)
        msg = w.trip_until_estop(WAIT_S)
        assert msg is not None and msg.arbitration_id in ESTOP_IDS
        [text] = said()  # once, however many snapshots the engine published since
        assert f"pid {pid}" in text and "exit code -9" in text and "the guard goes on" in text


def test_a_frozen_monitor_process_neither_delays_a_stop_nor_shows_stale_news_after(tmp_path: Path) -> None:
    """SIGSTOP to the monitor process: a trip still stops on time; once it runs again, the page shows the stop."""
    with watched_daemon(tmp_path, groot2=True) as w:
        wait_for("the task to run", lambda: running(w))
        pid = w.daemon.monitor.pid
        os.kill(pid, signal.SIGSTOP)
        try:
            msg = w.trip_until_estop(2.0)
            assert msg is not None and msg.arbitration_id in ESTOP_IDS, "no Estop within 2 s with the monitors frozen"
            stops = w.daemon.engine.gate.stops
            ticks = w.daemon.engine.stats.ticks  # 50 more: more snapshots than the socket holds for it
            wait_for("the engine to tick on", lambda: w.daemon.engine.stats.ticks >= ticks + 50)
        finally:
            os.kill(pid, signal.SIGCONT)
        wait_for("the page to show the stop", lambda: w.status()["task"]["stops"] >= stops)


def test_the_monitor_process_ends_with_the_daemon(tmp_path: Path) -> None:
    """When the daemon stops, its monitor process is gone too."""
    with watched_daemon(tmp_path, groot2=True) as w:
        pid = w.daemon.monitor.pid
        assert not gone(pid)
    wait_for("the monitor process to end", lambda: gone(pid))


def test_the_monitor_process_ends_when_the_daemon_is_killed(tmp_path: Path) -> None:
    """A daemon killed outright (no clean-up runs) leaves no monitor process behind: it sees its socket close."""
    code = (
        "from canguard.config.schema import MonitorConfig\n"
        "from canguard.engine.events import EventJournal\n"
        "from canguard.service.monitor import Monitor\n"
        "m = Monitor(MonitorConfig(http='127.0.0.1:0'), EventJournal(None))\n"
        "print(m.pid, flush=True)\n"
        "import time; time.sleep(600)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    daemon = subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE, text=True,
                              cwd=tmp_path)
    try:
        assert daemon.stdout is not None
        pid = int(daemon.stdout.readline())
        assert not gone(pid)
        daemon.kill()
        daemon.wait(WAIT_S)
        wait_for("the orphaned monitor process to end", lambda: gone(pid))
    finally:
        if daemon.poll() is None:
            daemon.kill()
            daemon.wait(WAIT_S)


def test_a_port_in_use_names_the_address_and_leaves_no_process() -> None:
    """A page address already taken is a ConfigError naming it and why, and the monitor process it started is gone."""
    import socket

    from canguard.config.schema import MonitorConfig
    from canguard.errors import ConfigError
    from canguard.service.monitor import Monitor

    taken = socket.socket()
    try:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        before = set(children())
        with pytest.raises(ConfigError, match=rf"status page on 127\.0\.0\.1:{port}: cannot listen"):
            Monitor(MonitorConfig(http=f"127.0.0.1:{port}"), EventJournal(None))
        assert set(children()) <= before
    finally:
        taken.close()


def children() -> list[int]:
    """The ids of this process's living children."""
    out = []
    for task in os.listdir(f"/proc/{os.getpid()}/task"):
        with open(f"/proc/{os.getpid()}/task/{task}/children", encoding="ascii") as f:
            out += [int(pid) for pid in f.read().split() if not gone(int(pid))]
    return out


def test_the_monitor_process_runs_below_the_daemon() -> None:
    """Every thread of the monitor process is SCHED_BATCH (never preempts the daemon on waking), 10 nice steps nicer."""
    from canguard.config.schema import MonitorConfig
    from canguard.service.monitor import Monitor

    monitor = Monitor(MonitorConfig(http="127.0.0.1:0"), EventJournal(None))
    try:
        pid = monitor.pid
        ours = os.getpriority(os.PRIO_PROCESS, 0)

        def threads() -> list[int]:
            tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
            return tids if len(tids) > 1 else []  # its servers' threads started too

        tids = wait_for("the monitor process's threads", threads)
        for tid in tids:
            assert os.sched_getscheduler(tid) == os.SCHED_BATCH
            assert os.getpriority(os.PRIO_PROCESS, tid) == min(19, ours + 10)
    finally:
        monitor.close()


def test_sends_to_the_monitor_process_never_wait_and_a_gone_one_is_an_error() -> None:
    """The daemon's end takes whole messages while there is room, refuses the next at once, and raises once closed."""
    from canguard.service.monitor import WANT_BLACKBOARD, GilHoldingSocket, socket_pair

    ours, theirs = socket_pair()
    try:
        ours.setblocking(False)
        end = GilHoldingSocket(ours)
        assert end.recv() is None  # nothing asked
        theirs.send(WANT_BLACKBOARD)
        assert end.recv() == WANT_BLACKBOARD
        sent = 0
        while end.send(b"x" * 1000):  # the monitor process reads nothing: its buffer fills, no send waits
            sent += 1
            assert sent < 100_000
        assert sent > 10 and theirs.recv(2000) == b"x" * 1000  # whole messages, one per send
        theirs.close()
        with pytest.raises(OSError):
            end.send(b"x")
        assert end.recv() == b""  # the other end closed
    finally:
        ours.close()
        theirs.close()
