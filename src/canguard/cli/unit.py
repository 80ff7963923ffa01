"""``canguard unit``: the systemd unit for this install, with the right ExecStart.

The shipped ``canguard.service`` runs ``/opt/canguard/bin/canguard`` (the venv of
docs/deploy.md). Installed elsewhere (pipx, another venv), this prints the same unit
with the path of the canguard that runs this command, so nobody edits paths by hand:
``canguard unit | sudo tee /etc/systemd/system/canguard.service``.
"""

from __future__ import annotations

import argparse
import re
import shutil
import sys
from pathlib import Path

from canguard.cli.common import subcommand
from canguard.data import data_path
from canguard.errors import ConfigError

SHIPPED_EXEC = "/opt/canguard/bin/canguard"
DEFAULT_CONFIG = Path("/etc/canguard/canguard.yaml")


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``canguard unit``."""
    p = subcommand(
        sub, "unit",
        description="Print canguard.service with ExecStart pointing at this install's canguard, the "
                    "config path and the CAN interface(s) it binds to.",
    )
    p.add_argument("--config", type=Path, default=DEFAULT_CONFIG, metavar="PATH",
                   help=f"the config the service runs (default {DEFAULT_CONFIG})")
    p.add_argument("--channel", action="append", default=None, metavar="CANx",
                   help="a CAN interface the service starts and stops with (repeatable; default can0)")
    p.add_argument("--metrics", metavar="HOST:PORT", help="serve Prometheus metrics there (loopback only)")
    p.set_defaults(func=cmd_unit)


def this_canguard() -> str:
    """The canguard executable of this install: beside the running interpreter, else on PATH."""
    beside = Path(sys.executable).parent / "canguard"
    if beside.exists():
        return str(beside)
    found = shutil.which("canguard")
    if found:
        return str(Path(found).absolute())
    return f"{sys.executable} -m canguard"


def render_unit(text: str, *, exe: str, config: Path, channels: list[str], metrics: str | None) -> str:
    """The shipped unit's text with ExecStart, the config, the bound devices and metrics set."""
    if metrics is not None and not re.fullmatch(r"(127\.0\.0\.1|localhost|\[::1\]):\d+", metrics):
        raise ConfigError(f"--metrics {metrics}: expected a loopback HOST:PORT (127.0.0.1:9108): "
                          "the unit lets only localhost through")
    cmd = f"{exe} run -c {config}" + (f" --metrics {metrics}" if metrics else "")
    text, n = re.subn(r"^ExecStart=.*$", f"ExecStart={cmd}", text, flags=re.M)
    if n != 1:
        raise ConfigError("the shipped canguard.service has no single ExecStart= line")
    devices = " ".join(f"sys-subsystem-net-devices-{c}.device" for c in channels)
    text = re.sub(r"sys-subsystem-net-devices-can0\.device", devices, text)
    if metrics:
        text = text.replace("RestrictAddressFamilies=AF_CAN AF_NETLINK AF_UNIX",
                            "RestrictAddressFamilies=AF_CAN AF_NETLINK AF_UNIX AF_INET AF_INET6")
        text = text.replace("IPAddressDeny=any", "IPAddressDeny=any\nIPAddressAllow=localhost")
    return text


def cmd_unit(args: argparse.Namespace) -> int:
    """Print the unit."""
    shipped = data_path("systemd", "canguard.service").read_text(encoding="utf-8")
    print(render_unit(shipped, exe=this_canguard(), config=args.config.absolute(),
                      channels=args.channel or ["can0"], metrics=args.metrics), end="")
    return 0
