"""CANopen drives (``canopen:``): an EDS's PDO mapping, heartbeat and EMCY as cantools messages and raw frames.

A CANopen drive is translated once, at config load, into what the rest of
canguard already handles: each TPDO a source reads becomes a cantools
``Message`` (little-endian signals at the bits the TPDO mapping gives them, the
source's ``scale``), the heartbeat (``0x700 + node``, the NMT state) and EMCY
(``0x080 + node``: code u16, error register u8, 5 manufacturer bytes) become
messages too, and the CiA 402 controlword commands and NMT commands become raw
frames. The decoder, the models and the engine then handle a drive's frames,
live and in replay, without a CANopen code path; what is CANopen-specific at run
time (the heartbeat, NMT state, EMCY and Fault-bit reasons) is a set of source
roles :class:`~canguard.protect.staleness.SourceHealth` knows.

The EDS (or DCF) is read with the ``canopen`` library (the optional extra
``canopen``), imported only when a config has a ``canopen:`` section.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

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
    "quick_stop": 0x0002,
    "enable_operation": 0x000F,
    "shutdown": 0x0006,
    "switch_on": 0x0007,
    "disable_voltage": 0x0000,
    "disable_operation": 0x0007,
    "fault_reset": 0x0080,
}
"""CiA 402 controlword commands (``command:`` of a frame) and their controlword values."""

NMT_COMMANDS: Mapping[str, int] = {
    "start": 0x01,
    "stop": 0x02,
    "pre_operational": 0x80,
    "reset_node": 0x81,
    "reset_communication": 0x82,
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
    """One PDO of a drive: its name (``TPDO1``), COB-ID and mapped objects in order."""

    name: str
    cob_id: int
    objects: tuple[MappedObject, ...]

    @property
    def length(self) -> int:
        """The frame's payload length in bytes."""
        bits = max((o.start_bit + o.bits for o in self.objects), default=0)
        return (bits + 7) // 8

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

    def tpdo_of(self, index: int, subindex: int) -> tuple[Pdo, MappedObject] | None:
        """The first TPDO that maps ``index:subindex`` and where, or None."""
        for pdo in self.tpdos:
            obj = pdo.find(index, subindex)
            if obj is not None:
                return pdo, obj
        return None

    def rpdo_of(self, index: int, subindex: int = 0) -> tuple[Pdo, MappedObject] | None:
        """The first RPDO that maps ``index:subindex`` and where, or None."""
        for pdo in self.rpdos:
            obj = pdo.find(index, subindex)
            if obj is not None:
                return pdo, obj
        return None

    def command_data(self, command: int) -> tuple[Pdo, bytes] | None:
        """The RPDO mapping the controlword and its payload with ``command`` in it, or None.

        The RPDO's other mapped objects carry their EDS values: a frame that changes only
        the controlword, as far as the drive's defaults go.
        """
        found = self.rpdo_of(CONTROLWORD)
        if found is None:
            return None
        pdo, _ = found
        payload = 0
        for obj in pdo.objects:
            value = (
                command
                if (obj.index, obj.subindex) == (CONTROLWORD, 0)
                else self.defaults.get((obj.index, obj.subindex), 0)
            )
            payload |= _raw_bits(obj, value) << obj.start_bit
        return pdo, payload.to_bytes(pdo.length, "little")

    def describe(self) -> list[str]:
        """Lines for ``canguard check``: COB-IDs, which object sits where, heartbeat and EMCY ids."""
        lines = [
            f"{self.name}: node {self.node} on {self.bus}, {self.eds.name}"
            + (f" ({self.device})" if self.device else ""),
            f"  heartbeat 0x{self.heartbeat_id:03X} every {self.heartbeat_s:g} s (timeout {self.timeout_s:g} s),"
            f" EMCY 0x{self.emcy_id:03X}",
        ]
        for pdo in (*self.tpdos, *self.rpdos):
            objs = ", ".join(f"{o.ref} {o.name} [bits {o.start_bit}..{o.start_bit + o.bits - 1}]" for o in pdo.objects)
            lines.append(f"  {pdo.name} 0x{pdo.cob_id:03X}: {objs or '(nothing mapped)'}")
        return lines


def _raw_bits(obj: MappedObject, value: int | float) -> int:
    """``value`` as the unsigned bits ``obj`` occupies."""
    if obj.is_float:
        fmt = "<f" if obj.bits == 32 else "<d"
        return int.from_bytes(struct.pack(fmt, float(value)), "little")
    return int(value) & ((1 << obj.bits) - 1)


