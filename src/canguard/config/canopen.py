"""CANopen drives (``canopen:``): an EDS's PDO mapping, heartbeat and EMCY as cantools messages and raw frames.

Translated once, at config load: TPDOs, heartbeat (``0x700 + node``) and EMCY (``0x080 + node``: code u16,
error register u8, 5 manufacturer bytes) become cantools messages, CiA 402 and NMT commands raw frames; no
CANopen code runs later. ``configure: true`` adds the :class:`SdoWrite` s that configure the drive.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from canguard.config.canopen_eds import Eds

HEARTBEAT_BASE = 0x700
EMCY_BASE = 0x080
NMT_ID = 0x000
RPDO_COMM, RPDO_MAP = 0x1400, 0x1600
TPDO_COMM, TPDO_MAP = 0x1800, 0x1A00
PRODUCER_HEARTBEAT = 0x1017
CONTROLWORD = 0x6040
STATUSWORD = 0x6041
FAULT_BIT = 3
"""Statusword bit 3 (CiA 402): Fault."""
UNDESCRIBED = "(not in the EDS)"
"""The name of an object a PDO maps that the EDS does not describe (its type, so its sign, is unknown)."""
HEARTBEAT_FACTOR = 1.5
"""A heartbeat consumer's timeout, in producer heartbeat periods."""

COMMANDS: Mapping[str, int] = {
    "quick_stop": 0x0002, "enable_operation": 0x000F, "shutdown": 0x0006, "switch_on": 0x0007,
    "disable_voltage": 0x0000, "disable_operation": 0x0007, "fault_reset": 0x0080,
}
"""CiA 402 controlword commands (``command:`` of a frame) and their controlword values."""

NMT_COMMANDS: Mapping[str, int] = {
    "start": 0x01, "stop": 0x02, "pre_operational": 0x80, "reset_node": 0x81, "reset_communication": 0x82,
}
"""NMT commands (``nmt:`` of a frame): the command specifier of ``0x000: CS NODE``."""

_OBJECT = re.compile(r"(?:0x)?([0-9A-Fa-f]{4})(?::(?:0x)?([0-9A-Fa-f]{1,2}))?")


@dataclass(frozen=True)
class MappedObject:
    """One object a PDO carries: where its bits sit in the frame."""

    index: int
    subindex: int
    name: str
    start_bit: int
    bits: int
    signed: bool = False
    is_float: bool = False

    @property
    def ref(self) -> str:
        """``0x6077`` or ``0x6077:01``."""
        return f"0x{self.index:04X}" + (f":{self.subindex:02X}" if self.subindex else "")


@dataclass(frozen=True)
class Pdo:
    """One PDO of a drive: its name (``TPDO1``), COB-ID and mapped objects in order; ``enabled``: valid in the EDS
    (COB-ID bit 31 clear) or made valid by a ``pdo:`` override (``overridden``)."""

    name: str
    cob_id: int
    objects: tuple[MappedObject, ...]
    enabled: bool = True
    overridden: bool = False

    @property
    def bits(self) -> int:
        """The bits its objects take up to the last one."""
        return max((o.start_bit + o.bits for o in self.objects), default=0)

    @property
    def number(self) -> int:
        """1-based: 3 for ``TPDO3``."""
        return int(self.name[4:])

    @property
    def length(self) -> int:
        """The frame's payload length in bytes."""
        return (self.bits + 7) // 8

    def find(self, index: int, subindex: int) -> MappedObject | None:
        """The mapped object ``index:subindex``, or None."""
        return next((o for o in self.objects if o.index == index and o.subindex == subindex), None)


