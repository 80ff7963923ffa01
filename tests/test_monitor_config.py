"""``monitor:`` in the config and ``--http`` / ``--groot2``: addresses, the token rule, and nothing loaded when off."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from canguard.config.loader import load_config
from canguard.engine.events import EventJournal
from canguard.errors import ConfigError
from checkout import REPO
from clikit import cli
from monitorkit import write_demo_config


def config_with(tmp_path: Path, monitor: object) -> Path:
    """The demo's config on a private channel with ``monitor:`` set to ``monitor``."""
    path = write_demo_config(tmp_path, "monitor-config-test")
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    doc["monitor"] = monitor
    path.write_text(yaml.safe_dump(doc, allow_unicode=True), encoding="utf-8")
    return path


class TestMonitorConfig:
    """The ``monitor:`` section."""

    def test_off_unless_configured(self, tmp_path: Path) -> None:
        """A config without ``monitor:`` serves nothing."""
        cfg = load_config(write_demo_config(tmp_path, "c"))
        assert (cfg.monitor.http, cfg.monitor.groot2, cfg.monitor.token) == (None, None, None)

    def test_the_issue_example_loads(self, tmp_path: Path) -> None:
        """``monitor: {http: "127.0.0.1:8470", groot2: 1667}`` gives both addresses, Groot2 on loopback."""
        cfg = load_config(config_with(tmp_path, {"http": "127.0.0.1:8470", "groot2": 1667}))
        assert cfg.monitor.http == "127.0.0.1:8470"
        assert cfg.monitor.groot2 == "127.0.0.1:1667"

    def test_network_address_needs_a_token(self, tmp_path: Path) -> None:
        """A page on 0.0.0.0 without ``monitor.token`` is refused, naming the key and the way out."""
        with pytest.raises(ConfigError) as err:
            load_config(config_with(tmp_path, {"http": "0.0.0.0:8470"}))
        text = str(err.value)
        assert "monitor.token" in text and "not loopback" in text and "canguard.yaml" in text

    def test_network_address_with_a_token_loads(self, tmp_path: Path) -> None:
        """With a token, a page reachable from the network is allowed."""
        cfg = load_config(config_with(tmp_path, {"http": "0.0.0.0:8470", "token": "s3cret"}))
        assert (cfg.monitor.http, cfg.monitor.token) == ("0.0.0.0:8470", "s3cret")

    @pytest.mark.parametrize(("monitor", "key", "expected"), [
        ({"http": "8470x"}, "monitor.http", "HOST:PORT"),
        ({"http": "127.0.0.1:70000"}, "monitor.http", "a port number 0..65535"),
        ({"http": "robot.local:8470"}, "monitor.http", "numeric IP address"),
        ({"groot2": 65535}, "monitor.groot2", "a port number 0..65534"),
        ({"token": ""}, "monitor.token", "a bearer token"),
        ({"htp": "127.0.0.1:8470"}, "monitor.htp", "one of http, token, groot2"),
    ])
    def test_bad_values_name_key_and_expectation(self, tmp_path: Path, monitor: dict[str, object], key: str,
                                                 expected: str) -> None:
        """Each malformed value is reported with its key, its line and what was expected."""
        with pytest.raises(ConfigError) as err:
            load_config(config_with(tmp_path, monitor))
        assert key in str(err.value) and expected in str(err.value)


class TestMonitorFlags:
    """``--http`` and ``--groot2`` on ``canguard run``."""

    def test_network_http_flag_without_token_exits_2(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """``--http 0.0.0.0:PORT`` with no ``monitor.token`` exits 2 naming the flag, before opening any bus."""
        code, _, err = cli(capsys, "run", "-c", write_demo_config(tmp_path, "flag-test"), "--http", "0.0.0.0:0")
        assert code == 2
        assert "--http 0.0.0.0:0" in err and "monitor.token" in err

    def test_bad_groot2_flag_exits_2(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """``--groot2`` that is not a port exits 2 naming the flag."""
        code, _, err = cli(capsys, "run", "-c", write_demo_config(tmp_path, "flag-test"), "--groot2", "abc:x")
        assert code == 2 and "--groot2 'abc:x'" in err

    def test_flags_listed_in_help(self, capsys: pytest.CaptureFixture[str]) -> None:
        """``run -h`` and ``demo -h`` show both flags."""
        for command in ("run", "demo"):
            _, out, _ = cli(capsys, command, "-h")
            assert "--http HOST:PORT" in out and "--groot2 PORT" in out


def test_daemon_without_monitor_imports_no_server(tmp_path: Path) -> None:
    """A daemon with no monitor configured loads neither the monitor package, http.server nor zmq."""
    config = write_demo_config(tmp_path, "imports-test")
    code = (
        "import sys\n"
        "from pathlib import Path\n"
        "from canguard.service.daemon import Daemon\n"
        "from canguard.service.systemd import Notifier\n"
        f"Daemon(Path({str(config)!r}), notifier=Notifier(env={{}}))\n"
        "print(*[m for m in ('canguard.service.monitor', 'http.server', 'zmq', 'msgpack') if m in sys.modules])\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60,
                          check=True)
    assert proc.stdout.strip() == ""


def test_network_page_says_so_at_start(caplog: pytest.LogCaptureFixture) -> None:
    """A page bound to every interface says at start that the network reaches it and that requests need the token."""
    from canguard.config.schema import MonitorConfig
    from canguard.service.monitor import Monitor

    monitor = Monitor(MonitorConfig(http="0.0.0.0:0", token="s3cret"), EventJournal(None))
    try:
        with caplog.at_level("WARNING", logger="canguard.service.monitor"):
            monitor.start()
    finally:
        monitor.close()
    [said] = [r.getMessage() for r in caplog.records if "status page" in r.getMessage()]
    assert "reachable from the network" in said and "Bearer" in said
