"""DBC files as teams and vendors export them: loaded as cantools loads them without strict checks.

A pre-pass blanks what cantools refuses even when not strict (Vector's ``VECTOR__INDEPENDENT_SIG_MSG``, statements
of a message or signal the file does not define), keeping line numbers. Signals strict mode would refuse (overlapping,
not fitting, multiplexed by one of those) leave their message: an error where the config reads one, else a note.
"""

from __future__ import annotations

import bisect
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cantools

from canguard.config.yamlsrc import Checks, _closest, _found, _path, _shown
from canguard.errors import clip, quote

if TYPE_CHECKING:
    from canguard.config.canopen import CanopenSection

PSEUDO_MESSAGE = "VECTOR__INDEPENDENT_SIG_MSG"
"""The message Vector's tools keep the signals of no message in (DLC 0; cantools refuses what refers to it)."""

_BO = re.compile(r"BO_\s+(\d+)\s+(\w+)\s*:")
_SG = re.compile(r"SG_\s+(\w+)\s*(?:\w+\s*)?:\s*(\d+)\|(\d+)@([01])")
_STRING = r'"(?:[^"\\]|\\.)*"'
_WORD = re.compile(_STRING + r'|;|[^\s";]+')
"""A word of a statement: a string (may span lines and hold ``;``), a ``;``, or a run of anything else."""
_KEYWORD = re.compile(_STRING + r'|^[ \t]*([A-Z][A-Z_]*_)(?=[\s:])', re.MULTILINE)
"""A string (skipped whole), or a keyword that starts a line: a statement (``BO_``, ``SG_``, ``VAL_``, ...)."""
_END = re.compile(_STRING + "|;")


@dataclass(frozen=True)
class SignalProblem:
    """One thing a DBC gets wrong about signals of one message, and where."""

    message: str
    signals: tuple[str, ...]
    text: str  # ``file:line: ...`` naming the signals and the message


@dataclass(frozen=True)
class _SgLine:
    name: str
    start: int
    length: int
    little: bool
    line: int


_NAMING = tuple(t.split() for t in (
    "VAL_ # S", "SIG_VALTYPE_ # S", "SG_MUL_VAL_ # S", "BO_TX_BU_ #", "CM_ BO_ #", "CM_ SG_ # S", 'BA_ " BO_ #',
    'BA_ " SG_ # S', 'BA_REL_ " BU_BO_REL_ * #'))
"""The statements that may name a message the file does not define (cantools refuses them): ``#`` its DBC id,
``S`` a signal, ``"`` a string, ``*`` any word. (cantools ignores a ``BU_SG_REL_`` of an undefined message.)"""
_STATEMENTS = frozenset(t[0] for t in _NAMING)
_WORDS_NAMING = max(len(t) for t in _NAMING)  # the words that name a message and signal (``BA_ "a" SG_ 5 s``)


def _fits(pattern: str, word: str) -> bool:
    if pattern in ('#', '"'):
        return word.isdigit() if pattern == "#" else word.startswith('"')
    return pattern in ("*", "S") or pattern == word


def _named_message(words: list[str]) -> tuple[int, str | None] | None:
    """The DBC message id (and signal name) a statement's words refer to, or None when it names no message."""
    for t in _NAMING:
        if len(words) >= len(t) and all(_fits(p, w) for p, w in zip(t, words, strict=False)):
            return int(words[t.index("#")]), words[t.index("S")] if "S" in t else None
    return None


def _label(words: list[str], dbc_id: int, signal: str | None) -> str:
    """A statement as a note names it: ``VAL_ of signal S of message 1712``."""
    attribute = f" {words[1]}" if words[0] in ("BA_", "BA_REL_") else ""
    of_signal = f" of signal {signal}" if signal is not None else ""
    return f"{words[0]}{attribute}{of_signal} of message {dbc_id}"