@dataclass(frozen=True)
class CanopenDrive:
    """One ``canopen:`` entry, resolved against its EDS."""

    name: str
    eds: Path
    node: int
    bus: str
    heartbeat_s: float
    tpdos: tuple[Pdo, ...]
    rpdos: tuple[Pdo, ...]
    defaults: Mapping[tuple[int, int], int | float] = field(default_factory=dict)
    """The EDS value (DCF ``ParameterValue``, else ``DefaultValue``) of each object an RPDO maps."""
    device: str = ""
    """The EDS's vendor and product name."""
    setup: tuple[SdoWrite, ...] = ()
    """``configure: true``: the SDO writes that give the drive what the config expects (empty: not configured)."""
    notes: tuple[str, ...] = ()
    """What reading the EDS tolerated or the drive must be told (``canguard check -v``)."""

    @property
    def heartbeat_id(self) -> int:
        """The COB-ID of the drive's heartbeat."""
        return HEARTBEAT_BASE + self.node

    @property
    def emcy_id(self) -> int:
        """The COB-ID of the drive's EMCY messages."""
        return EMCY_BASE + self.node

    @property
    def timeout_s(self) -> float:
        """The heartbeat consumer's timeout: 1.5 heartbeat periods."""
        return HEARTBEAT_FACTOR * self.heartbeat_s

    @property
    def configure(self) -> bool:
        """True when canguard configures the drive over SDO (``configure: true``)."""
        return bool(self.setup)

    def tpdo_of(self, index: int, subindex: int) -> tuple[Pdo, MappedObject] | None:
        """The first enabled TPDO that maps ``index:subindex`` and where, or None."""
        return _first_mapping(self.enabled_tpdos, index, subindex)

    @property
    def enabled_tpdos(self) -> tuple[Pdo, ...]:
        """The TPDOs the drive sends (valid in the EDS or made valid by ``pdo:``)."""
        return tuple(p for p in self.tpdos if p.enabled)

    def command_data(self, command: int) -> tuple[Pdo, bytes] | None:
        """The RPDO mapping the controlword and its payload with ``command`` in it (the other objects at their EDS
        values), or None."""
        found = _first_mapping(self.rpdos, CONTROLWORD, 0)
        if found is None:
            return None
        pdo, _ = found
        payload = 0
        for obj in pdo.objects:
            at = (obj.index, obj.subindex)
            value = command if at == (CONTROLWORD, 0) else self.defaults.get(at, 0)
            payload |= _raw_bits(obj, value) << obj.start_bit
        return pdo, payload.to_bytes(pdo.length, "little")

    def describe(self, verbose: bool = False) -> list[str]:
        """Lines for ``canguard check``: COB-IDs, which object sits where; ``verbose``: the notes too."""
        device = f" ({self.device})" if self.device else ""
        lines = [f"{self.name}: node {self.node} on {self.bus}, {self.eds.name}{device}",
                 f"  heartbeat 0x{self.heartbeat_id:03X} every {self.heartbeat_s:g} s (timeout {self.timeout_s:g} s),"
                 f" EMCY 0x{self.emcy_id:03X}"]
        for pdo in (*self.tpdos, *self.rpdos):
            objs = ", ".join(f"{o.ref} {o.name} [bits {o.start_bit}..{o.start_bit + o.bits - 1}]" for o in pdo.objects)
            state = " (pdo: override)" if pdo.overridden else "" if pdo.enabled else " (disabled in the EDS)"
            lines.append(f"  {pdo.name} 0x{pdo.cob_id:03X}{state}: {objs or '(nothing mapped)'}")
        if self.setup:
            lines.append(f"  configure: {len(self.setup)} SDO writes at start and after each boot-up")
            if verbose:
                lines += [f"    {w.describe()}" for w in self.setup]
        if verbose:
            lines += [f"  note: {n}" for n in self.notes]
        return lines


@dataclass(frozen=True)
class SdoWrite:
    """One SDO download that configures a drive; ``check``: read back after all writes (False for the CiA 301
    mapping steps later writes overwrite)."""

    index: int
    subindex: int
    value: int
    size: int
    what: str
    check: bool = True

    @property
    def data(self) -> bytes:
        """The value as the SDO's little-endian payload."""
        return self.value.to_bytes(self.size, "little")

    def describe(self) -> str:
        """``0x1A02:01 = 0x60770010 (TPDO3 entry 1: 0x6077 Torque actual value)``."""
        return f"0x{self.index:04X}:{self.subindex:02X} = 0x{self.value:0{self.size * 2}X} ({self.what})"


def pdo_writes(eds: Eds, pdo: Pdo, period_ms: int) -> list[SdoWrite]:
    """The CiA 301 procedure giving the TPDO ``pdo``'s mapping, COB-ID and event timer: disable it, clear the count,
    write the entries and the count, event-driven every ``period_ms`` (where the EDS has those), enable it."""
    comm, mapping = TPDO_COMM + pdo.number - 1, TPDO_MAP + pdo.number - 1
    raw = eds.value(comm, 1)
    flags = (int(raw) if isinstance(raw, int) else 0) & 0x60000000
    cob = flags | pdo.cob_id
    out = [SdoWrite(comm, 1, cob | 0x80000000, 4, f"{pdo.name} disabled while it is mapped", check=False),
           SdoWrite(mapping, 0, 0, 1, f"{pdo.name} mapping cleared", check=False)]
    for k, obj in enumerate(pdo.objects, 1):
        entry = (obj.index << 16) | (obj.subindex << 8) | obj.bits
        out.append(SdoWrite(mapping, k, entry, 4, f"{pdo.name} entry {k}: {obj.ref} {obj.name}"))
    out.append(SdoWrite(mapping, 0, len(pdo.objects), 1, f"{pdo.name} maps {len(pdo.objects)} objects"))
    if eds.variable(comm, 2) is not None:
        out.append(SdoWrite(comm, 2, 0xFF, 1, f"{pdo.name} transmission type: event-driven"))
    if eds.variable(comm, 5) is not None:
        out.append(SdoWrite(comm, 5, period_ms, 2, f"{pdo.name} event timer: every {period_ms} ms"))
    out.append(SdoWrite(comm, 1, cob, 4, f"{pdo.name} COB-ID 0x{pdo.cob_id:03X}, valid (bit 31 cleared)"))
    return out


