"""CANopen drives (``canopen:``): an EDS's PDO mapping, heartbeat and EMCY as cantools messages and raw frames.

Translated once, at config load: no CANopen code runs later. An EDS or DCF is read as drive vendors publish it:
deviations outside the object dictionary (a malformed ``[Comments]``, an incomplete ``[DummyUsage]``, unknown
keys) are noted (``canguard check -v``), not refused.
"""

from __future__ import annotations

import io
import math
import re
import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from canguard.config.schema import FrameSpec, SignalRef, SourceConfig
from canguard.config.yamlsrc import Checks, _closest, _found, _path

HEARTBEAT_BASE = 0x700
EMCY_BASE = 0x080
NMT_ID = 0x000
RPDO_COMM, RPDO_MAP = 0x1400, 0x1600
TPDO_COMM, TPDO_MAP = 0x1800, 0x1A00
PRODUCER_HEARTBEAT = 0x1017
CONTROLWORD = 0x6040
STATUSWORD = 0x6041
FAULT_BIT = 3  # the statusword's Fault bit (CiA 402)
UNDESCRIBED = "(not in the EDS)"
"""The name of an object a PDO maps that the EDS does not describe (its type, so its sign, is unknown)."""
HEARTBEAT_FACTOR = 1.5  # a heartbeat consumer's timeout, in producer heartbeat periods

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
DEVICE_TYPE = 0x1000
PROFILES = {
    401: "CiA 401 (generic I/O module)", 402: "CiA 402 (drive and motion control)",
    404: "CiA 404 (measuring device / closed-loop controller)", 406: "CiA 406 (encoder)",
    410: "CiA 410 (inclinometer)", 418: "CiA 418 (battery module)", 419: "CiA 419 (battery charger)",
}
"""Device profiles by number (0x1000 bits 0..15): what ``init`` names a device that is not a drive."""
DISABLED = 0x80000000  # a PDO COB-ID's bit 31: the PDO is not valid (the drive does not send or take it)
PREDEFINED_TPDO, PREDEFINED_RPDO = (0x180, 0x280, 0x380, 0x480), (0x200, 0x300, 0x400, 0x500)
"""The predefined connection set: the COB-ID of PDO n (1..4) is ``base[n-1] + node``."""

_OBJECT_SECTION = re.compile(r"([0-9A-Fa-f]{4})(?:(sub)([0-9A-Fa-f]+)|(Name|Value|Denotation))?", re.IGNORECASE)
_OBJECT_KEYS = frozenset(k.casefold() for k in (
    "ParameterName", "ObjectType", "DataType", "AccessType", "DefaultValue", "PDOMapping", "SubNumber",
    "LowLimit", "HighLimit", "ObjFlags", "CompactSubObj", "ParameterValue", "Denotation", "UploadFile",
    "DownloadFile", "StorageLocation", "Factor", "Description", "Unit",
))
"""The keys CiA 306 (and the ``canopen`` library) define for an object's section."""
_COB_OBJECTS = ((0x1400, 0x1600, 1), (0x1800, 0x1A00, 1), (0x1014, 0x1015, 0))
"""(first index, end, sub-index) of the COB-IDs that carry the node id: RPDOs, TPDOs, EMCY."""


class EdsError(ValueError):
    """An EDS that cannot be read or that contradicts itself (the message says where)."""


@dataclass
class _Section:
    name: str
    line: int
    keys: dict[str, int]  # key as written -> its first line
    again: list[int]  # lines of keys written again
    is_object: bool  # a section of the object dictionary ([6077], [1A00sub1], [1003Name]...)


def _scan(text: str) -> tuple[list[_Section], list[str]]:
    """The sections of an INI text with their lines and keys, and the text's lines."""
    lines = text.splitlines()
    sections: list[_Section] = []
    for no, line in enumerate(lines, 1):
        s = line.strip()
        if not s or s[0] in ";#":
            continue
        if s.startswith("[") and "]" in s:
            name = s[1:s.index("]")].strip()
            sections.append(_Section(name, no, {}, [], _OBJECT_SECTION.fullmatch(name) is not None))
        elif sections and "=" in s:
            key = s.split("=", 1)[0].strip()
            if key in sections[-1].keys:
                sections[-1].again.append(no)
            else:
                sections[-1].keys[key] = no
    return sections, lines