class _Prepass:
    """Finds the messages, signals and statements of a DBC text, and blanks what cantools would refuse."""

    def __init__(self, text: str, display: str) -> None:
        self.text = text
        self.display = display
        self.newlines = [m.start() for m in re.finditer("\n", text)]
        self.blank: list[tuple[int, int]] = []

    def line(self, pos: int) -> int:
        return bisect.bisect_right(self.newlines, pos - 1) + 1

    def line_end(self, pos: int) -> int:
        end = self.text.find("\n", pos)
        return len(self.text) if end < 0 else end

    def run(self) -> tuple[str, list[str], dict[int, list[_SgLine]]]:
        """The text cantools is given, the notes, and each message's ``SG_`` lines by DBC id."""
        notes: list[str] = []
        signal_lines: dict[int, list[_SgLine]] = {}
        messages: dict[int, str] = {}
        statements: list[tuple[int, int, list[str], tuple[int, str | None]]] = []
        current: int | None = None
        pseudo: list[int] = []  # the first and last position of the pseudo-message, then its signal count
        for found in _KEYWORD.finditer(self.text):
            tok = found.group(1)
            if tok is None:  # a string: whatever it holds starts no statement
                continue
            pos = found.start(1)
            if tok not in ("BO_", "SG_"):
                if tok in _STATEMENTS:
                    self.statement(pos, statements)
                current = None  # the next statement: the message's SG_ lines are over
                continue
            m = (_BO if tok == "BO_" else _SG).match(self.text, pos, self.line_end(pos))
            if m is None:
                continue
            if tok == "BO_":
                current = int(m.group(1))
                messages[current] = m.group(2)
                signal_lines[current] = []
                if m.group(2) == PSEUDO_MESSAGE:
                    pseudo = [pos, self.line_end(pos), 0]
            elif current is not None:
                signal_lines[current].append(_SgLine(
                    m.group(1), int(m.group(2)), int(m.group(3)), m.group(4) == "1", self.line(pos)))
                if messages[current] == PSEUDO_MESSAGE:
                    pseudo[1:] = [self.line_end(pos), pseudo[2] + 1]
        defined = {k: {s.name for s in v} for k, v in signal_lines.items() if messages[k] != PSEUDO_MESSAGE}
        if pseudo:
            self.blank.append((pseudo[0], pseudo[1]))
            notes.append(f"{self.display}:{self.line(pseudo[0])}: skipped BO_ {PSEUDO_MESSAGE} "
                         f"(Vector's pseudo-message for the signals of no message; signals: {pseudo[2]})")
        for start, stop, words, (dbc_id, signal) in statements:
            why = self.refused(dbc_id, signal, defined, messages)
            if why:
                self.blank.append((start, stop))
                notes.append(f"{self.display}:{self.line(start)}: skipped {_label(words, dbc_id, signal)}: {why}")
        return self.blanked(), notes, signal_lines

    def statement(self, pos: int, statements: list[tuple[int, int, list[str], tuple[int, str | None]]]) -> None:
        """Keep the statement starting at ``pos`` (up to its ``;``) when it names a message."""
        words: list[str] = []
        for w in _WORD.finditer(self.text, pos):  # the first words tell (a keyword alone names nothing)
            if w.group() == ";" or len(words) == _WORDS_NAMING:
                break
            words.append(w.group())
        ref = _named_message(words)
        if ref is None:
            return
        for m in _END.finditer(self.text, pos):
            if m.group() == ";":
                statements.append((pos, m.end(), words, ref))
                return

    @staticmethod
    def refused(dbc_id: int, signal: str | None, defined: dict[int, set[str]], messages: dict[int, str]) -> str:
        """Why a statement naming ``dbc_id`` (and ``signal``) is skipped (the file does not define it), or ''."""
        if dbc_id not in defined:
            if messages.get(dbc_id) == PSEUDO_MESSAGE:
                return f"it belongs to {PSEUDO_MESSAGE}, Vector's pseudo-message for the signals of no message"
            return f"the file defines no message of that id (0x{dbc_id & 0x1FFFFFFF:X})"
        if signal is not None and signal not in defined[dbc_id]:
            return f"message {messages[dbc_id]} has no signal {signal}"
        return ""

    def blanked(self) -> str:
        """The text with each blanked range's characters turned to spaces, its line breaks kept."""
        chars = list(self.text) if self.blank else []
        for start, stop in self.blank:  # ranges may overlap (a statement without its ';' runs into the next)
            chars[start:stop] = re.sub(r"[^\n]", " ", self.text[start:stop])
        return "".join(chars) if self.blank else self.text


def _bits(signal: Any) -> int:
    """The bits ``signal`` covers as a mask over the payload (bit ``8 * byte + bit``, as the DBC numbers them)."""
    length = int(signal.length)
    start = int(signal.start)
    if signal.byte_order == "little_endian":
        return ((1 << length) - 1) << start
    mask = 0
    pos = start
    for _ in range(length):  # Motorola: from the most significant bit down, then on into the next byte
        mask |= 1 << pos
        pos = pos + 15 if pos % 8 == 0 else pos - 1
    return mask


def _first_last(mask: int) -> tuple[int, int]:
    return (mask & -mask).bit_length() - 1, mask.bit_length() - 1


def _pages(signal: Any, by_name: dict[str, list[Any]]) -> dict[str, frozenset[int]]:
    """The multiplexer values that select ``signal``, per multiplexer up its chain."""
    out: dict[str, frozenset[int]] = {}
    seen = 0
    while signal.multiplexer_signal is not None and seen < 64:
        out[signal.multiplexer_signal] = frozenset(signal.multiplexer_ids or ())
        parents = by_name.get(signal.multiplexer_signal, [])
        if len(parents) != 1:
            break
        signal = parents[0]
        seen += 1
    return out


