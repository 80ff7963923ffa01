"""The loader's ``canopen:`` section: drives from their EDS, sources reading their objects, their frames.

It records its problems in the loader's :class:`~canguard.config.yamlsrc.Checks`; the loader adds
:meth:`CanopenSection.messages` to the config's database.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from canguard.config import canopen as co
from canguard.config.canopen import CanopenDrive, MappedObject, Pdo, SdoWrite
from canguard.config.canopen_eds import Eds, EdsError
from canguard.config.schema import FrameSpec, SignalRef, SourceConfig
from canguard.config.yamlsrc import Checks, _closest, _found, _path

DRIVE_KEYS = ("eds", "node", "bus", "heartbeat", "pdo", "configure", "tpdo_period")
CONFIGURED_HEARTBEAT_S = 0.1
"""The heartbeat canguard tells a drive (``configure: true``) whose entry and EDS give none."""
DEFAULT_TPDO_PERIOD_S = 0.01
"""The event timer canguard gives a ``pdo:`` TPDO it configures (``tpdo_period:``)."""


class CanopenSection:
    """``canopen:`` drives and what sources and frames take from them."""

    def __init__(self, checks: Checks) -> None:
        self.checks = checks
        self.problem = checks.problem
        self.drives: dict[str, CanopenDrive] = {}
        self._signals: dict[tuple[str, int], dict[str, Any]] = {}
        """Per (drive, COB-ID): signal name -> cantools Signal, for the messages built at the end."""
        self._labels: dict[tuple[str, int], tuple[str, int]] = {}
        """Per (drive, COB-ID): (message name, payload length)."""
        self.failed: set[str] = set()
        """Drives whose entry has a problem: their sources and frames add no follow-on errors."""
        self._eds: dict[str, Eds] = {}
        self._events: set[str] = set()
        """Drives one of whose sources already carries the EMCY event roles."""

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
            tpdos, rpdos = co.drive_pdos(eds)
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
        setup = self.setup(eds, tpdos, body, key, heartbeat) if configure else ()
        if "tpdo_period" in body and not configure:
            c.problem(_path(key, "tpdo_period"), f"{body['tpdo_period']!r} without configure: true",
                      "configure: true with it (the period is what canguard tells the drive)")
        notes = [*eds.notes, *eds.foreign_cob_ids()]
        told = eds.value(co.PRODUCER_HEARTBEAT)
        if not configure and told != round(heartbeat * 1000):
            notes.append(f"the EDS's 0x1017 producer heartbeat time is {told} ms: the drive must be told "
                         f"{round(heartbeat * 1000)} ms (configure: true does)")
        notes += [f"{pdo.name} is a pdo: override: the drive must be told its mapping and COB-ID (configure: true does)"
                  for pdo in tpdos if pdo.overridden and not configure]
        return CanopenDrive(name=name, eds=path, node=node, bus=bus, heartbeat_s=heartbeat, tpdos=tuple(tpdos),
                            rpdos=tuple(rpdos), defaults=defaults, device=eds.device, setup=setup, notes=tuple(notes))

    def heartbeat(self, eds: Eds, body: Mapping[str, Any], key: str, configure: bool) -> float:
        """``heartbeat:`` (s), else the EDS's 0x1017 (ms) when not 0, else (``configure: true``)
        :data:`CONFIGURED_HEARTBEAT_S`; else a problem, and that as a stand-in (no follow-on errors)."""
        if "heartbeat" in body:
            return self.checks.seconds(body, "heartbeat", key, CONFIGURED_HEARTBEAT_S)
        ms = eds.value(co.PRODUCER_HEARTBEAT)
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

    def setup(self, eds: Eds, tpdos: list[Pdo], body: Mapping[str, Any], key: str,
              heartbeat_s: float) -> tuple[SdoWrite, ...]:
        """``configure: true``: the heartbeat, then each ``pdo:`` override's mapping, COB-ID and event timer."""
        period_s = self.checks.seconds(body, "tpdo_period", key, DEFAULT_TPDO_PERIOD_S)
        period_ms = max(1, min(0xFFFF, round(period_s * 1000)))
        writes = [co.heartbeat_write(heartbeat_s)]
        for pdo in tpdos:
            if pdo.overridden:
                writes += co.pdo_writes(eds, pdo, period_ms)
        return tuple(writes)

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
                out[pname] = co.override(eds, by_name[pname], refs)
            except EdsError as exc:
                self.problem(pkey, str(exc), "PDO-mappable numbers that fit in 8 bytes")
        return [out[p.name] for p in tpdos]

    def resolve(self, eds: Eds, value: Any, key: str) -> tuple[int, int | None] | None:
        """``value`` (hex ``INDEX[:SUB]`` or a ParameterName) as (index, subindex) of an object of ``eds``."""
        parsed = co.parse_object(value)
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
        parsed = co.parse_object(value)
        if isinstance(parsed, str):
            for pdo in drive.enabled_tpdos:
                for obj in pdo.objects:
                    if obj.name.casefold() == parsed.casefold():
                        return pdo, obj
        elif parsed is not None:
            eds = self._eds[drive.name]
            if parsed[1] is None and hasattr(eds.entry(parsed[0]), "subindices"):
                try:
                    eds.pdo_value(parsed[0], None)
                except EdsError as exc:  # a record or array: its sub-index 0 is a count, never a value
                    self.problem(key, _found(value), f"a variable, not a whole object: {exc}")
                    return None
            found = drive.tpdo_of(parsed[0], parsed[1] or 0)
            if found is not None and found[1].name == co.UNDESCRIBED:
                self.problem(key, f"{found[1].ref}, which {found[0].name} maps but {drive.eds.name} does not "
                             "describe", "an object the EDS describes (its data type gives its size and sign)")
                return None
            if found is not None:
                return found
        mapped = co.mapped_text(drive.enabled_tpdos)
        off = [p.name for p in drive.tpdos if not p.enabled]
        hint = (f"; {', '.join(off)} disabled in the EDS: map it there with canopen.{drive.name}.pdo "
                "(`canguard init --canopen` writes one)" if off else "")
        self.problem(key, _found(value), f"an object a TPDO of {drive.name} maps ({mapped or 'no TPDO'}{hint})")
        return None

    def health_refs(self, drive: CanopenDrive, near: Pdo | None) -> list[SignalRef]:
        """The drive's heartbeat, EMCY and (statusword mapped) Fault-bit roles of every source it feeds; the Fault
        bit from ``near`` (the source's own TPDO) when it maps the statusword, so bit and value come in one frame."""
        name, emcy = drive.name, drive.emcy_id
        refs = [self.ref(drive, None, "nmt", f"{name}_nmt_state", 0, 7, cob_id=drive.heartbeat_id,
                         max_age_s=drive.timeout_s)]
        if name not in self._events:  # one source per drive carries the EMCY event's fields
            self._events.add(name)
            refs.append(self.ref(drive, None, "emcy_code", f"{name}_emcy_code", 0, 16, cob_id=emcy))
            refs.append(self.ref(drive, None, "emcy_data", f"{name}_emcy_data", 24, 40, cob_id=emcy))
        refs.append(self.ref(drive, None, "emcy", f"{name}_error_register", 16, 8, cob_id=emcy))
        in_near = near.find(co.STATUSWORD, 0) if near is not None else None
        status = (near, in_near) if near is not None and in_near is not None else drive.tpdo_of(co.STATUSWORD, 0)
        if status is not None:
            pdo, obj = status
            refs.append(self.ref(drive, pdo, "fault", f"{name}_fault", obj.start_bit + co.FAULT_BIT, 1))
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
        self._labels[(drive.name, cob_id)] = (label, length)
        conversion = BaseConversion.factory(scale=scale, offset=0, is_float=is_float)
        self._signals.setdefault((drive.name, cob_id), {})[signal] = Signal(signal, start, bits, "little_endian",
                                                                             is_signed=signed, conversion=conversion)
        return SignalRef(role=role, bus=drive.bus, message=label, frame_id=cob_id, is_extended_id=False, signal=signal,
                         max_age_s=max_age_s)

    def messages(self) -> list[Any]:
        """The cantools messages of every drive frame a source reads (built once every source is read)."""
        from cantools.database.can import Message

        return [Message(frame_id=cob_id, name=self._labels[(dname, cob_id)][0], length=self._labels[(dname, cob_id)][1],
                        signals=list(signals.values()), strict=False, bus_name=self.drives[dname].bus)
                for (dname, cob_id), signals in self._signals.items()]

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
            cs = co.NMT_COMMANDS.get(value["nmt"]) if isinstance(value["nmt"], str) else None
            if cs is None:
                c.problem(_path(key, "nmt"), _found(value["nmt"]), "one of " + ", ".join(co.NMT_COMMANDS))
                return None
            return FrameSpec(drive.bus, co.NMT_ID, bytes([cs, drive.node]), label=f"{drive.name}.nmt_{value['nmt']}")
        command = value["command"]
        word = co.COMMANDS.get(command) if isinstance(command, str) else None
        if word is None:
            c.problem(_path(key, "command"), _found(command),
                      "one of " + ", ".join(co.COMMANDS) + _closest(command, co.COMMANDS))
            return None
        found = drive.command_data(word)
        if found is None:
            mapped = co.mapped_text(drive.rpdos)
            c.problem(_path(key, "command"), f"{command} for {drive.name}, whose RPDOs do not map 0x6040 "
                      f"({mapped or 'no RPDO'})", "a drive with the controlword in an RPDO")
            return None
        pdo, data = found
        return FrameSpec(drive.bus, pdo.cob_id, data, label=f"{drive.name}.{command}")
