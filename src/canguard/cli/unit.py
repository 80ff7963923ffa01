"""``canguard unit``: the systemd unit for this install, with the right ExecStart; the CAN link's networkd file."""

from __future__ import annotations

import argparse
import re
import shutil
import sys
from pathlib import Path

from canguard.cli.common import replace_once, subcommand
from canguard.data import data_path
from canguard.errors import ConfigError

DEFAULT_CONFIG = Path("/etc/canguard/canguard.yaml")
NETWORK_FILE = "80-can0.network"
UNIT_FILE = "canguard.service"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``canguard unit``."""
    p = subcommand(sub, "unit", cmd_unit,
                   description="Print canguard.service with ExecStart pointing at this install's canguard, the "
                               "config path and the CAN interface(s) it binds to.")
    p.add_argument("--config", type=Path, default=DEFAULT_CONFIG, metavar="PATH",
                   help=f"the config the service runs (default {DEFAULT_CONFIG})")
    p.add_argument("--channel", action="append", default=None, metavar="CANx",
                   help="a CAN interface the service starts and stops with (repeatable; default can0)")
    p.add_argument("--metrics", metavar="HOST:PORT", help="serve Prometheus metrics there (loopback only)")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--network", action="store_true",
                      help="print the systemd-networkd file that brings the channel(s) up instead "
                           "(/etc/systemd/network/80-can0.network)")
    what.add_argument("--write", type=Path, default=None, metavar="DIR",
                      help="write canguard.service and 80-can0.network into DIR (made if missing) instead of "
                           "printing, e.g. `canguard unit --write systemd` for docs/deploy.md's install lines")


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
    text = replace_once(text, r"^ExecStart=.*$", f"ExecStart={cmd}", UNIT_FILE)
    devices = " ".join(f"sys-subsystem-net-devices-{c}.device" for c in channels)
    text = re.sub(r"sys-subsystem-net-devices-can0\.device", devices, text)
    if metrics:
        text = text.replace("RestrictAddressFamilies=AF_CAN AF_NETLINK AF_UNIX",
                            "RestrictAddressFamilies=AF_CAN AF_NETLINK AF_UNIX AF_INET AF_INET6")
        text = text.replace("IPAddressDeny=any", "IPAddressDeny=any\nIPAddressAllow=localhost")
    return text


def cmd_unit(args: argparse.Namespace) -> int:
    """Print the unit (or the network file), or write both into a directory."""
    channels = args.channel or ["can0"]
    unit = render_unit(data_path("systemd", UNIT_FILE).read_text(encoding="utf-8"), exe=this_canguard(),
                       config=args.config.absolute(), channels=channels, metrics=args.metrics)
    network = data_path("systemd", NETWORK_FILE).read_text(encoding="utf-8")  # networkd's Name= takes several
    network = replace_once(network, r"^Name=can0$", f"Name={' '.join(channels)}", NETWORK_FILE)
    if args.write is None:
        print(network if args.network else unit, end="")
        return 0
    from canguard.io.outputs import check_output

    for name, text in ((UNIT_FILE, unit), (NETWORK_FILE, network)):
        target = args.write / name
        check_output(target, "--write", makes_dirs=True)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text, encoding="utf-8")
        print(f"wrote {target}")
    return 0
