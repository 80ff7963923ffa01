"""``canguard init DIR``: a starter config, its tree and a DBC copy, ready to edit and deploy.

The packaged whole-robot example fitted to DIR, a bus and a state directory (``--canopen``: one drive).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from canguard.cli.common import replace_once, subcommand
from canguard.data import data_path
from canguard.errors import ConfigError

EXAMPLE = "robot_guard"
DEFAULT_STATE_DIR = Path("/var/lib/canguard")


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``canguard init``."""
    p = subcommand(sub, "init", cmd_init,
                   description="Write DIR/canguard.yaml (the whole-robot example, with paths fitted to DIR), "
                               "DIR/robot_guard.xml and DIR/robot.dbc. Edit them for your robot, then "
                               "`canguard check -c DIR/canguard.yaml`. See docs/deploy.md.")
    p.add_argument("dir", type=Path, metavar="DIR")
    p.add_argument("--channel", default="can0", help="the SocketCAN interface of the bus (default can0)")
    p.add_argument("--simulation", action="store_true",
                   help="keep python-can's virtual bus and say 'simulation: true' (a bench, not a robot)")
    p.add_argument("--state-dir", type=Path, default=None, metavar="PATH",
                   help="where the daemon writes events and I²t heat (default /var/lib/canguard; "
                        "with --simulation: DIR)")
    p.add_argument("--canopen", type=Path, default=None, metavar="EDS",
                   help="instead: a config and tree for one CANopen drive from its EDS (with --node)")
    p.add_argument("--node", type=int, default=None, metavar="N", help="with --canopen: the drive's node id 1..127")
    p.add_argument("--configure", action="store_true",
                   help="with --canopen: canguard configures the drive over SDO (configure: true): its TPDO "
                        "mapping, COB-ID and heartbeat, at start and after each boot-up")
    p.add_argument("--force", action="store_true", help="overwrite files that exist")


def starter_config(text: str, *, channel: str, simulation: bool, state_dir: Path) -> str:
    """The example config's text with the paths and the bus of a deployment (comments kept)."""
    bus = "{interface: virtual, channel: can0}" if simulation else f"{{interface: socketcan, channel: {channel}}}"
    for pattern, repl in ((r"^dbc: \[[^\]]*\]", "dbc: [robot.dbc]"),
                          (r"\{file: [^,]*robot_guard\.xml,", "{file: robot_guard.xml,"),
                          (r"^  main: \{interface: [^}]*\}", f"  main: {bus}"),
                          (r"^events: \S+", f"events: {state_dir / 'events.jsonl'}"),
                          (r"^state: \{file: [^,]*,", f"state: {{file: {state_dir / 'i2t_state.json'},")):
        text = replace_once(text, pattern, repl, f"{EXAMPLE}.yaml")
    head = (f"# Written by `canguard init`: {'a simulation on the virtual bus' if simulation else 'the robot'}.\n"
            "# Edit the sources, thresholds and frames for your drives; check with `canguard check -c <this file>`.\n")
    if simulation:
        text += "\nsimulation: true                  # virtual buses only: allowed under systemd on purpose\n"
    return head + text


def canopen_files(args: argparse.Namespace, target: Path, state_dir: Path) -> dict[Path, str | Path]:
    """``--canopen EDS --node N``: the drive's config and tree, and a copy of its EDS."""
    from canguard.cli.init_canopen import drive_files

    eds: Path = args.canopen.expanduser().absolute()
    if args.node is None or not 1 <= args.node <= 127:
        raise ConfigError(f"init --canopen: --node: found {args.node}, expected the drive's node id 1..127")
    if not eds.is_file():
        raise ConfigError(f"init --canopen: {eds}: no such file, expected the drive's EDS")
    made, messages = drive_files(eds, args.node, bus="can0" if args.simulation else args.channel,
                                 state_dir=state_dir.expanduser().absolute(), simulation=args.simulation,
                                 configure=args.configure)
    for line in messages:
        print(f"canguard init: {line}", file=sys.stderr)
    return {**{target / name: text for name, text in made.items()}, target / eds.name: eds}


def cmd_init(args: argparse.Namespace) -> int:
    """Write the three files; exit 2 naming a file that exists (without --force)."""
    from canguard.config.loader import load_config

    target: Path = args.dir.expanduser().absolute()
    state_dir = args.state_dir if args.state_dir is not None else (target if args.simulation else DEFAULT_STATE_DIR)
    files: dict[Path, str | Path]
    if args.canopen is not None:
        files = canopen_files(args, target, state_dir)
    elif args.configure:
        raise ConfigError("init: --configure: found no --canopen, expected --canopen EDS --node N with it")
    else:
        files = {
            target / "canguard.yaml": starter_config(
                data_path("config", "examples", f"{EXAMPLE}.yaml").read_text(encoding="utf-8"),
                channel=args.channel, simulation=args.simulation, state_dir=state_dir.expanduser().absolute(),
            ),
            target / "robot_guard.xml": data_path("config", "trees", f"{EXAMPLE}.xml"),
            target / "robot.dbc": data_path("dbc", "robot.dbc"),
        }
    existing = [str(p) for p in files if p.exists()]
    if existing and not args.force:
        raise ConfigError("init: " + ", ".join(existing) + ": exists already; expected a new file "
                          "(use --force to overwrite)")
    created = not target.exists()
    try:
        target.mkdir(parents=True, exist_ok=True)
        for path, content in files.items():
            if isinstance(content, Path):
                shutil.copyfile(content, path)
            else:
                path.write_text(content, encoding="utf-8")
        cfg = load_config(target / "canguard.yaml")  # what we wrote must load: a broken starter is our bug
    except (OSError, ConfigError) as exc:
        for path in files:  # nothing half-made left behind
            path.unlink(missing_ok=True)
        if created:
            shutil.rmtree(target, ignore_errors=True)
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"init: {exc.filename or target}: cannot be written ({exc.strerror or exc})") from None
    for path in files:
        print(f"wrote {path}")
    buses = ", ".join(f"{n} ({b.interface} {b.channel})" for n, b in cfg.buses.items())
    print(f"buses: {buses}; events and I²t heat in {state_dir}")
    print(f"next: edit them, then `canguard check -c {target / 'canguard.yaml'}`")
    return 0