def parse_object(value: Any) -> tuple[int, int] | str | None:
    """``object:`` as (index, subindex) when it is hex (``0x6077``, ``6077:0``, a YAML int), else its name."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return (value, 0) if 0 <= value <= 0xFFFF else None
    if not isinstance(value, str) or not value.strip():
        return None
    m = _OBJECT.fullmatch(value.strip())
    if m is None:
        return value.strip()
    return int(m.group(1), 16), int(m.group(2) or "0", 16)


class EdsError(ValueError):
    """An EDS that cannot be read or that contradicts itself (the message says where)."""


class Eds:
    """An EDS/DCF read with the ``canopen`` library for one node id: object lookups and PDO mappings."""

    def __init__(self, path: Path, node: int) -> None:
        try:
            from canopen.objectdictionary import import_od
        except ImportError as exc:  # the optional extra is missing
            raise EdsError("the python 'canopen' library is not installed: pip install 'canguard[canopen]'") from exc
        try:
            self.od = import_od(str(path), node)
        except FileNotFoundError as exc:
            raise EdsError(f"no such file: {path}") from exc
        except Exception as exc:  # configparser and the canopen library raise many kinds
            raise EdsError(f"{path} does not load as an EDS ({type(exc).__name__}: {exc})") from exc
        self.path = path

    @property
    def device(self) -> str:
        """Vendor and product name from ``[DeviceInfo]``."""
        info = self.od.device_information
        return " ".join(str(x) for x in (info.vendor_name, info.product_name) if x)

    def variable(self, index: int, subindex: int = 0) -> Any:
        """The OD variable ``index:subindex`` (or the variable ``index`` itself), or None."""
        try:
            entry: Any = self.od[index]
        except KeyError:
            return None
        if hasattr(entry, "subindex") and not hasattr(entry, "subindices"):
            return entry if subindex == 0 else None
        try:
            return entry[subindex]
        except KeyError:
            return None

    def by_name(self, name: str) -> Any:
        """The variable whose ParameterName is ``name`` (``Record.Sub`` for a sub-object), or None."""
        folded = name.casefold()
        for entry in self.od.values():
            if not hasattr(entry, "subindices"):
                if entry.name.casefold() == folded:
                    return entry
                continue
            for var in entry.values():
                full = f"{entry.name}.{var.name}".casefold()
                if folded in (full, var.name.casefold()) and var.subindex != 0:
                    return var
        return None

    def value(self, index: int, subindex: int = 0) -> Any:
        """The object's DCF value, else its EDS default (``$NODEID`` resolved), or None."""
        var = self.variable(index, subindex)
        if var is None:
            return None
        return var.value if var.value is not None else var.default

    def mapped(self, index: int, subindex: int, start_bit: int, bits: int | None = None) -> MappedObject:
        """``index:subindex`` as a PDO entry at ``start_bit`` (its EDS size unless ``bits`` is given)."""
        from canopen.objectdictionary import datatypes

        var = self.variable(index, subindex)
        if var is None:
            raise EdsError(f"0x{index:04X}:{subindex:02X} is not an object of {self.path.name}")
        size = bits if bits is not None else (1 if var.data_type == datatypes.BOOLEAN else len(var))
        return MappedObject(
            index=index,
            subindex=subindex,
            name=var.name,
            start_bit=start_bit,
            bits=size,
            signed=var.data_type in datatypes.SIGNED_TYPES,
            is_float=var.data_type in datatypes.FLOAT_TYPES,
        )

    def pdos(self, comm_base: int, map_base: int, prefix: str) -> list[Pdo]:
        """The PDOs the EDS defines at ``comm_base``/``map_base``, valid ones only (COB-ID bit 31 clear)."""
        found: list[Pdo] = []
        for n in range(512):
            cob = self.value(comm_base + n, 1)
            count = self.value(map_base + n, 0)
            if cob is None or count is None:
                continue
            cob = int(cob)
            if cob & 0x80000000:
                continue  # not valid: the drive does not send (or take) it by default
            objects: list[MappedObject] = []
            start = 0
            for sub in range(1, int(count) + 1):
                entry = int(self.value(map_base + n, sub) or 0)
                index, subindex, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
                if index < 0x1000:  # a dummy entry (data type index): bits that carry nothing
                    start += bits
                    continue
                if self.variable(index, subindex) is None:
                    # Mapped by default but not described (an EDS left incomplete): where it sits is known,
                    # what it is not; only a source reading it is a problem.
                    objects.append(MappedObject(index, subindex, UNDESCRIBED, start, bits))
                else:
                    objects.append(self.mapped(index, subindex, start, bits))
                start += bits
            found.append(Pdo(name=f"{prefix}{n + 1}", cob_id=cob & 0x7FF, objects=tuple(objects)))
        return found

    def override(self, pdo: Pdo, objects: list[tuple[int, int]]) -> Pdo:
        """``pdo`` mapping ``objects`` in order instead, each of its EDS data type's size."""
        mapped: list[MappedObject] = []
        start = 0
        for index, subindex in objects:
            obj = self.mapped(index, subindex, start)
            mapped.append(obj)
            start += obj.bits
        if start > 64:
            raise EdsError(f"{pdo.name} would carry {start} bits, more than the 64 of a CAN frame")
        return Pdo(name=pdo.name, cob_id=pdo.cob_id, objects=tuple(mapped))

