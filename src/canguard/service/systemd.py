"""sd_notify from scratch, and the policy deciding when the watchdog may be fed.

``WATCHDOG=1`` goes only while :func:`watchdog_hold` finds nothing wrong with the loop."""

from __future__ import annotations

import logging
import os
import socket
import time
from collections.abc import Iterable, Mapping

log = logging.getLogger(__name__)


class Notifier:
    """Sends sd_notify datagrams to ``$NOTIFY_SOCKET`` (read once); a no-op outside systemd, never raising."""

    def __init__(self, env: Mapping[str, str] | None = None) -> None:
        self._env = dict(os.environ if env is None else env)
        self.address: str | None = None
        """The socket address as passed to ``sendto`` (abstract names start with NUL); None: not under systemd."""
        self._sock: socket.socket | None = None
        self._warned = False
        raw = self._env.get("NOTIFY_SOCKET", "")
        if raw.startswith(("@", "/")):
            self.address = "\0" + raw[1:] if raw[0] == "@" else raw
        elif raw:  # e.g. "vsock:..." (systemd >= 254 in VMs): not something a robot's daemon meets
            log.warning("NOTIFY_SOCKET=%r is neither a path nor an @abstract name; notifications off", raw)

    def notify(self, *fields: str) -> bool:
        """Send ``fields`` (``"KEY=value"`` each) as one datagram; True if it was sent. Never raises."""
        if self.address is None or not fields:
            return False
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                self._sock.setblocking(False)
            self._sock.sendto("\n".join(fields).encode("utf-8", "replace"), self.address)
        except OSError as exc:
            log.log(logging.DEBUG if self._warned else logging.WARNING, "sd_notify to %r failed: %s",
                    self._env.get("NOTIFY_SOCKET"), exc)
            self._warned = True
            return False
        return True

    def ready(self) -> bool:
        """``READY=1``: buses open, tree loaded; or a reload finished."""
        return self.notify("READY=1")

    def watchdog(self) -> bool:
        """``WATCHDOG=1``: feed the watchdog. Call only when :func:`watchdog_hold` finds nothing."""
        return self.notify("WATCHDOG=1")

    def status(self, text: str) -> bool:
        """``STATUS=text`` (one line; newlines are replaced by spaces): shown by ``systemctl status``."""
        return self.notify("STATUS=" + " ".join(str(text).splitlines()))

    def stopping(self) -> bool:
        """``STOPPING=1``: the daemon is shutting down (SIGTERM received)."""
        return self.notify("STOPPING=1")

    def reloading(self) -> bool:
        """``RELOADING=1`` + ``MONOTONIC_USEC`` (systemd >= 253); :meth:`ready` once the reload is done."""
        return self.notify("RELOADING=1", f"MONOTONIC_USEC={time.monotonic_ns() // 1000}")

    def watchdog_interval_s(self) -> float | None:
        """``WatchdogSec=`` in seconds when systemd expects pings from this process, else None."""
        pid = self._env.get("WATCHDOG_PID")
        try:
            usec = int(self._env.get("WATCHDOG_USEC") or 0)
            ours = not pid or int(pid) == os.getpid()
        except ValueError:
            return None
        return usec / 1e6 if usec > 0 and ours else None


def watchdog_hold(now: float, last_tick: float | None, tick_period_s: float, stale_unstopped: Iterable[str] = (),
                  k: float = 3.0) -> str:
    """Why the daemon may not send ``WATCHDOG=1`` now ("" when it may): no tick within ``k * tick_period_s``, or a
    source stale while the tree is not stopping the task (``stale_unstopped``)."""
    if tick_period_s <= 0:
        raise ValueError(f"tick_period_s must be > 0, got {tick_period_s}")
    if last_tick is None:
        return "no tick yet"
    late_s = now - last_tick
    limit_s = k * tick_period_s
    if late_s > limit_s:
        return f"loop stalled: last tick {late_s:.3f} s ago (limit {limit_s:.3f} s)"
    stale = sorted(set(stale_unstopped))
    return f"stale source(s) without a stop: {', '.join(stale)}" if stale else ""
