"""An EDS or DCF as drive vendors publish it, read with the ``canopen`` library for one node id.

Scanned first for each section's line (errors name ``file:line [6077]``) and for deviations outside the
object dictionary (a malformed ``[Comments]``, an incomplete ``[DummyUsage]``, unknown keys): noted in
:attr:`Eds.notes` (``canguard check -v``), not refused.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

DEVICE_TYPE = 0x1000
PROFILES = {
    401: "CiA 401 (generic I/O module)", 402: "CiA 402 (drive and motion control)",
    404: "CiA 404 (measuring device / closed-loop controller)", 406: "CiA 406 (encoder)",
    410: "CiA 410 (inclinometer)", 418: "CiA 418 (battery module)", 419: "CiA 419 (battery charger)",
}
"""Device profiles by number (0x1000 bits 0..15): what ``init`` names a device that is not a drive."""
DISABLED = 0x80000000
"""A PDO COB-ID's bit 31: the PDO is not valid (the drive does not send or take it)."""
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
    keys: dict[str, int]
    """Key (as written) -> line (its first)."""
    again: list[int]
    """Lines of keys written again."""

    @property
    def is_object(self) -> bool:
        """True for a section of the object dictionary (``[6077]``, ``[1A00sub1]``, ``[1003Name]``...)."""
        return _OBJECT_SECTION.fullmatch(self.name) is not None


def _scan(text: str) -> tuple[list[_Section], list[str]]:
    """The sections of an INI text with their lines and keys, and the text's lines."""
    lines = text.splitlines()
    sections: list[_Section] = []
    for no, line in enumerate(lines, 1):
        s = line.strip()
        if not s or s[0] in ";#":
            continue
        if s.startswith("[") and "]" in s:
            sections.append(_Section(s[1:s.index("]")].strip(), no, {}, []))
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
        self.notes: list[str] = []
        """Deviations tolerated while reading."""
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
        except Exception as exc:  # configparser and the canopen library raise many kinds
            raise EdsError(self._load_error(exc)) from exc

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

    def _load_error(self, exc: Exception) -> str:
        """The library's error, with the file and line of the section it names."""
        section = getattr(exc, "section", None)
        if section is None:
            m = re.search(r"section:? '?\[?([0-9A-Za-z_]+)", str(exc))
            section = m.group(1) if m else None
        where = self.where_section(str(section)) if section else str(self.path)
        return f"{where}: does not load as an EDS ({type(exc).__name__}: {exc})"

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
        try:
            return self.od[index]
        except KeyError:
            return None

    def variable(self, index: int, subindex: int = 0) -> Any:
        """The OD variable ``index:subindex`` (or the variable ``index`` itself), or None."""
        entry = self.entry(index)
        if entry is None:
            return None
        if not hasattr(entry, "subindices"):
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

    def pdo_value(self, index: int, subindex: int | None) -> Any:
        """The variable ``index[:subindex]`` when it can be a PDO value; else :class:`EdsError` saying where and why
        (a record or array without a sub-index, ``PDOMapping=0``, strings and domains)."""
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