def heartbeat_write(heartbeat_s: float) -> SdoWrite:
    """0x1017 producer heartbeat time = ``heartbeat_s`` in ms."""
    ms = max(1, round(heartbeat_s * 1000))
    return SdoWrite(PRODUCER_HEARTBEAT, 0, ms, 2, f"producer heartbeat every {ms} ms")


def _first_mapping(pdos: Iterable[Pdo], index: int, subindex: int) -> tuple[Pdo, MappedObject] | None:
    return next(((p, obj) for p in pdos if (obj := p.find(index, subindex)) is not None), None)


def mapped_text(pdos: Iterable[Pdo]) -> str:
    """``TPDO1: 0x6041, 0x6077; TPDO2: nothing``."""
    return "; ".join(f"{p.name}: {', '.join(o.ref for o in p.objects) or 'nothing'}" for p in pdos)


def drive_pdos(eds: Eds) -> tuple[list[Pdo], list[Pdo]]:
    """Every TPDO the EDS defines (disabled ones too, ``enabled`` False) and its enabled RPDOs."""
    return (_read_pdos(eds, TPDO_COMM, TPDO_MAP, "TPDO"),
            [p for p in _read_pdos(eds, RPDO_COMM, RPDO_MAP, "RPDO") if p.enabled])


def _read_pdos(eds: Eds, comm_base: int, map_base: int, prefix: str) -> list[Pdo]:
    """Every PDO the EDS defines, valid or not; a disabled one without a COB-ID gets the predefined set's (PDO 1..4),
    else 0 (no override may name it)."""
    from canguard.config.canopen_eds import DISABLED, PREDEFINED_RPDO, PREDEFINED_TPDO

    predefined = PREDEFINED_TPDO if comm_base == TPDO_COMM else PREDEFINED_RPDO
    found: list[Pdo] = []
    for n in range(512):
        cob, count = eds.value(comm_base + n, 1), eds.value(map_base + n, 0)
        if cob is None or count is None:
            continue
        ident = int(cob) & 0x7FF or (predefined[n] + eds.node if n < 4 else 0)
        objects: list[MappedObject] = []
        start = 0
        for sub in range(1, int(count) + 1):
            word = int(eds.value(map_base + n, sub) or 0)
            index, subindex, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
            var = eds.variable(index, subindex) if index >= 0x1000 else None  # below: a dummy entry's bits
            if var is not None:
                objects.append(mapped(eds, var, start, bits))
            elif index >= 0x1000:  # only a source reading it is a problem
                objects.append(MappedObject(index, subindex, UNDESCRIBED, start, bits))
            start += bits
        found.append(Pdo(f"{prefix}{n + 1}", ident, tuple(objects), enabled=not int(cob) & DISABLED))
    return found


def mapped(eds: Eds, var: Any, start_bit: int, bits: int | None = None) -> MappedObject:
    """The OD variable ``var`` as a PDO entry at ``start_bit`` (its EDS size unless ``bits`` is given)."""
    from canopen.objectdictionary import datatypes

    size = bits if bits is not None else (1 if var.data_type == datatypes.BOOLEAN else len(var))
    return MappedObject(int(var.index), int(var.subindex), var.name, start_bit, size,
                        signed=var.data_type in datatypes.SIGNED_TYPES, is_float=var.data_type in datatypes.FLOAT_TYPES)


def override(eds: Eds, pdo: Pdo, objects: list[tuple[int, int | None]]) -> Pdo:
    """``pdo`` mapping ``objects`` in order instead, enabled; EdsError for an object that cannot be a PDO value
    (where and why) or a mapping longer than a CAN frame."""
    from canguard.config.canopen_eds import EdsError

    out: list[MappedObject] = []
    start = 0
    for index, subindex in objects:
        obj = mapped(eds, eds.pdo_value(index, subindex), start)
        out.append(obj)
        start += obj.bits
    if start > 64:
        raise EdsError(f"{pdo.name} would carry {start} bits, more than the 64 of a CAN frame")
    if not pdo.cob_id:
        raise EdsError(f"{pdo.name} has no COB-ID in {eds.path.name} (only bit 31 set, beyond TPDO4)")
    return Pdo(name=pdo.name, cob_id=pdo.cob_id, objects=tuple(out), enabled=True, overridden=True)


def _raw_bits(obj: MappedObject, value: int | float) -> int:
    """``value`` as the unsigned bits ``obj`` occupies."""
    if obj.is_float:
        fmt = "<f" if obj.bits == 32 else "<d"
        return int.from_bytes(struct.pack(fmt, float(value)), "little")
    return int(value) & ((1 << obj.bits) - 1)


def parse_object(value: Any) -> tuple[int, int | None] | str | None:
    """``object:`` as (index, subindex) when it is hex (``0x6077``, ``6077:0``, a YAML int), else its name; the
    subindex is None where none is written."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return (value, None) if 0 <= value <= 0xFFFF else None
    if not isinstance(value, str) or not value.strip():
        return None
    m = _OBJECT.fullmatch(value.strip())
    if m is None:
        return value.strip()
    return int(m.group(1), 16), (int(m.group(2), 16) if m.group(2) else None)
