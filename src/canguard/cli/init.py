"""``canguard init DIR``: a starter config, its tree and a DBC copy, ready to edit and deploy.

``--canopen EDS --node N``: a config and tree for one CANopen drive instead (docs/commands.md).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from canguard.cli.common import replace_once, subcommand
from canguard.config.canopen import (
    CONTROLWORD,
    DEVICE_TYPE,
    PRODUCER_HEARTBEAT,
    PROFILES,
    STATUSWORD,
    TPDO_MAP,
    Eds,
    EdsError,
    Pdo,
    SdoWrite,
    drive_pdos,
    heartbeat_write,
    override,
    pdo_writes,
)
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


GUARDED = {0x6077: "torque", 0x6078: "current"}
"""CiA 402 objects ``init`` guards: torque / current actual value (‰ of rated)."""
OVERCURRENT_PCT, RECOVERY_PCT = 150.0, 100.0
"""Starting thresholds in % of the rated value: trip above 1.5 x rated, recover at rated."""
HEARTBEAT_S = 0.1
"""The heartbeat ``init`` writes for a drive whose EDS has 0x1017 = 0."""
TPDO_PERIOD_MS = 10
"""The event timer the drive is told for a TPDO ``init`` maps (``configure: true``'s default)."""
CIA_402 = 402
WRITABLE = frozenset({"rw", "wo", "rww", "rwr"})
"""EDS AccessTypes an SDO may write."""


def q(text: str) -> str:
    """``text`` as a YAML double-quoted scalar (JSON's quoting is YAML's): any file name round-trips."""
    return json.dumps(text)


def read_drive(eds_path: Path, node: int) -> Eds:
    """The EDS at ``node``, refused unless it describes a CiA 402 drive (profile named when it does not)."""
    try:
        eds = Eds(eds_path, node)
    except EdsError as exc:
        raise ConfigError(f"init --canopen {eds_path}: {exc}") from None
    profile = eds.profile
    if profile is not None and profile != CIA_402 and (profile in PROFILES or not _guarded_objects(eds)):
        named = PROFILES.get(profile, f"profile {profile}" if profile else "no standard profile")
        raise ConfigError(f"init --canopen {eds_path}: {eds.where(DEVICE_TYPE)} device type "
                          f"0x{int(eds.value(DEVICE_TYPE)):08X}: this is a {named} device, not a drive; expected a "
                          "CiA 402 drive (0x1000 bits 0..15 = 402)")
    if not _guarded_objects(eds):
        raise ConfigError(f"init --canopen {eds_path}: found neither 0x6077 (torque actual value) nor 0x6078 "
                          f"(current actual value) in {eds_path.name}, expected a CiA 402 drive's torque or current "
                          "actual value")
    return eds


def _guarded_objects(eds: Eds) -> list[int]:
    return [index for index in GUARDED if eds.entry(index) is not None]


def choose_tpdo(eds: Eds, tpdos: list[Pdo]) -> tuple[Pdo, bool]:
    """The TPDO that carries the guarded values, and whether it is a new mapping (a ``pdo:`` override): a default
    TPDO that maps them, else the statusword (its Fault bit) and them in the first TPDO with room."""
    for pdo in tpdos:
        if pdo.enabled and any(pdo.find(index, 0) for index in GUARDED):
            return pdo, False
    values = [i for i in GUARDED if not eds.refusal(i)]
    if not values:
        reasons = "; ".join(eds.refusal(i) for i in _guarded_objects(eds))
        raise ConfigError(f"init --canopen {eds.path}: {reasons}: expected 0x6077 or 0x6078 as a PDO-mappable "
                          "object")
    wanted = ([] if eds.refusal(STATUSWORD) else [STATUSWORD]) + values
    candidates = [p for p in tpdos if not p.enabled] + [p for p in tpdos if p.enabled]
    for pdo in filter(lambda p: _remappable(eds, p), candidates):
        keep = [] if not pdo.enabled else [(o.index, o.subindex) for o in pdo.objects]
        if pdo.enabled and len(pdo.objects) and pdo.bits != sum(o.bits for o in pdo.objects):
            continue  # dummy entries: a new mapping would move the objects others read
        # ``wanted``, then with fewer objects from its end, down to one guarded value
        for extra in (wanted[:n] for n in range(len(wanted), 0, -1) if any(i in GUARDED for i in wanted[:n])):
            try:
                refs: list[tuple[int, int | None]] = [*keep, *((i, None) for i in extra if (i, 0) not in keep)]
                return override(eds, pdo, refs), True
            except EdsError:
                continue
    mapped = "; ".join(f"{p.name}: {p.bits} bits" + ("" if p.enabled else " (disabled)")
                       + ("" if _remappable(eds, p) else " (mapping not writable)") for p in tpdos)
    raise ConfigError(f"init --canopen {eds.path}: found no TPDO free or with room for 0x6077/0x6078 "
                      f"({mapped or 'no TPDO'}), expected a disabled TPDO or one with 16 bits free (map one by hand "
                      "with canopen.DRIVE.pdo, see docs/config.md)")


def _remappable(eds: Eds, pdo: Pdo) -> bool:
    """True when the EDS lets the TPDO's mapping be written (its count and first entry are not ro/const)."""
    index = TPDO_MAP + pdo.number - 1
    return all(var is not None and var.access_type in WRITABLE
               for var in (eds.variable(index, 0), eds.variable(index, 1)))


def drive_files(eds_path: Path, node: int, *, bus: str, state_dir: Path, simulation: bool,
                configure: bool = False) -> tuple[dict[str, str], list[str]]:
    """The config and tree texts (by file name) for the drive of ``eds_path`` at ``node``, and lines for stderr."""
    eds = read_drive(eds_path, node)
    try:
        tpdos, rpdos = drive_pdos(eds)
    except EdsError as exc:
        raise ConfigError(f"init --canopen {eds_path}: {exc}") from None
    pdo, new = choose_tpdo(eds, tpdos)
    sources = [(f"drive_{what}", index) for index, what in GUARDED.items() if pdo.find(index, 0)]
    messages: list[str] = []
    told = eds.value(PRODUCER_HEARTBEAT)
    heartbeat = None if isinstance(told, int) and told > 0 else HEARTBEAT_S
    writes: list[SdoWrite] = []
    if heartbeat is not None:
        writes.append(heartbeat_write(heartbeat))
    if new:
        writes += pdo_writes(eds, pdo, TPDO_PERIOD_MS)
    carried = ", ".join(f"{o.ref} {o.name}" for o in pdo.objects)
    messages.append(f"{pdo.name} 0x{pdo.cob_id:03X} carries {carried}"
                    + (" (a pdo: override: the EDS does not map it by default)" if new else ""))
    if writes and configure:
        messages.append("configure: true: canguard tells the drive over SDO at start and after each boot-up: "
                        + "; ".join(w.describe() for w in writes))
    elif writes:
        messages += ["the drive must be told (or set configure: true, and canguard tells it over SDO):",
                     *(f"  {w.describe()}" for w in writes)]
    messages += [f"warning: {w}" for w in eds.foreign_cob_ids()]
    messages += [f"note: {n}" for n in eds.notes]
    interface = "virtual" if simulation else "socketcan"
    lines = _config_lines(eds, node, interface, bus, tpdos, (pdo, new), heartbeat, configure, writes)
    lines += ["", "sources:"]
    lines += [f'  {name}: {{kind: current, canopen: drive, object: "0x{index:04X}", scale: 0.1}}  # % of rated'
              for name, index in sources]
    lines += ["", "tree: {file: drive_guard.xml, main: DriveGuard, tick_hz: 100}", ""]
    lines += _frames(any(p.find(CONTROLWORD, 0) for p in rpdos))
    lines += [f"events: {q(str(state_dir / 'events.jsonl'))}",
              f"state: {{file: {q(str(state_dir / 'i2t_state.json'))}}}"]
    if simulation:
        lines.append("simulation: true")
    return {"canguard.yaml": "\n".join(lines) + "\n", "drive_guard.xml": _tree([n for n, _ in sources])}, messages


def _config_lines(eds: Eds, node: int, interface: str, bus: str, tpdos: list[Pdo], chosen: tuple[Pdo, bool],
                  heartbeat: float | None, configure: bool, writes: list[SdoWrite]) -> list[str]:
    """The head of the config: buses and the drive's entry, with what the EDS maps and the drive must be told."""
    pdo, new = chosen
    lines = [
        f"# Written by `canguard init --canopen {eds.path.name} --node {node}`"
        + (f": {eds.device}" if eds.device else "") + ".",
        "# Thresholds are in % of the drive's rated torque / current: edit them for your motor;",
        "# check with `canguard check -c <this file>`.",
        "buses:",
        f"  main: {{interface: {interface}, channel: {q(bus)}}}",
        "",
        "canopen:",
        "  drive:",
        f"    eds: {q(eds.path.name)}",
        f"    node: {node}",
        "    bus: main",
    ]
    if heartbeat is not None:
        lines.append(f"    heartbeat: {heartbeat:g}                  # the EDS's 0x1017 is 0: no heartbeat by default")
    if configure:
        lines.append("    configure: true                 # canguard writes the heartbeat and pdo: over SDO")
    if new:
        objs = ", ".join(q(o.ref) for o in pdo.objects)
        lines += ["    pdo:", f"      {pdo.name}: [{objs}]"]
    lines.append("  # the EDS's default TPDOs map:")
    for p in tpdos:
        objs = ", ".join(f"{o.ref} {o.name}" for o in p.objects) or "nothing"
        lines.append(f"  #   {p.name} 0x{p.cob_id:03X}{'' if p.enabled else ' (disabled)'}: {objs}")
    if writes:
        lines.append("  # configure: true tells the drive over SDO at start and after each boot-up:" if configure
                     else "  # the drive must be told (configure: true makes canguard tell it over SDO):")
        lines += [f"  #   {w.describe()}" for w in writes]
    for warning in eds.foreign_cob_ids():
        lines.append(f"  # warning: {warning}")
    return lines


def _frames(has_controlword: bool) -> list[str]:
    if has_controlword:
        return [
            "task:                              # sent every period while the task runs",
            "  period: 0.02",
            "  frames: [{canopen: drive, command: enable_operation}]",
            "",
            "stop:                              # sent when the tree stops the task, repeated",
            "  repeat: 0.05",
            "  frames: [{canopen: drive, command: quick_stop}]",
            "",
        ]
    return [
        "# No RPDO of the EDS maps the controlword (0x6040): stop with NMT.",
        "stop:",
        "  repeat: 0.05",
        "  frames: [{canopen: drive, nmt: stop}]",
        "",
    ]


def _tree(names: list[str]) -> str:
    guards = "".join(f'      <IsCurrentSafe topic_name="{name}" overcurrent_threshold="{OVERCURRENT_PCT}"'
                     f' recovery_threshold="{RECOVERY_PCT}"/>\n' for name in names)
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<!-- Written by canguard init for one CANopen drive: the task runs while every guarded value is safe. -->
<root BTCPP_format="4" main_tree_to_execute="DriveGuard">
  <BehaviorTree ID="DriveGuard">
    <ReactiveSequence>
{guards}      <ExecuteTask/>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""
