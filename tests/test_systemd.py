"""sd_notify over a real unix datagram socket, the watchdog policy, and the systemd unit files."""

from __future__ import annotations

import logging
import os
import re
import shutil
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from canguard.service.systemd import Notifier, watchdog_hold
from checkout import REPO

SYSTEMD_DIR = REPO / "systemd"
ANALYZE = shutil.which("systemd-analyze")


@pytest.fixture
def notify_socket(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A unix datagram socket bound in tmp_path, as systemd's NOTIFY_SOCKET would be."""
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(2.0)
    yield sock, path
    sock.close()


def _recv(sock: socket.socket) -> bytes:
    return sock.recv(4096)


class TestNotifier:
    """Notifier: the exact datagrams systemd receives."""

    def test_ready_sends_exact_datagram(self, notify_socket: tuple[socket.socket, str]) -> None:
        """ready() sends the datagram READY=1."""
        sock, path = notify_socket
        n = Notifier({"NOTIFY_SOCKET": path})
        assert n.address == path
        assert n.ready()
        assert _recv(sock) == b"READY=1"

    def test_each_message_is_one_datagram(self, notify_socket: tuple[socket.socket, str]) -> None:
        """watchdog, status, stopping and reloading each arrive as one exact datagram, in order."""
        sock, path = notify_socket
        n = Notifier({"NOTIFY_SOCKET": path})
        n.watchdog()
        n.status("line one\nline two")
        n.stopping()
        n.reloading()
        got = [_recv(sock) for _ in range(4)]
        assert got[:3] == [b"WATCHDOG=1", b"STATUS=line one line two", b"STOPPING=1"]
        assert got[3].startswith(b"RELOADING=1\nMONOTONIC_USEC=")

    def test_reloading_uses_the_monotonic_clock(self, notify_socket: tuple[socket.socket, str]) -> None:
        """RELOADING=1 carries MONOTONIC_USEC of CLOCK_MONOTONIC now, as systemd >= 253 requires."""
        sock, path = notify_socket
        before = time_usec()
        Notifier({"NOTIFY_SOCKET": path}).reloading()
        after = time_usec()
        fields = dict(line.split("=", 1) for line in _recv(sock).decode().splitlines())
        assert fields["RELOADING"] == "1"
        assert before <= int(fields["MONOTONIC_USEC"]) <= after

    def test_abstract_socket_name(self) -> None:
        """An @name NOTIFY_SOCKET reaches the abstract unix socket of that name."""
        name = f"canguard-test-{uuid.uuid4().hex}"
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        sock.bind("\0" + name)
        sock.settimeout(2.0)
        try:
            assert Notifier({"NOTIFY_SOCKET": "@" + name}).ready()
            assert sock.recv(4096) == b"READY=1"
        finally:
            sock.close()

    def test_without_notify_socket_is_silent_no_op(self) -> None:
        """Outside systemd every call returns False and nothing is raised or sent."""
        n = Notifier({})
        assert n.address is None
        assert not any([n.ready(), n.watchdog(), n.status("x"), n.stopping(), n.reloading()])

    def test_default_env_is_the_process_environment(
        self, notify_socket: tuple[socket.socket, str], monkeypatch: pytest.MonkeyPatch
    ) -> None:
        """With no env given, NOTIFY_SOCKET is read from os.environ."""
        sock, path = notify_socket
        monkeypatch.setenv("NOTIFY_SOCKET", path)
        Notifier().watchdog()
        assert _recv(sock) == b"WATCHDOG=1"

    def test_send_error_never_raises_and_logs_once(
        self, tmp_path: Path, caplog: pytest.LogCaptureFixture
    ) -> None:
        """A socket that is gone makes notify return False, logged at WARNING only the first time."""
        n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "missing.sock")})
        with caplog.at_level(logging.DEBUG, logger="canguard.service.systemd"):
            assert not n.ready()
            assert not n.watchdog()
        warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
        assert len(warnings) == 1 and "missing.sock" in warnings[0].getMessage()
        assert len([r for r in caplog.records if "sd_notify" in r.getMessage()]) == 2  # the second at DEBUG

    def test_unsupported_address_disables(self, caplog: pytest.LogCaptureFixture) -> None:
        """A NOTIFY_SOCKET that is neither a path nor @name turns notifications off with a warning."""
        n = Notifier({"NOTIFY_SOCKET": "vsock:2:1234"})
        assert n.address is None and not n.ready()
        assert "vsock" in caplog.text

    def test_watchdog_interval(self) -> None:
        """WATCHDOG_USEC gives the interval in seconds, unless WATCHDOG_PID names another process."""
        assert Notifier({"WATCHDOG_USEC": "2000000"}).watchdog_interval_s() == 2.0
        assert (
            Notifier({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": str(os.getpid())}).watchdog_interval_s()
            == 2.0
        )
        assert Notifier({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "1"}).watchdog_interval_s() is None
        assert Notifier({"WATCHDOG_USEC": "0"}).watchdog_interval_s() is None
        assert Notifier({"WATCHDOG_USEC": "soon"}).watchdog_interval_s() is None
        assert Notifier({}).watchdog_interval_s() is None


def time_usec() -> int:
    """CLOCK_MONOTONIC in microseconds."""
    return time.monotonic_ns() // 1000


class TestWatchdogVerdict:
    """watchdog_hold: the pure decision to feed systemd's watchdog, and why not."""

    def test_on_time_and_fresh_is_ok(self) -> None:
        """A loop that ticked within k periods with no stale unstopped source may feed the watchdog."""
        assert watchdog_hold(now=10.025, last_tick=10.0, tick_period_s=0.01, k=3.0) == ""

    def test_stalled_loop_is_not_ok(self) -> None:
        """A loop whose last tick is more than k periods old must not feed the watchdog."""
        assert "stalled" in watchdog_hold(now=10.031, last_tick=10.0, tick_period_s=0.01, k=3.0)

    def test_no_tick_yet_is_not_ok(self) -> None:
        """Before the first tick the daemon is not healthy."""
        assert watchdog_hold(now=1.0, last_tick=None, tick_period_s=0.01) == "no tick yet"

    def test_stale_source_without_stop_is_not_ok(self) -> None:
        """A stale source the tree reads that has not caused a stop withholds the ping and is named."""
        assert watchdog_hold(10.0, 10.0, 0.01, stale_unstopped=["bms", "bms", "left"]).endswith(": bms, left")

    def test_bad_period_is_refused(self) -> None:
        """A non-positive tick period is a ValueError."""
        with pytest.raises(ValueError, match="tick_period_s"):
            watchdog_hold(1.0, 1.0, 0.0)


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, capture_output=True, text=True, timeout=60)


def _verify(unit: Path) -> list[str]:
    """Problems systemd-analyze verify reports about ``unit`` (it exits 0 on mere parse warnings)."""
    r = _run("systemd-analyze", "verify", "--man=no", str(unit))
    problems = [line for line in r.stderr.splitlines() if unit.name in line or str(unit) in line]
    if r.returncode != 0:
        problems.append(f"exit status {r.returncode}: {r.stderr.strip()}")
    return problems


def _exposure(unit: Path) -> float:
    r = _run("systemd-analyze", "security", "--offline=true", "--no-pager", str(unit))
    m = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", r.stdout + r.stderr)
    assert m, r.stdout + r.stderr
    return float(m.group(1))


SHIPPED_EXEC = "/opt/canguard/bin/canguard"


def _installed(text: str) -> str:
    """A unit's text with the venv path of docs/deploy.md replaced by this test run's canguard.

    verify checks that ExecStart's program exists; /opt/canguard is where a robot has it.
    """
    here = Path(sys.executable).parent / "canguard"
    return text.replace(SHIPPED_EXEC, str(here) if here.exists() else "/usr/bin/env canguard")


def _with_dropin(tmp_path: Path, dropin: str) -> Path:
    """canguard.service with a drop-in's [Service] lines merged in, as systemd would load it."""
    unit = _installed((SYSTEMD_DIR / "canguard.service").read_text())
    extra = (SYSTEMD_DIR / dropin).read_text().split("[Service]", 1)[1]
    out = tmp_path / "canguard.service"
    out.write_text(_installed(unit.replace("\n[Install]", extra + "\n[Install]")))
    return out


@pytest.mark.skipif(ANALYZE is None, reason="systemd-analyze is not installed on this machine")
class TestUnitFiles:
    """systemd/: the units pass systemd-analyze verify and security."""

    @pytest.mark.parametrize("name", ["canguard.service", "canguard-can0.service"])
    def test_verify_passes(self, name: str, tmp_path: Path) -> None:
        """systemd-analyze verify reports no problem for the shipped unit (ExecStart: this install's canguard)."""
        unit = tmp_path / name
        unit.write_text(_installed((SYSTEMD_DIR / name).read_text()))
        assert _verify(unit) == []

    def test_verify_catches_mistakes(self, tmp_path: Path) -> None:
        """The verify check is not vacuous: a typo in a setting and a missing binary are reported."""
        text = _installed((SYSTEMD_DIR / "canguard.service").read_text())
        bad = tmp_path / "canguard.service"
        bad.write_text(text.replace("Type=notify", "Type=notifyy"))
        assert any("service type" in p for p in _verify(bad))
        bad.write_text((SYSTEMD_DIR / "canguard.service").read_text().replace(SHIPPED_EXEC, "/nonexistent/canguard"))
        assert _verify(bad)

    def test_security_exposure_at_most_1(self) -> None:
        """systemd-analyze security rates canguard.service's exposure at 1.0 or below (0.9 today)."""
        assert _exposure(SYSTEMD_DIR / "canguard.service") <= 1.0

    def test_metrics_dropin_keeps_exposure_at_most_1_2(self, tmp_path: Path) -> None:
        """With the loopback metrics drop-in applied the unit still verifies and rates 1.2 or below."""
        unit = _with_dropin(tmp_path, "metrics.conf")
        assert "--metrics 127.0.0.1:9108" in unit.read_text()
        assert _verify(unit) == []
        assert _exposure(unit) <= 1.2

    def test_monitor_dropin_opens_loopback_ip_only(self, tmp_path: Path) -> None:
        """With the monitors' drop-in the unit verifies, allows IP sockets to localhost only, rates <= 1.2."""
        unit = _with_dropin(tmp_path, "monitor.conf")
        text = unit.read_text()
        assert "RestrictAddressFamilies=AF_INET AF_INET6" in text and "IPAddressAllow=localhost" in text
        assert "IPAddressDeny=any" in text
        assert _verify(unit) == []
        assert _exposure(unit) <= 1.2

    def test_monitor_dropin_puts_the_daemon_before_its_monitor_process(self, tmp_path: Path) -> None:
        """The monitors' drop-in raises the daemon 10 nice steps and starts its children back at 0 (reset on fork)."""
        unit = _with_dropin(tmp_path, "monitor.conf")
        text = unit.read_text()
        assert re.search(r"^Nice=-10$", text, re.MULTILINE)
        # without a policy set, systemd never makes the call that carries the reset-on-fork flag
        assert "CPUSchedulingPolicy=other" in text and "CPUSchedulingResetOnFork=yes" in text
        assert "RestrictRealtime=yes" in text  # no real-time policy crept in
        assert _verify(unit) == []

    def test_service_keeps_the_can_bus_reachable(self) -> None:
        """The service allows AF_CAN, binds to can0 and does not hide the host network."""
        text = (SYSTEMD_DIR / "canguard.service").read_text()
        settings = dict(
            line.split("=", 1) for line in text.splitlines() if "=" in line and not line.startswith("#")
        )
        assert settings["Type"] == "notify" and settings["NotifyAccess"] == "main"
        assert set(settings["RestrictAddressFamilies"].split()) == {"AF_CAN", "AF_NETLINK", "AF_UNIX"}
        assert "PrivateNetwork" not in settings
        assert settings["BindsTo"] == "sys-subsystem-net-devices-can0.device"
        assert "sys-subsystem-net-devices-can0.device" in settings["After"]
        assert settings["ExecStart"] == f"{SHIPPED_EXEC} run -c /etc/canguard/canguard.yaml"

    def test_can0_setup_sets_bitrate_and_restart(self) -> None:
        """Both can0 setups configure 1 Mbit/s with automatic bus-off restart."""
        oneshot = (SYSTEMD_DIR / "canguard-can0.service").read_text()
        assert "ip link set can0 type can bitrate 1000000 restart-ms 100" in oneshot
        network = (SYSTEMD_DIR / "80-can0.network").read_text()
        assert "Name=can0" in network and "BitRate=1M" in network and "RestartSec=100ms" in network
