"""Prometheus metrics (``canguard run --metrics 127.0.0.1:9108``; off by default), listed in docs/deploy.md."""

from __future__ import annotations

from typing import Any

from canguard.config.monitor import parse_address as monitor_address
from canguard.errors import CanguardError

TICK_BUCKETS_S = (25e-6, 50e-6, 100e-6, 250e-6, 500e-6, 1e-3, 2.5e-3, 5e-3, 10e-3, 25e-3, 50e-3, 0.1)
"""Tick duration histogram buckets: a tick should take well under a millisecond."""


class MetricsUnavailable(CanguardError, ImportError):
    """``--metrics`` was asked for but prometheus-client is not installed."""


def parse_address(addr: str) -> tuple[str, int]:
    """``--metrics HOST:PORT`` (port 0: any free one); ValueError quoting ``addr`` when malformed."""
    text = addr.strip()
    found = "HOST:PORT, e.g. 127.0.0.1:9108 or [::1]:9108" if text.isdigit() else monitor_address(text)
    if isinstance(found, str):
        raise ValueError(f"bad metrics address {addr!r}: expected {found}")
    return found.host, found.port


class Metrics:
    """canguard's Prometheus metrics on a private registry; :meth:`start` serves them (updates thread-safe)."""

    def __init__(self) -> None:
        try:
            import prometheus_client as prom
        except ImportError as exc:
            raise MetricsUnavailable("--metrics needs prometheus-client, which is not installed: "
                                     "pip install 'canguard[metrics]' (or pip install prometheus-client)") from exc
        self._prom = prom
        self.registry = reg = prom.CollectorRegistry(auto_describe=True)
        self._received = prom.Counter("canguard_frames_received", "CAN frames read from the bus", ["bus"], registry=reg)
        self._decoded = prom.Counter("canguard_frames_decoded", "CAN frames decoded into samples", ["bus"],
                                     registry=reg)
        self._invalid = prom.Counter("canguard_frames_invalid", "Frames of configured ids that did not decode", ["bus"],
                                     registry=reg)
        self._send_errors = prom.Counter("canguard_send_errors", "Frames that could not be sent (full TX queue, error)",
                                         ["bus"], registry=reg)
        self._trips = prom.Counter("canguard_trips", "Guard trips", ["node"], registry=reg)
        self._stop = prom.Gauge("canguard_stop_active", "1 while the tree stops the task, else 0", registry=reg)
        self._tick = prom.Histogram("canguard_tick_duration_seconds", "Tree tick duration", buckets=TICK_BUCKETS_S,
                                    registry=reg)
        self._i2t = prom.Gauge("canguard_i2t_level_percent", "I²t heat of each guard, percent of its trip level",
                               ["node"], registry=reg)
        self._age = prom.Gauge("canguard_sample_age_seconds", "Age of the newest sample of each source", ["source"],
                               registry=reg)
        self._children: dict[tuple[int, str], Any] = {}
        self.port: int | None = None
        """The port actually served (the OS's choice when started with port 0)."""

    def _child(self, metric: Any, label: str) -> Any:
        key = (id(metric), label)
        child = self._children.get(key)
        if child is None:  # labels() is thread-safe and gives one child per label: a race stores the same one
            child = self._children[key] = metric.labels(label)
        return child

    def start(self, addr: str) -> None:
        """Serve ``/metrics`` at ``addr`` from a daemon thread (ValueError: malformed, OSError: cannot bind)."""
        host, port = parse_address(addr)
        try:
            server, _thread = self._prom.start_http_server(port, addr=host, registry=self.registry)
        except OSError as exc:
            raise OSError(exc.errno, f"cannot serve metrics on {addr}: {exc.strerror or exc}") from exc
        self.port = int(server.server_address[1])

    def frames(self, bus: str, received: int, decoded: int, invalid: int) -> None:
        """Count frames of ``bus``: read, decoded into samples, and of a configured id that did not decode."""
        for metric, n in ((self._received, received), (self._decoded, decoded), (self._invalid, invalid)):
            self._child(metric, bus).inc(n)

    def send_error(self, bus: str, n: int = 1) -> None:
        """Count ``n`` frames that could not be sent on ``bus``."""
        self._child(self._send_errors, bus).inc(n)

    def trip(self, node: str) -> None:
        """Count one trip of guard ``node``."""
        self._child(self._trips, node).inc()

    def set_stop_state(self, active: bool) -> None:
        """1 while the tree stops the task, 0 while the task runs."""
        self._stop.set(1 if active else 0)

    def observe_tick(self, seconds: float) -> None:
        """Record the duration of one tree tick."""
        self._tick.observe(seconds)

    def set_i2t_level(self, node: str, pct: float) -> None:
        """Set the I²t heat of guard ``node`` in percent of its trip level."""
        self._child(self._i2t, node).set(pct)

    def set_sample_age(self, source: str, s: float) -> None:
        """Set the age in seconds of ``source``'s newest sample (``inf`` before the first)."""
        self._child(self._age, source).set(s)