class Eds:
    """An EDS/DCF read with the ``canopen`` library for one node id: objects, PDOs, where each is written."""

    def __init__(self, path: Path, node: int) -> None:
        try:
            from canopen.objectdictionary import import_od
        except ImportError as exc:  # the optional extra is missing
            raise EdsError("the python 'canopen' library is not installed: pip install 'canguard[canopen]'") from exc
        try:
            raw = path.read_bytes()
        except FileNotFoundError as exc:
            raise EdsError(f"no such file: {path}") from exc
        except OSError as exc:
            raise EdsError(f"{path}: {exc.strerror or exc}") from exc
        self.path = path
        self.node = node
        self.notes: list[str] = []  # deviations tolerated while reading
        try:  # Windows tools write both
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError:
            text = raw.decode("latin-1")
        sections, lines = _scan(text)
        self._lines = {s.name.casefold(): s.line for s in sections}
        drop = self._lenient(sections, lines)
        kept = [line for no, line in enumerate(lines, 1) if no not in drop]
        source = io.StringIO("\n".join(kept) + "\n")
        source.name = str(path)  # import_od picks the format by the name's suffix
        try:
            self.od: Any = import_od(source, node)
        except Exception as exc:  # configparser and the canopen library raise many kinds; name the section's line
            named = re.search(r"section:? '?\[?([0-9A-Za-z_]+)", str(exc))
            section = getattr(exc, "section", None) or (named.group(1) if named else None)
            where = self.where_section(str(section)) if section else str(self.path)
            raise EdsError(f"{where}: does not load as an EDS ({type(exc).__name__}: {exc})") from exc

    def _lenient(self, sections: list[_Section], lines: list[str]) -> set[int]:
        """Lines to leave out and notes for deviations outside the object dictionary."""
        drop: set[int] = set()
        ends = [s.line for s in sections[1:]] + [len(lines) + 1]
        seen: set[str] = set()
        for section, end in zip(sections, ends, strict=True):
            name = section.name.casefold()
            if not section.is_object and name in seen:
                self.note(section.line, f"[{section.name}]", "written a second time: left out")
                drop.update(range(section.line, end))
                continue
            seen.add(name)
            if not section.is_object and section.again:
                self.note(section.again[0], f"[{section.name}]", "a key written a second time: the first kept")
                drop.update(section.again)
            if name == "comments":
                count = section.keys.get("Lines")
                want = {f"Line{i}" for i in range(1, self._int(lines, count) + 1)} if count else set()
                if count is None or not want <= set(section.keys):
                    found = ", ".join(f"{k}=" for k in section.keys) or "nothing"
                    self.note(section.line, "[Comments]", f"found {found}, expected Lines= and Line1=..LineN=: "
                              "left out (comments are not part of the object dictionary)")
                    drop.update(range(section.line, end))
            elif name == "dummyusage":
                missing = [f"Dummy{i:04d}" for i in range(1, 8) if f"Dummy{i:04d}" not in section.keys]
                if missing:
                    self.note(section.line, "[DummyUsage]", f"no {', '.join(missing)}: taken as 0 (not usable)")
                    lines[section.line - 1] += "\n" + "\n".join(f"{k}=0" for k in missing)
            elif section.is_object and not name[4:].startswith(("name", "value", "denotation")):
                unknown = [k for k in section.keys if k.casefold() not in _OBJECT_KEYS]
                if unknown:
                    self.note(section.keys[unknown[0]], f"[{section.name}]",
                              f"keys CiA 306 does not define: {', '.join(unknown)} (ignored)")
        return drop

    @staticmethod
    def _int(lines: list[str], line: int) -> int:
        try:
            return int(lines[line - 1].split("=", 1)[1].split(";")[0].strip(), 0)
        except (ValueError, IndexError):
            return 0

    def note(self, line: int, what: str, text: str) -> None:
        """Record a tolerated deviation at ``line``."""
        self.notes.append(f"{self.path.name}:{line} {what}: {text}")

    def where_section(self, section: str) -> str:
        """``file.eds:LINE [section]`` (the file alone when the section is not in it)."""
        line = self._lines.get(section.casefold())
        return f"{self.path.name}:{line} [{section}]" if line else f"{self.path.name} [{section}]"

    def where(self, index: int, subindex: int | None = None) -> str:
        """``file.eds:LINE [6077]`` or ``[1A00sub1]``: where an object is written."""
        if subindex is not None:
            for name in (f"{index:04X}sub{subindex:X}", f"{index:04X}sub{subindex}", f"{index:04X}sub{subindex:02X}"):
                if name.casefold() in self._lines:
                    return self.where_section(name)
        return self.where_section(f"{index:04X}")

    @property
    def device(self) -> str:
        """Vendor and product name from ``[DeviceInfo]``."""
        info = self.od.device_information
        return " ".join(str(x) for x in (info.vendor_name, info.product_name) if x)

    @property
    def profile(self) -> int | None:
        """The device profile number (0x1000 bits 0..15: 402 for a drive), or None when 0x1000 has no value."""
        value = self.value(DEVICE_TYPE)
        return int(value) & 0xFFFF if isinstance(value, int) else None

    def entry(self, index: int) -> Any:
        """The OD entry at ``index`` (variable, record or array), or None."""
        return self.od.get(index)

    def variable(self, index: int, subindex: int = 0) -> Any:
        """The OD variable ``index:subindex`` (or the variable ``index`` itself), or None."""
        entry = self.entry(index)
        if entry is None:
            return None
        if not hasattr(entry, "subindices"):
            return entry if subindex == 0 else None
        return entry.get(subindex)

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

    def pdo_value(self, index: int, subindex: int | None) -> Any:
        """The variable ``index[:subindex]`` when it can be a PDO value; else :class:`EdsError` saying where and why."""
        entry = self.entry(index)
        if entry is None:
            raise EdsError(f"0x{index:04X} is not an object of {self.path.name}")
        if hasattr(entry, "subindices") and subindex is None:
            subs = ", ".join(f"0x{index:04X}:{v.subindex:02X} {v.name}" for v in entry.values() if v.subindex)
            kind = "an array" if type(entry).__name__ == "ODArray" else "a record"
            raise EdsError(f"{self.where(index)} {entry.name} is {kind}: name one of its sub-indices ({subs})")
        var = self.variable(index, subindex or 0)
        if var is None:
            raise EdsError(f"0x{index:04X}:{subindex or 0:02X} is not an object of {self.path.name} "
                           f"(see {self.where(index)})")
        place = self.where(index, subindex if hasattr(entry, "subindices") else None)
        if var.data_type not in var.STRUCT_TYPES:  # strings, domains, time types: no number
            raise EdsError(f"{place} {var.name} is a string or domain (DataType 0x{var.data_type:04X}), "
                           "not a number a PDO can carry")
        if not var.pdo_mappable:
            raise EdsError(f"{place} {var.name} has PDOMapping=0: the drive cannot send it in a PDO")
        return var

    def refusal(self, index: int) -> str:
        """Why ``index`` (sub-index 0) cannot be a PDO value; "" when it can."""
        try:
            self.pdo_value(index, None)
        except EdsError as exc:
            return str(exc)
        return ""

    def foreign_cob_ids(self) -> list[str]:
        """COB-IDs written as numbers (not ``$NODEID+``) that belong to another node id than this one's."""
        out: list[str] = []
        for first, end, sub in _COB_OBJECTS:
            for index in range(first, end):
                var = self.variable(index, sub)
                given = getattr(var, "value_raw", None)  # set by the library only where the file has the key
                raw = given or getattr(var, "default_raw", None)
                if not raw or "$NODEID" in raw.upper():
                    continue
                try:
                    cob = int(raw.replace(" ", ""), 0) & 0x7FF
                except ValueError:
                    continue
                base = cob & ~0x7F
                if cob & 0x7F and cob & 0x7F != self.node and 0x80 <= base <= 0x500:
                    key = "ParameterValue" if given else "DefaultValue"
                    out.append(f"{self.where(index, sub if sub else None)} {key}={raw}: COB-ID 0x{cob:03X} is node "
                               f"{cob & 0x7F}'s (0x{base:03X} + {cob & 0x7F}), not node {self.node}'s "
                               f"(0x{base:03X} + {self.node} = 0x{base + self.node:03X})")
        return out


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
    """One PDO of a drive (``TPDO1``); ``enabled``: valid in the EDS or made valid by a ``pdo:`` override."""

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
    device: str = ""  # the EDS's vendor and product name
    setup: tuple[SdoWrite, ...] = ()  # configure: true: the SDO writes that give the drive what the config expects
    notes: tuple[str, ...] = ()  # what reading the EDS tolerated or the drive must be told (``canguard check -v``)

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
        """The RPDO mapping the controlword, and its payload: ``command``, the other objects at their EDS values."""
        found = _first_mapping(self.rpdos, CONTROLWORD, 0)
        if found is None:
            return None
        pdo, _ = found
        payload = 0
        for obj in pdo.objects:
            at = (obj.index, obj.subindex)
            value = command if at == (CONTROLWORD, 0) else self.defaults.get(at, 0)
            raw = (int.from_bytes(struct.pack("<f" if obj.bits == 32 else "<d", float(value)), "little")
                   if obj.is_float else int(value) & ((1 << obj.bits) - 1))
            payload |= raw << obj.start_bit
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
    """One SDO download that configures a drive; ``check``: read back after all writes (not a step later undone)."""

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
    """The CiA 301 writes giving the TPDO ``pdo`` its mapping, COB-ID and event timer (``period_ms``)."""
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
    """Every PDO the EDS defines; one without a COB-ID gets the predefined set's (PDO 1..4), else 0."""
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
    """``pdo`` mapping ``objects`` instead, enabled; EdsError for an object no PDO can carry, or over 64 bits."""
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