def _exclusive(a: dict[str, frozenset[int]], b: dict[str, frozenset[int]]) -> bool:
    """Whether two signals are never in one payload: pages of one multiplexer that share no value."""
    return any(not (ids & b[mux]) for mux, ids in a.items() if mux in b)


class _MessageCheck:
    """The strict checks of one loaded message, with the file and line of each signal."""

    def __init__(self, message: Any, lines: list[_SgLine], display: str) -> None:
        self.message = message
        self.display = display
        self.lines = lines
        self.taken: set[int] = set()
        self.problems: list[SignalProblem] = []
        self.broken: set[int] = set()  # id() of each signal taken out
        self.pages: list[SignalProblem] = []  # multiplexer values that select only signals taken out

    def line(self, signal: Any) -> int:
        """The line of ``signal``'s ``SG_`` line (0 when the format has no lines)."""
        where = (signal.start, signal.length, signal.byte_order == "little_endian")
        match = [k for k, s in enumerate(self.lines) if (s.start, s.length, s.little) == where]
        named = [k for k in match if self.lines[k].name == signal.name] or match
        free = [k for k in named if k not in self.taken] or named
        if not free:
            return 0
        self.taken.add(free[0])
        return self.lines[free[0]].line

    def add(self, signals: Iterable[Any], text: str, *, take_out: bool = True) -> None:
        """Record a problem of ``signals``; ``take_out``: they leave the message."""
        signals = list(signals)
        if take_out:
            self.broken.update(id(s) for s in signals)
        self.problems.append(SignalProblem(self.message.name, tuple(s.name for s in signals), text))

    def run(self) -> list[Any]:
        """Record every problem of the message; the sound signals, in the message's order."""
        m = self.message
        signals = list(m.signals)
        lines = {id(s): self.line(s) for s in signals}
        where = {k: f"{self.display}:{n}" if n else self.display for k, n in lines.items()}
        by_name: dict[str, list[Any]] = {}
        for s in signals:
            by_name.setdefault(s.name, []).append(s)
        for name, same in by_name.items():
            if len(same) > 1:
                same = sorted(same, key=lambda s: lines[id(s)])
                others = ", ".join(where[id(s)] for s in same[1:])
                # cantools decodes and encodes both (one value under the name); only a multiplexer of two names
                # leaves its pages unknown
                self.add(same, f"{where[id(same[0])]}: signal {name} is defined {len(same)} times in message "
                               f"{m.name} (again at {others})", take_out=any(s.is_multiplexer for s in same))
        masks = {id(s): _bits(s) for s in signals}
        size_bits = 8 * int(m.length)
        for s in signals:
            if masks[id(s)] >> size_bits:
                first, last = _first_last(masks[id(s)])
                self.add([s], f"{where[id(s)]}: signal {s.name} (bits {first}..{last}) does not fit in message "
                              f"{m.name} ({m.length} bytes)")
        pages = {id(s): _pages(s, by_name) for s in signals}
        for j, a in enumerate(signals):
            for b in signals[j + 1:]:
                shared = masks[id(a)] & masks[id(b)]
                if shared and not _exclusive(pages[id(a)], pages[id(b)]):
                    first, last = _first_last(shared)
                    self.add([a, b], f"{where[id(a)]}: signals {a.name} and {b.name} ({where[id(b)]}) overlap in "
                                     f"message {m.name} (bits {first}..{last})")
        self.orphans(signals, by_name, where)
        sound = [s for s in signals if id(s) not in self.broken]
        self.emptied(signals, sound, where)
        return sound

    def emptied(self, signals: list[Any], sound: list[Any], where: dict[int, str]) -> None:
        """Multiplexer pages only signals taken out were on: cantools refuses a frame on them."""
        for mux in sound:
            if not mux.is_multiplexer:
                continue
            before = {i for s in signals if s.multiplexer_signal == mux.name for i in s.multiplexer_ids or ()}
            after = {i for s in sound if s.multiplexer_signal == mux.name for i in s.multiplexer_ids or ()}
            if before - after:
                values = ", ".join(str(i) for i in sorted(before - after))
                self.pages.append(SignalProblem(
                    self.message.name, (),
                    f"{where[id(mux)]}: multiplexer {mux.name} of message {self.message.name} = {values} selects "
                    "only signals left out, so no frame on it decodes"))

    def orphans(self, signals: list[Any], by_name: dict[str, list[Any]], where: dict[int, str]) -> None:
        """Signals multiplexed by a signal that is left out are left out too (their page cannot be told)."""
        changed = True
        while changed:
            changed = False
            for s in signals:
                mux = s.multiplexer_signal
                if id(s) in self.broken or mux is None:
                    continue
                parents = by_name.get(mux, [])
                if len(parents) != 1 or id(parents[0]) in self.broken:
                    self.add([s], f"{where[id(s)]}: signal {s.name} is multiplexed by {mux}, which is left out "
                                  f"of message {self.message.name}")
                    changed = True


