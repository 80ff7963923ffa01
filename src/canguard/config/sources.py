"""DBC files, messages, signals and the sources that read them."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import cantools

from canguard.config.dbc import DbcFile, SignalProblem, load_dbc_file
from canguard.config.schema import NON_VALUE_ROLES, SignalRef, SourceConfig, SourceKind
from canguard.config.yamlsrc import Checks, _closest, _found, _path, _shown
from canguard.errors import clip, quote

if TYPE_CHECKING:
    from canguard.config.canopen import CanopenSection

_SNIFF_BYTES = 4096
"""How much of a DBC that does not load is looked at to tell binary data from a text with a syntax error."""


def _not_loaded(path: Path, exc: Exception) -> str:
    """Why a DBC file did not load, printable and short: binary data is named as such, not echoed."""
    try:
        with path.open("rb") as f:
            head = f.read(_SNIFF_BYTES)
    except OSError as err:
        return f"cannot be read ({err.strerror or err})"
    text = head.decode("utf-8", errors="replace")
    odd = sum(1 for c in text if c == "\ufffd" or (not c.isprintable() and c not in "\t\r\n"))
    if b"\0" in head or odd > len(text) // 20:
        start = quote(head.decode("utf-8", "backslashreplace"), 40)
        return f"is not a DBC file: binary data, not text (it starts {start})"
    return f"does not load ({clip(str(exc))})"


class Messages:
    """The messages a source or frame may name: the ``dbc:`` files' and the ``canopen:`` drives'."""

    def __init__(self, checks: Checks) -> None:
        self.checks = checks
        self.problem = checks.problem
        self.database: Any = None
        self.dbcs: list[DbcFile] = []
        """What each DBC file gets wrong: errors where the config reads it, notes elsewhere."""
        self.ok = False
        """Whether the DBC files loaded (else no message is looked up: their problems are recorded)."""
        self.by_name: dict[str, Any] = {}
        self._by_id: dict[int, list[Any]] = {}
        self.canopen: CanopenSection | None = None
        """The ``canopen:`` drives, when the config has any."""

    def load_dbc(self, value: Any) -> tuple[Path, ...]:
        """Load ``dbc:`` (one path or a list): a problem for each file that does not load, and for clashes."""
        if isinstance(value, str):
            value = [value]
        if not isinstance(value, list) or not value:
            self.problem("dbc", _found(value), "a DBC file path or a non-empty list of them")
            return ()
        files, databases = self.dbc_files(value)
        if len(databases) != len(value):
            return tuple(files)
        where: dict[str, Path] = {}
        ids: dict[tuple[int, bool], tuple[str, Path]] = {}
        before = len(self.checks.problems)
        for p, db in databases:
            for m in db.messages:
                key = (m.frame_id, bool(m.is_extended_frame))
                if m.name in where:
                    self.problem("dbc", f"message {m.name!r} in both {where[m.name]} and {p}", "unique message names")
                elif key in ids:
                    other, op = ids[key]
                    self.problem("dbc", f"frame id 0x{m.frame_id:X} as {other!r} in {op} and as {m.name!r} in {p}",
                                 "unique frame ids")
                else:
                    where[m.name], ids[key] = p, (m.name, p)
        if len(self.checks.problems) > before:
            return tuple(files)
        if len(databases) == 1:
            self.database = databases[0][1]
        else:
            messages = [m for _, db in databases for m in db.messages]
            nodes = [n for _, db in databases for n in db.nodes]
            # not strict, as each file loaded: two signals of one name stay in their message
            self.database = cantools.database.can.Database(messages=messages, nodes=nodes, strict=False)
        self._index(self.database.messages)
        self.ok = True
        return tuple(files)

    def dbc_files(self, value: list[Any]) -> tuple[list[Path], list[tuple[Path, Any]]]:
        """Each file of ``dbc:`` (a problem for each that does not load) and the database of each that does."""
        files: list[Path] = []
        databases: list[tuple[Path, Any]] = []
        for i, item in enumerate(value):
            p = self.checks.file_path(item, f"dbc[{i}]")
            if p is None:
                continue
            files.append(p)
            try:
                loaded = load_dbc_file(p)
            except FileNotFoundError:
                self.problem(f"dbc[{i}]", _shown(item), f"an existing DBC file (no such file: {p})")
            except Exception as exc:  # cantools raises many kinds of parse errors
                self.problem(f"dbc[{i}]", f"{p} which {_not_loaded(p, exc)}", "a valid DBC file")
            else:
                databases.append((p, loaded.database))
                self.dbcs.append(loaded)
        return files, databases

    def add(self, messages: list[Any]) -> None:
        """Add messages made elsewhere (a CANopen drive's PDOs, heartbeat, EMCY) to the config's database."""
        if not messages:
            return
        existing = list(self.database.messages) if self.database is not None else []
        ids = {(m.frame_id, bool(m.is_extended_frame)): m.name for m in existing}
        names = {m.name for m in existing}
        added = []
        for m in messages:
            other = ids.get((m.frame_id, False))
            if other is not None or m.name in names:
                what = f"COB-ID 0x{m.frame_id:03X} of {m.name} also message {other or m.name!r}"
                self.problem("canopen", what, "CANopen frames whose ids and names no other message uses")
                continue
            ids[(m.frame_id, False)], names = m.name, names | {m.name}
            added.append(m)
        if self.database is None:
            self.database = cantools.database.can.Database(messages=added)
        else:
            self.database.messages.extend(added)
            self.database.refresh()
        self._index(added)

    def _index(self, messages: list[Any]) -> None:
        for m in messages:
            self.by_name[m.name] = m
            self._by_id.setdefault(m.frame_id, []).append(m)

    @property
    def notes(self) -> list[str]:
        """Every statement the DBC files skipped and every signal problem, one ``file:line: ...`` line each."""
        return [n for f in self.dbcs for n in (*f.notes, *(p.text for p in (*f.problems, *f.pages)))]

    def involved(self, message: str, signal: str) -> list[SignalProblem]:
        """The problems signal ``signal`` of ``message`` is involved in (none: it is sound, or not in the file)."""
        return [p for f in self.dbcs for p in f.problems if p.message == message and signal in p.signals]

    def lost_pages(self, message: str) -> list[SignalProblem]:
        """The multiplexer values of ``message`` on which its frames no longer decode (none: all decode)."""
        return [p for f in self.dbcs for p in f.pages if p.message == message]

    def dropped(self, message: str) -> list[Any]:
        """The signals the DBC files took out of ``message`` (cantools ``Signal`` objects)."""
        return [s for f in self.dbcs for s in f.dropped.get(message, [])]

    def message(self, mapping: Mapping[str, Any], key: str) -> Any:
        """The cantools message ``mapping``'s ``message:`` names (or numbers); None when left out or after a problem."""
        if "message" not in mapping or not self.ok:
            return None
        value = mapping["message"]
        key = _path(key, "message")
        if isinstance(value, str):
            if value in self.by_name:
                return self.by_name[value]
            text = value.strip().lower()
            try:
                number = int(text, 16) if text.startswith("0x") else int(text, 10)
            except ValueError:
                self.problem(key, _shown(value), "a DBC message name or frame id" + _closest(value, self.by_name))
                return None
            value = number
        if isinstance(value, int) and not isinstance(value, bool):
            found = self._by_id.get(value & 0x1FFFFFFF, [])
            if len(found) == 1:
                return found[0]
            if len(found) > 1:
                names = ", ".join(m.name for m in found)
                self.problem(key, f"frame id 0x{value:X} of several messages ({names})", "a message name")
                return None
            self.problem(key, f"0x{value:X}", "the frame id of a DBC message")
            return None
        self.problem(key, _found(value), "a DBC message name or frame id")
        return None

    def signal(self, message: Any, value: Any, key: str) -> Any:
        """The signal ``value`` of ``message``; None after recording a problem (also naming what the DBC gets wrong)."""
        names = [s.name for s in message.signals]
        involved = self.involved(message.name, value) if isinstance(value, str) else []
        if not involved and value in names:
            return message.get_signal_by_name(value)
        if involved:
            why = "; ".join(p.text for p in involved)
            self.problem(key, f"{value!r}, which the DBC gets wrong ({why})",
                         f"a signal of {message.name} that fits it, shares no bits and has a name of its own")
            return None
        self.problem(key, _found(value), f"a signal of {message.name}" + _closest(value, names))
        return None

    def read_signal(self, message: Any, value: Any, key: str) -> Any:
        """:meth:`signal`, for a source to read: None after a problem, also when some of the message's frames do
        not decode (a multiplexer page of only signals the DBC gets wrong)."""
        sig = self.signal(message, value, key)
        lost = self.lost_pages(message.name) if sig is not None else []
        if lost:
            why = "; ".join(p.text for p in lost)
            self.problem(key, f"{value!r}, of a message whose frames do not all decode ({why})",
                         "a signal of a message whose every frame decodes (fix the DBC, or read another message)")
            return None
        return sig


def _ref(role: str, bus: str, message: Any, signal: Any) -> SignalRef:
    return SignalRef(role, bus, message.name, message.frame_id, bool(message.is_extended_frame), signal.name,
                     unit=signal.unit or None, minimum=None if signal.minimum is None else float(signal.minimum),
                     maximum=None if signal.maximum is None else float(signal.maximum))


def _message_signals(m: Messages, key: str, value: Mapping[str, Any], keys: tuple[str, ...], bus: str
                     ) -> list[SignalRef]:
    """The signals a source of one message reads (``keys``: its kind's, in role order)."""
    msg = m.message(value, key)
    signals: list[SignalRef] = []
    for k in keys:
        if msg is None or k in ("message", "effort") or k not in value:
            continue
        sig = m.read_signal(msg, value[k], _path(key, k))
        if sig is not None:
            signals.append(_ref("current" if k == "signal" else k, bus, msg, sig))
    return signals


def _effort_signals(c: Checks, m: Messages, key: str, value: Mapping[str, Any], bus: str) -> list[SignalRef]:
    """The joints of a ``joints`` source (``effort:``), each a signal named by its joint."""
    effort = value.get("effort")
    if not isinstance(effort, list) or not effort:
        if "effort" in value:
            c.problem(_path(key, "effort"), _found(effort), "a non-empty list of {message, signal, name}")
        return []
    signals: list[SignalRef] = []
    seen: set[str] = set()
    for i, item in enumerate(effort):
        ikey = f"{key}.effort[{i}]"
        if not c.mapping(item, ikey, ("message", "signal", "name", "bus"), ("message", "signal", "name")):
            continue
        jname = item.get("name")
        if "name" in item:
            if not isinstance(jname, str) or not jname or jname in NON_VALUE_ROLES:
                c.problem(_path(ikey, "name"), _found(jname),
                          "a joint name (a string, not " + ", ".join(sorted(NON_VALUE_ROLES)) + ")")
                jname = None
            elif jname in seen:
                c.problem(_path(ikey, "name"), f"{jname!r} again", "a joint name unique in the source")
                jname = None
            else:
                seen.add(jname)
        ibus = c.bus(item, ikey) if "bus" in item else bus
        msg = m.message(item, ikey)
        if msg is None or "signal" not in item:
            continue
        sig = m.read_signal(msg, item["signal"], _path(ikey, "signal"))
        if sig is not None and jname is not None:
            signals.append(_ref(jname, ibus, msg, sig))
    return signals


def source(c: Checks, m: Messages, name: str, value: Any) -> SourceConfig | None:
    """The source ``sources.NAME``; None after a problem."""
    key = _path("sources", name)
    if not isinstance(value, Mapping):
        c.problem(key, _found(value), "a mapping with kind: battery | joints | current")
        return None
    kind = value.get("kind")
    if "canopen" in value:
        return _canopen_source(c, m, name, kind, value, key)
    keys = _KIND_KEYS.get(kind) if isinstance(kind, str) else None
    known = keys is not None
    if keys is None:
        c.problem(_path(key, "kind"), _found(kind), "one of battery, joints, current" + _closest(kind, SOURCE_KINDS))
        # Still check what can be checked without the kind (the source itself is not built).
        keys = ("message", "current", "signal", "present", "counter", "effort")
    c.mapping(value, key, ("kind", "bus", "max_age", *keys), keys[:2] if known else ())
    bus = c.bus(value, key)
    max_age = c.seconds(value, "max_age", key, 0.5)
    signals: list[SignalRef] = []
    if "message" in keys and (known or "message" in value):
        signals.extend(_message_signals(m, key, value, keys, bus))
    if "effort" in keys and (known or "effort" in value):
        signals.extend(_effort_signals(c, m, key, value, bus))
    if not known:
        return None
    return SourceConfig(name=name, kind=cast(SourceKind, kind), bus=bus, signals=tuple(signals), max_age_s=max_age)


def _canopen_source(c: Checks, m: Messages, name: str, kind: Any, value: Mapping[str, Any], key: str
                    ) -> SourceConfig | None:
    """A source reading an object of a ``canopen:`` drive (``kind: current``)."""
    c.mapping(value, key, ("kind", "canopen", "object", "scale", "max_age"), ("kind", "canopen", "object"))
    if kind != "current":
        c.problem(_path(key, "kind"), _found(kind), "current (a source of a canopen: drive)")
        return None
    if m.canopen is None:
        c.problem(_path(key, "canopen"), _found(value.get("canopen")), "a drive of canopen: (none configured)")
        return None
    return m.canopen.source(name, value, key)


class ReadSources(NamedTuple):
    """``sources:`` as read: the sound sources, the names of those with a problem, whether it was a mapping."""

    sources: dict[str, SourceConfig]
    broken: set[str]
    ok: bool


def read_sources(c: Checks, m: Messages, value: Any) -> ReadSources:
    """Every source of ``sources:`` (``value``; None: none), each problem recorded."""
    value = value or {}
    read = ReadSources({}, set(), isinstance(value, Mapping))
    if not read.ok:
        c.problem("sources", _found(value), "a mapping of source name -> source")
    for name, body, _ in c.named(value if read.ok else {}, "sources", "a source name"):
        before = len(c.problems)
        src = source(c, m, name, body)
        if src is not None:
            read.sources[name] = src
        if len(c.problems) > before:
            # Already reported: references to this source must not add follow-on errors.
            read.broken.add(name)
    return read


SOURCE_KINDS: tuple[SourceKind, ...] = ("battery", "joints", "current")
_KIND_KEYS: dict[str, tuple[str, ...]] = {
    "battery": ("message", "current", "present", "counter"), "joints": ("effort",),
    "current": ("message", "signal", "present", "counter")}
"""The keys of each source kind besides kind, bus and max_age (the first two, or the one, required), in role order."""