def parse_object(value: Any) -> tuple[int, int | None] | str | None:
    """``object:`` as (index, subindex or None) when it is hex (``0x6077``, ``6077:0``, an int), else its name."""
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


DRIVE_KEYS = ("eds", "node", "bus", "heartbeat", "pdo", "configure", "tpdo_period")
CONFIGURED_HEARTBEAT_S = 0.1  # what canguard tells a drive (configure: true) whose entry and EDS give none
DEFAULT_TPDO_PERIOD_S = 0.01  # the event timer canguard gives a ``pdo:`` TPDO it configures (``tpdo_period:``)


class CanopenSection:
    """``canopen:`` drives and what sources and frames take from them."""

    def __init__(self, checks: Checks) -> None:
        self.checks = checks
        self.problem = checks.problem
        self.drives: dict[str, CanopenDrive] = {}
        self._messages: dict[tuple[str, int], tuple[str, int, dict[str, Any]]] = {}
        """Per (drive, COB-ID): message name, payload length, signal name -> cantools Signal (built at the end)."""
        self.failed: set[str] = set()  # drives with a problem: their sources and frames add no follow-on errors
        self._eds: dict[str, Eds] = {}
        self._events: set[str] = set()  # drives one of whose sources carries the EMCY event roles

    def load(self, value: Any) -> None:
        """Read every ``canopen:`` drive (problems recorded, broken drives left out)."""
        if not isinstance(value, Mapping):
            self.problem("canopen", _found(value), "a mapping of drive name -> {eds, node, bus, heartbeat, pdo}")
            return
        for name, body, key in self.checks.named(value, "canopen", "a drive name"):
            drive = self.drive(name, body, key)
            if drive is not None:
                self.drives[name] = drive
            else:
                self.failed.add(name)

    def drive(self, name: str, body: Any, key: str) -> CanopenDrive | None:
        """One drive from its entry; None (its problem recorded) when its EDS or node cannot be had."""
        c = self.checks
        if not c.mapping(body, key, DRIVE_KEYS, ("eds", "node")):
            return None
        node = body.get("node")
        if isinstance(node, bool) or not isinstance(node, int) or not 1 <= node <= 127:
            c.problem(_path(key, "node"), _found(node), "a CANopen node id 1..127")
            return None
        bus = c.bus(body, key)
        path = c.file_path(body["eds"], _path(key, "eds")) if "eds" in body else None
        if path is None:
            return None
        try:
            eds = Eds(path, node)
            tpdos, rpdos = drive_pdos(eds)
        except EdsError as exc:
            c.problem(_path(key, "eds"), repr(str(body["eds"])) + f" ({exc})", "a readable EDS or DCF file")
            return None
        self._eds[name] = eds
        if "pdo" in body:
            tpdos = self.overrides(eds, tpdos, body["pdo"], _path(key, "pdo"))
        configure = c.choice(body, "configure", key, (True, False), False)
        heartbeat = self.heartbeat(eds, body, key, configure)
        values = {(o.index, o.subindex): eds.value(o.index, o.subindex) for pdo in rpdos for o in pdo.objects}
        defaults = {at: v for at, v in values.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
        setup: tuple[SdoWrite, ...] = ()
        if configure:  # the heartbeat, then each pdo: override's mapping, COB-ID and event timer
            period_ms = max(1, min(0xFFFF, round(c.seconds(body, "tpdo_period", key, DEFAULT_TPDO_PERIOD_S) * 1000)))
            writes = [w for pdo in tpdos if pdo.overridden for w in pdo_writes(eds, pdo, period_ms)]
            setup = (heartbeat_write(heartbeat), *writes)
        if "tpdo_period" in body and not configure:
            c.problem(_path(key, "tpdo_period"), f"{body['tpdo_period']!r} without configure: true",
                      "configure: true with it (the period is what canguard tells the drive)")
        notes = [*eds.notes, *eds.foreign_cob_ids()]
        told = eds.value(PRODUCER_HEARTBEAT)
        if not configure and told != round(heartbeat * 1000):
            notes.append(f"the EDS's 0x1017 producer heartbeat time is {told} ms: the drive must be told "
                         f"{round(heartbeat * 1000)} ms (configure: true does)")
        notes += [f"{pdo.name} is a pdo: override: the drive must be told its mapping and COB-ID (configure: true does)"
                  for pdo in tpdos if pdo.overridden and not configure]
        return CanopenDrive(name=name, eds=path, node=node, bus=bus, heartbeat_s=heartbeat, tpdos=tuple(tpdos),
                            rpdos=tuple(rpdos), defaults=defaults, device=eds.device, setup=setup, notes=tuple(notes))

    def heartbeat(self, eds: Eds, body: Mapping[str, Any], key: str, configure: bool) -> float:
        """``heartbeat:``, else the EDS's 0x1017 when not 0, else (configured, or after a problem) the default."""
        if "heartbeat" in body:
            return self.checks.seconds(body, "heartbeat", key, CONFIGURED_HEARTBEAT_S)
        ms = eds.value(PRODUCER_HEARTBEAT)
        if isinstance(ms, int) and ms > 0:
            return ms / 1000.0
        if configure:
            return CONFIGURED_HEARTBEAT_S
        told = ms if ms is not None else "absent"
        self.problem(_path(key, "heartbeat"), f"nothing (the EDS's 0x1017 producer heartbeat time is {told}: "
                     "the drive sends no heartbeat by default)",
                     "the drive's heartbeat period in seconds (heartbeat: 0.1), with the drive told 0x1017 = "
                     "that period in ms, or configure: true (canguard tells it)")
        return CONFIGURED_HEARTBEAT_S

    def overrides(self, eds: Eds, tpdos: list[Pdo], value: Any, key: str) -> list[Pdo]:
        """``pdo: {TPDO3: [objects...]}``: those TPDOs (disabled in the EDS or not) map these objects instead."""
        if not isinstance(value, Mapping):
            self.problem(key, _found(value), "a mapping of TPDO name -> list of objects")
            return tpdos
        by_name = {p.name: p for p in tpdos}
        out = dict(by_name)
        for pname, objects in value.items():
            pkey = _path(key, pname)
            if pname not in by_name:
                self.problem(pkey, _found(pname), f"a TPDO of {eds.path.name}" + _closest(pname, list(by_name)))
                continue
            if not isinstance(objects, list) or not objects:
                self.problem(pkey, _found(objects), "a non-empty list of objects ('0x6041', '0x6077:0')")
                continue
            refs = [r for i, item in enumerate(objects) if (r := self.resolve(eds, item, f"{pkey}[{i}]")) is not None]
            if len(refs) != len(objects):
                continue
            try:
                out[pname] = override(eds, by_name[pname], refs)
            except EdsError as exc:
                self.problem(pkey, str(exc), "PDO-mappable numbers that fit in 8 bytes")
        return [out[p.name] for p in tpdos]

    def resolve(self, eds: Eds, value: Any, key: str) -> tuple[int, int | None] | None:
        """``value`` (hex ``INDEX[:SUB]`` or a ParameterName) as (index, subindex) of an object of ``eds``."""
        parsed = parse_object(value)
        if parsed is None:
            self.problem(key, _found(value), "an object: INDEX or INDEX:SUB in hex, or its EDS ParameterName")
            return None
        if isinstance(parsed, str):
            var = eds.by_name(parsed)
            if var is None:
                self.problem(key, repr(parsed), f"an object of {eds.path.name} (hex INDEX[:SUB] or ParameterName)")
                return None
            return int(var.index), int(var.subindex)
        if eds.entry(parsed[0]) is None or (parsed[1] is not None and eds.variable(parsed[0], parsed[1]) is None):
            self.problem(key, f"0x{parsed[0]:04X}:{parsed[1] or 0:02X}", f"an object of {eds.path.name}")
            return None
        return parsed

    def source(self, name: str, value: Mapping[str, Any], key: str) -> SourceConfig:
        """A ``kind: current`` source of a drive: the object's value, then the drive's health roles."""
        c = self.checks
        drive = self.drive_of(value.get("canopen"), key)
        if drive is None:
            return SourceConfig(name=name, kind="current", bus="", signals=(), max_age_s=0.5)
        scale = value.get("scale", 1.0)
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale == 0:
            c.problem(_path(key, "scale"), _found(scale), "a finite number other than 0")
            scale = 1.0
        # A TPDO's period is not the heartbeat's: max_age is the value's own; the heartbeat keeps its timeout.
        max_age = c.seconds(value, "max_age", key, drive.timeout_s)
        refs: list[SignalRef] = []
        where = self.tpdo_object(drive, value.get("object"), _path(key, "object"))
        if where is not None:
            pdo, obj = where
            refs.append(self.ref(drive, pdo, "current", f"{name}_current", obj.start_bit, obj.bits,
                                 signed=obj.signed, is_float=obj.is_float, scale=float(scale)))
        refs.extend(self.health_refs(drive, where[0] if where is not None else None))
        return SourceConfig(name=name, kind="current", bus=drive.bus, signals=tuple(refs), max_age_s=max_age)

    def drive_of(self, dname: Any, key: str) -> CanopenDrive | None:
        """The drive ``canopen: NAME`` names; None, with a problem unless that drive's own entry has one."""
        drive = self.drives.get(dname) if isinstance(dname, str) else None
        if drive is None and not (isinstance(dname, str) and dname in self.failed):
            self.problem(_path(key, "canopen"), _found(dname), "a drive of canopen:" + _closest(dname, self.drives))
        return drive

    def tpdo_object(self, drive: CanopenDrive, value: Any, key: str) -> tuple[Pdo, MappedObject] | None:
        """The TPDO that maps ``object:`` and where; else a problem naming the TPDOs and what they map."""
        if value is None:
            self.problem(key, "nothing", "the object the source reads (hex INDEX[:SUB] or ParameterName)")
            return None
        parsed = parse_object(value)
        if isinstance(parsed, str):
            named = [(p, o) for p in drive.enabled_tpdos for o in p.objects if o.name.casefold() == parsed.casefold()]
            if named:
                return named[0]
        elif parsed is not None:
            eds = self._eds[drive.name]
            if parsed[1] is None and hasattr(eds.entry(parsed[0]), "subindices"):
                # a record or array: its sub-index 0 is a count, never a value
                self.problem(key, _found(value), f"a variable, not a whole object: {eds.refusal(parsed[0])}")
                return None
            found = drive.tpdo_of(parsed[0], parsed[1] or 0)
            if found is not None and found[1].name == UNDESCRIBED:
                self.problem(key, f"{found[1].ref}, which {found[0].name} maps but {drive.eds.name} does not "
                             "describe", "an object the EDS describes (its data type gives its size and sign)")
                return None
            if found is not None:
                return found
        mapped = mapped_text(drive.enabled_tpdos)
        off = [p.name for p in drive.tpdos if not p.enabled]
        hint = (f"; {', '.join(off)} disabled in the EDS: map it there with canopen.{drive.name}.pdo "
                "(`canguard init --canopen` writes one)" if off else "")
        self.problem(key, _found(value), f"an object a TPDO of {drive.name} maps ({mapped or 'no TPDO'}{hint})")
        return None

    def health_refs(self, drive: CanopenDrive, near: Pdo | None) -> list[SignalRef]:
        """The drive's health roles; the Fault bit from ``near`` (the source's TPDO) if it can: one frame for both."""
        name, emcy = drive.name, drive.emcy_id
        refs = [self.ref(drive, None, "nmt", f"{name}_nmt_state", 0, 7, cob_id=drive.heartbeat_id,
                         max_age_s=drive.timeout_s)]
        if name not in self._events:  # one source per drive carries the EMCY event's fields
            self._events.add(name)
            refs.append(self.ref(drive, None, "emcy_code", f"{name}_emcy_code", 0, 16, cob_id=emcy))
            refs.append(self.ref(drive, None, "emcy_data", f"{name}_emcy_data", 24, 40, cob_id=emcy))
        refs.append(self.ref(drive, None, "emcy", f"{name}_error_register", 16, 8, cob_id=emcy))
        in_near = near.find(STATUSWORD, 0) if near is not None else None
        status = (near, in_near) if near is not None and in_near is not None else drive.tpdo_of(STATUSWORD, 0)
        if status is not None:
            pdo, obj = status
            refs.append(self.ref(drive, pdo, "fault", f"{name}_fault", obj.start_bit + FAULT_BIT, 1))
        return refs

    def ref(self, drive: CanopenDrive, pdo: Pdo | None, role: str, signal: str, start: int, bits: int, *,
            signed: bool = False, is_float: bool = False, scale: float = 1.0, cob_id: int = 0,
            max_age_s: float | None = None) -> SignalRef:
        """A SignalRef to ``signal`` of the drive's message at ``cob_id`` (a PDO's), noted for :meth:`messages`."""
        from cantools.database.can import Signal
        from cantools.database.conversion import BaseConversion

        if pdo is not None:
            cob_id, label, length = pdo.cob_id, f"{drive.name}_{pdo.name}", pdo.length
        elif cob_id == drive.heartbeat_id:
            label, length = f"{drive.name}_heartbeat", 1
        else:
            label, length = f"{drive.name}_emcy", 8
        signals = self._messages.setdefault((drive.name, cob_id), (label, length, {}))[2]
        conversion = BaseConversion.factory(scale=scale, offset=0, is_float=is_float)
        signals[signal] = Signal(signal, start, bits, "little_endian", is_signed=signed, conversion=conversion)
        return SignalRef(role=role, bus=drive.bus, message=label, frame_id=cob_id, is_extended_id=False, signal=signal,
                         max_age_s=max_age_s)

    def messages(self) -> list[Any]:
        """The cantools messages of every drive frame a source reads (built once every source is read)."""
        from cantools.database.can import Message

        return [Message(frame_id=cob_id, name=label, length=length, signals=list(signals.values()), strict=False,
                        bus_name=self.drives[dname].bus)
                for (dname, cob_id), (label, length, signals) in self._messages.items()]

    def frame(self, value: Mapping[str, Any], key: str) -> FrameSpec | None:
        """``{canopen: left, command: quick_stop}`` (the controlword in its RPDO) or ``{canopen: left, nmt: stop}``."""
        c = self.checks
        c.mapping(value, key, ("canopen", "command", "nmt"), ("canopen",))
        drive = self.drive_of(value.get("canopen"), key)
        if drive is None:
            return None
        if ("command" in value) == ("nmt" in value):
            c.problem(key, "both or neither of command and nmt", "one of command: (CiA 402) or nmt:")
            return None
        if "nmt" in value:
            cs = NMT_COMMANDS.get(value["nmt"]) if isinstance(value["nmt"], str) else None
            if cs is None:
                c.problem(_path(key, "nmt"), _found(value["nmt"]), "one of " + ", ".join(NMT_COMMANDS))
                return None
            return FrameSpec(drive.bus, NMT_ID, bytes([cs, drive.node]), label=f"{drive.name}.nmt_{value['nmt']}")
        command = value["command"]
        word = COMMANDS.get(command) if isinstance(command, str) else None
        if word is None:
            c.problem(_path(key, "command"), _found(command),
                      "one of " + ", ".join(COMMANDS) + _closest(command, COMMANDS))
            return None
        found = drive.command_data(word)
        if found is None:
            mapped = mapped_text(drive.rpdos)
            c.problem(_path(key, "command"), f"{command} for {drive.name}, whose RPDOs do not map 0x6040 "
                      f"({mapped or 'no RPDO'})", "a drive with the controlword in an RPDO")
            return None
        pdo, data = found
        return FrameSpec(drive.bus, pdo.cob_id, data, label=f"{drive.name}.{command}")
