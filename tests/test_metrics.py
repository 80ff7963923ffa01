"""Prometheus metrics: what an operator scraping /metrics sees, and metrics being off by default."""

from __future__ import annotations

import re
import sys
import urllib.request
from collections.abc import Iterator

import pytest

from canguard.service.metrics import Metrics, MetricsUnavailable, parse_address


def _value(text: str, name: str, labels: str = "") -> float:
    """The sample value of ``name{labels}`` in Prometheus text format."""
    pattern = "^" + re.escape(name) + (re.escape("{" + labels + "}") if labels else "") + r" (\S+)$"
    m = re.search(pattern, text, flags=re.M)
    assert m, f"{name}{{{labels}}} not found in:\n{text}"
    return float(m.group(1))


@pytest.fixture
def served() -> Iterator[Metrics]:
    """Metrics served on a free loopback port (for the rest of the test process, as for the daemon's life)."""
    m = Metrics()
    m.start("127.0.0.1:0")
    yield m


def _scrape(m: Metrics) -> str:
    with urllib.request.urlopen(f"http://127.0.0.1:{m.port}/metrics", timeout=5) as resp:
        assert resp.status == 200
        return str(resp.read().decode())


class TestMetrics:
    """Metrics: the values the engine reports, as scraped over HTTP."""

    def test_scrape_shows_every_metric(self, served: Metrics) -> None:
        """Counters, gauges and the tick histogram appear over HTTP with their labels and values."""
        m = served
        for _ in range(3):
            m.frames("can0", 1, 0, 0)
        m.frames("can1", 5, 0, 0)
        m.frames("can0", 0, 2, 1)
        m.send_error("can1")
        m.trip("LeftCurrent")
        m.trip("LeftCurrent")
        m.set_stop_state(True)
        m.observe_tick(0.0003)
        m.observe_tick(0.02)
        m.set_i2t_level("LeftCurrent", 87.5)
        m.set_sample_age("bms", 0.25)
        text = _scrape(m)
        assert _value(text, "canguard_frames_received_total", 'bus="can0"') == 3
        assert _value(text, "canguard_frames_received_total", 'bus="can1"') == 5
        assert _value(text, "canguard_frames_decoded_total", 'bus="can0"') == 2
        assert _value(text, "canguard_frames_invalid_total", 'bus="can0"') == 1
        assert _value(text, "canguard_send_errors_total", 'bus="can1"') == 1
        assert _value(text, "canguard_trips_total", 'node="LeftCurrent"') == 2
        assert _value(text, "canguard_stop_active") == 1
        assert _value(text, "canguard_tick_duration_seconds_count") == 2
        assert _value(text, "canguard_tick_duration_seconds_bucket", 'le="0.0005"') == 1
        assert _value(text, "canguard_i2t_level_percent", 'node="LeftCurrent"') == 87.5
        assert _value(text, "canguard_sample_age_seconds", 'source="bms"') == 0.25

    def test_stop_state_goes_back_to_zero(self, served: Metrics) -> None:
        """The stop gauge reads 0 again once the task runs."""
        served.set_stop_state(True)
        served.set_stop_state(False)
        assert _value(_scrape(served), "canguard_stop_active") == 0

    def test_private_registry(self) -> None:
        """Two Metrics instances do not share values or clash on registration."""
        a, b = Metrics(), Metrics()
        a.trip("X")
        b.start("127.0.0.1:0")
        assert 'node="X"' not in _scrape(b)

    def test_port_in_use_names_the_address(self, served: Metrics) -> None:
        """Starting on a port already served raises OSError naming the address."""
        other = Metrics()
        with pytest.raises(OSError, match=f"127.0.0.1:{served.port}"):
            other.start(f"127.0.0.1:{served.port}")

    def test_missing_prometheus_client_is_a_clear_error(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """Without prometheus-client, building Metrics says which package to install."""
        monkeypatch.setitem(sys.modules, "prometheus_client", None)
        with pytest.raises(MetricsUnavailable, match=r"canguard\[metrics\]"):
            Metrics()


class TestParseAddress:
    """parse_address: the --metrics HOST:PORT argument."""

    @pytest.mark.parametrize(
        ("addr", "expected"),
        [
            ("127.0.0.1:9108", ("127.0.0.1", 9108)),
            ("localhost:0", ("localhost", 0)),
            ("[::1]:9108", ("::1", 9108)),
        ],
    )
    def test_good(self, addr: str, expected: tuple[str, int]) -> None:
        """Host and port come out of IPv4, localhost and bracketed IPv6 addresses."""
        assert parse_address(addr) == expected

    @pytest.mark.parametrize(
        "addr",
        [
            "9108",
            ":9108",
            "127.0.0.1",
            "127.0.0.1:",
            "host:http",
            "h:70000",
            "myhost:9108",
            "[::1]9108",
            "[nope]:1",
        ],
    )
    def test_bad(self, addr: str) -> None:
        """A malformed address is a ValueError quoting it."""
        with pytest.raises(ValueError, match="bad metrics address"):
            parse_address(addr)

    def test_bad_address_refused_by_start(self) -> None:
        """Metrics.start refuses a bad address before binding anything."""
        with pytest.raises(ValueError, match="HOST:PORT"):
            Metrics().start("9108")
