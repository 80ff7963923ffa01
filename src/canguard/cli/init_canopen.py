"""``canguard init DIR --canopen EDS --node N``: a starting config and tree for one CANopen drive.

The EDS is read as the daemon will read it (:mod:`canguard.config.canopen`); every object
its default TPDOs map is listed in the config, and the CiA 402 torque and current actual
values (0x6077, 0x6078) found among them become guarded sources (scale 0.1: % of the
rated value). Stop and task frames are the controlword's quick stop and enable operation
when an RPDO maps the controlword.
"""

from __future__ import annotations

from pathlib import Path

from canguard.config.canopen import (
    CONTROLWORD,
    RPDO_COMM,
    RPDO_MAP,
    TPDO_COMM,
    TPDO_MAP,
    Pdo,
    read_pdos,
)
from canguard.config.canopen_eds import Eds, EdsError
from canguard.errors import ConfigError

GUARDED = {0x6077: "torque", 0x6078: "current"}
"""CiA 402 objects ``init`` guards when a TPDO maps them: torque / current actual value (‰ of rated)."""
OVERCURRENT_PCT, RECOVERY_PCT = 150.0, 100.0
"""Starting thresholds in % of the rated value: trip above 1.5 x rated, recover at rated."""


def drive_files(eds_path: Path, node: int, *, bus: str, state_dir: Path, simulation: bool) -> dict[str, str]:
    """The config and tree texts (by file name) for the drive of ``eds_path`` at ``node``."""
    try:
        eds = Eds(eds_path, node)
        tpdos = read_pdos(eds, TPDO_COMM, TPDO_MAP, "TPDO")
        rpdos = read_pdos(eds, RPDO_COMM, RPDO_MAP, "RPDO")
    except EdsError as exc:
        raise ConfigError(f"init --canopen {eds_path}: {exc}") from None
    sources = _sources(tpdos)
    if not sources:
        mapped = "; ".join(f"{p.name}: {', '.join(o.ref for o in p.objects) or 'nothing'}" for p in tpdos)
        raise ConfigError(
            f"init --canopen {eds_path}: found no TPDO mapping 0x6077 or 0x6078 ({mapped or 'no TPDO'}), "
            "expected a CiA 402 drive's torque or current actual value (write the sources by hand, see docs/config.md)"
        )
    has_controlword = any(p.find(CONTROLWORD, 0) for p in rpdos)
    heartbeat = eds.value(0x1017)
    lines = [
        f"# Written by `canguard init --canopen {eds_path.name} --node {node}`"
        + (f": {eds.device}" if eds.device else "") + ".",
        "# Thresholds are in % of the drive's rated torque / current: edit them for your motor;",
        "# check with `canguard check -c <this file>`.",
        "buses:",
        f"  main: {{interface: {'virtual' if simulation else 'socketcan'}, channel: {bus}}}",
        "",
        "canopen:",
        f"  drive: {{eds: {eds_path.name}, node: {node}, bus: main"
        + ("" if isinstance(heartbeat, int) and heartbeat > 0 else ", heartbeat: 0.1") + "}",
        "  # the EDS's default TPDOs map:",
    ]
    for pdo in tpdos:
        objs = ", ".join(f"{o.ref} {o.name}" for o in pdo.objects) or "nothing"
        lines.append(f"  #   {pdo.name} 0x{pdo.cob_id:03X}: {objs}")
    lines += ["", "sources:"]
    lines += [f'  {name}: {{kind: current, canopen: drive, object: "0x{index:04X}", scale: 0.1}}  # % of rated'
              for name, index in sources]
    lines += ["", "tree: {file: drive_guard.xml, main: DriveGuard, tick_hz: 100}", ""]
    if has_controlword:
        lines += [
            "task:                              # sent every period while the task runs",
            "  period: 0.02",
            "  frames: [{canopen: drive, command: enable_operation}]",
            "",
            "stop:                              # sent when the tree stops the task, repeated",
            "  repeat: 0.05",
            "  frames: [{canopen: drive, command: quick_stop}]",
            "",
        ]
    else:
        lines += [
            "# No RPDO of the EDS maps the controlword (0x6040): stop with NMT.",
            "stop:",
            "  repeat: 0.05",
            "  frames: [{canopen: drive, nmt: stop}]",
            "",
        ]
    lines += [f"events: {state_dir / 'events.jsonl'}", f"state: {{file: {state_dir / 'i2t_state.json'}}}"]
    if simulation:
        lines.append("simulation: true")
    guards = "\n".join(
        f'      <IsCurrentSafe topic_name="{name}" overcurrent_threshold="{OVERCURRENT_PCT}"'
        f' recovery_threshold="{RECOVERY_PCT}"/>'
        for name, _ in sources
    )
    tree = (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        "<!-- Written by canguard init for one CANopen drive: the task runs while every guarded value is safe. -->\n"
        '<root BTCPP_format="4" main_tree_to_execute="DriveGuard">\n'
        '  <BehaviorTree ID="DriveGuard">\n'
        "    <ReactiveSequence>\n"
        f"{guards}\n"
        "      <ExecuteTask/>\n"
        "    </ReactiveSequence>\n"
        "  </BehaviorTree>\n"
        "</root>\n"
    )
    return {"canguard.yaml": "\n".join(lines) + "\n", "drive_guard.xml": tree}


def _sources(tpdos: list[Pdo]) -> list[tuple[str, int]]:
    """(source name, object index) of each guarded CiA 402 object some TPDO maps."""
    found: list[tuple[str, int]] = []
    for index, what in GUARDED.items():
        if any(p.find(index, 0) for p in tpdos):
            found.append((f"drive_{what}", index))
    return found
