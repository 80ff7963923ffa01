"""``monitor:``: where the status page and the Groot2 monitor listen, checked once for the config and the CLI."""

from __future__ import annotations

import ipaddress
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from canguard.config.schema import MonitorConfig
from canguard.config.yamlsrc import Checks, _found
from canguard.errors import ConfigError

LOOPBACK = "127.0.0.1"  # where a monitor given only a port listens


@dataclass(frozen=True)
class Address:
    """A host and a TCP port to listen on."""

    host: str
    port: int

    @property
    def loopback(self) -> bool:
        """True when only this machine can connect (127.0.0.0/8, ::1, ``localhost``)."""
        ip = _ip(self.host)
        return self.host == "localhost" or (ip is not None and ip.is_loopback)

    def __str__(self) -> str:
        return f"[{self.host}]:{self.port}" if ":" in self.host else f"{self.host}:{self.port}"


def parse_address(value: object, *, port_span: int = 1) -> Address | str:
    """``"HOST:PORT"``, ``"[V6]:PORT"`` or a bare port (loopback) as an :class:`Address`, else what was expected;
    ``port_span``: how many consecutive ports the server takes (port 0: any free one)."""
    expected = "HOST:PORT (e.g. 127.0.0.1:8470) or a port number"
    top = 65535 - (port_span - 1)
    if isinstance(value, int) and not isinstance(value, bool):
        host, port_text = LOOPBACK, str(value)
    elif isinstance(value, str) and value:
        if value.isdigit():
            host, port_text = LOOPBACK, value
        else:
            host, sep, port_text = value.rpartition(":")
            host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
            if not sep or not host:
                return expected
    else:
        return expected
    if not port_text.isdigit() or int(port_text) > top:
        return f"a port number 0..{top} (0: any free port)"
    if host != "localhost" and _ip(host) is None:
        return "a numeric IP address or localhost as HOST (0.0.0.0 for every interface)"
    return Address(host, int(port_text))


def _ip(host: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        return ipaddress.ip_address(host)
    except ValueError:
        return None


def _addresses(values: Mapping[str, Any]) -> dict[str, Address | str]:
    """``http`` and ``groot2`` where ``values`` gives them: each an :class:`Address`, or what was expected."""
    return {key: parse_address(values[key], port_span=span) for key, span in (("http", 1), ("groot2", 2))
            if values.get(key) is not None}


def read_monitor(c: Checks, value: Any) -> MonitorConfig:
    """The config's ``monitor:`` section (``value``; None: left out), each problem recorded."""
    value = c.section(value, "monitor", ("http", "token", "groot2"))
    if value is None:
        return MonitorConfig()
    found: dict[str, Address] = {}
    for key, address in _addresses(value).items():
        if isinstance(address, str):
            c.problem(f"monitor.{key}", _found(value[key]), address)
        else:
            found[key] = address
    token = value.get("token")
    if token is not None and not (isinstance(token, str) and token.strip()):
        c.problem("monitor.token", _found(token), "a bearer token (a non-empty string)")
        token = None
    http = found.get("http")
    if http is not None and not http.loopback and not token and "token" not in value:
        c.problem("monitor.token", "nothing",
                  f"a bearer token: monitor.http {http} is not loopback, so the page would be open to the "
                  "network (or bind monitor.http to 127.0.0.1)")
    return MonitorConfig(token=token, **{key: str(address) for key, address in found.items()})


def with_overrides(monitor: MonitorConfig, *, http: str | None = None, groot2: str | None = None) -> MonitorConfig:
    """The config's ``monitor:`` with ``--http`` / ``--groot2`` for its addresses; ConfigError naming the flag."""
    given = {"http": http, "groot2": groot2}
    parsed = _addresses(given)
    for key, address in parsed.items():
        if isinstance(address, str):
            raise ConfigError(f"--{key} {given[key]!r}: expected {address}")
    page = parsed.get("http")
    if isinstance(page, Address) and not page.loopback and not monitor.token:
        raise ConfigError(f"--http {http}: not a loopback address, so the page would be open to the network: "
                          "set monitor.token in the config (every request then needs it as a bearer token), "
                          "or use 127.0.0.1")
    return replace(monitor, **{key: str(address) for key, address in parsed.items()})