@dataclass
class DbcFile:
    """One loaded database file: cantools' database with its unsound signals taken out, and what was found."""

    path: Path
    database: Any
    notes: list[str]  # what the pre-pass skipped
    problems: list[SignalProblem]
    dropped: dict[str, list[Any]]  # per message name: the signals taken out of it
    pages: list[SignalProblem]


def load_dbc_file(path: Path) -> DbcFile:
    """Load a database file as cantools does without strict checks (a ``.dbc`` after the pre-pass), then check it."""
    shown = str(path)
    if path.suffix.lower() == ".dbc":
        # cantools reads a DBC as cp1252, a byte it cannot decode replaced
        with path.open(encoding="cp1252", errors="replace") as f:
            raw = f.read()
        text, notes, lines = _Prepass(raw, shown).run()
        db: Any = cantools.database.load_string(text, database_format="dbc", strict=False)
    else:
        db = cantools.database.load_file(str(path), strict=False)
        notes, lines = [], {}
    loaded = DbcFile(path, db, notes, [], {}, [])
    for m in db.messages:
        dbc_id = m.frame_id | (0x80000000 if m.is_extended_frame else 0)
        check = _MessageCheck(m, lines.get(dbc_id, []), shown)
        sound = check.run()
        if check.problems:
            loaded.problems.extend(check.problems)
            loaded.pages.extend(check.pages)
            loaded.dropped[m.name] = [s for s in m.signals if id(s) in check.broken]
            m.signals[:] = sound  # cantools' documented way: change the signals, then refresh()
            m.refresh()
    return loaded


def _not_loaded(path: Path, exc: Exception) -> str:
    """Why a DBC file did not load, printable and short: binary data is named as such, not echoed."""
    try:
        with path.open("rb") as f:
            head = f.read(4096)
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
        self.ok = False  # the DBC files loaded (else no message is looked up: their problems are recorded)
        self.by_name: dict[str, Any] = {}
        self._by_id: dict[int, list[Any]] = {}
        self.canopen: CanopenSection | None = None

    def load_dbc(self, value: Any) -> tuple[Path, ...]:
        """Load ``dbc:`` (one path or a list): a problem for each file that does not load, and for clashes."""
        if isinstance(value, str):
            value = [value]
        if not isinstance(value, list) or not value:
            self.problem("dbc", _found(value), "a DBC file path or a non-empty list of them")
            return ()
        files = self.dbc_files(value)
        if len(self.dbcs) != len(value):
            return files
        where: dict[str, Path] = {}
        ids: dict[tuple[int, bool], tuple[str, Path]] = {}
        before = len(self.checks.problems)
        for f in self.dbcs:
            for m in f.database.messages:
                key = (m.frame_id, bool(m.is_extended_frame))
                if m.name in where:
                    self.problem("dbc", f"message {m.name!r} in both {where[m.name]} and {f.path}",
                                 "unique message names")
                elif key in ids:
                    other, op = ids[key]
                    self.problem("dbc", f"frame id 0x{m.frame_id:X} as {other!r} in {op} and as {m.name!r} in {f.path}",
                                 "unique frame ids")
                else:
                    where[m.name], ids[key] = f.path, (m.name, f.path)
        if len(self.checks.problems) > before:
            return files
        if len(self.dbcs) == 1:
            self.database = self.dbcs[0].database
        else:
            messages = [m for f in self.dbcs for m in f.database.messages]
            nodes = [n for f in self.dbcs for n in f.database.nodes]
            # not strict, as each file loaded: two signals of one name stay in their message
            self.database = cantools.database.can.Database(messages=messages, nodes=nodes, strict=False)
        self._index(self.database.messages)
        self.ok = True
        return files

    def dbc_files(self, value: list[Any]) -> tuple[Path, ...]:
        """Each file of ``dbc:``, each that loads in :attr:`dbcs` (a problem for each that does not)."""
        files: list[Path] = []
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
                self.dbcs.append(loaded)
        return tuple(files)

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
        """:meth:`signal`, for a source to read: also a problem when some of the message's frames do not decode."""
        sig = self.signal(message, value, key)
        lost = [p for f in self.dbcs for p in f.pages if p.message == message.name] if sig is not None else []
        if lost:
            why = "; ".join(p.text for p in lost)
            self.problem(key, f"{value!r}, of a message whose frames do not all decode ({why})",
                         "a signal of a message whose every frame decodes (fix the DBC, or read another message)")
            return None
        return sig
