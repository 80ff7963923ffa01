"""Read recorded CAN logs as :class:`~canguard.io.frame.Frame` streams; write candump -L logs.

:func:`read_log` picks the reader by file extension (``.gz`` on any of them)::

    .log .candump .txt   candump text: ``candump -L`` / ``-l`` lines (the fast path)
                         or plain ``candump -ta`` output
    .asc .blf .trc .csv  python-can's own readers
    .mf4                 python-can's MF4 reader (needs ``python-can[mf4]``)

Every reader streams: the log is read in chunks of :data:`CHUNK_CHARS` characters
and never held whole, so memory stays flat in the log's length.

The candump -L fast path parses a whole chunk at once with C-level string
operations (one ``translate`` + ``split`` for the chunk, ``map(float)``,
``map(int)``, ``map(bytes.fromhex)`` over columns, frames built with
``tuple.__new__``): no per-line regex and no per-line Python code. A chunk that
does not have the plain shape (CAN FD, remote or error frames, comments, blank
lines, malformed lines, plain candump output) is parsed line by line by the
general parser instead, which knows every case and names the file:line of a bad
line.

Timestamps of python-can formats are what python-can reports: ASC timestamps are
relative to the measurement start (python-can's default), which keeps a replay
independent of the machine's time zone. python-can's integer channels are named
the way python-can's candump writer names them: ``0`` -> ``can0``.
"""

from __future__ import annotations

import gzip
import importlib.util
import io
import math
import operator
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from itertools import islice, repeat
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, TextIO

from canguard.errors import LogFormatError
from canguard.io.frame import Frame
from canguard.io.progress import ProgressBar

if TYPE_CHECKING:
    import can

__all__ = [
    "CANDUMP_SUFFIXES",
    "CHUNK_CHARS",
    "PYTHON_CAN_SUFFIXES",
    "BadLine",
    "Columns",
    "LogFrames",
    "ReadStats",
    "candump_id_texts",
    "format_candump_line",
    "frame_from_message",
    "log_format",
    "read_log",
    "write_candump",
]

CANDUMP_SUFFIXES = (".log", ".candump", ".txt")
PYTHON_CAN_SUFFIXES = (".asc", ".blf", ".trc", ".csv", ".mf4")
_TEXT_PYTHON_CAN = ("asc", "trc", "csv")

CHUNK_CHARS = 1 << 17
"""Characters read per chunk by the candump reader (about 2,800 lines: a block stays in the CPU caches)."""

MAX_BAD_EXAMPLES = 5
"""How many bad lines :class:`ReadStats` keeps as examples."""

CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF
CAN_SFF_MASK = 0x7FF
CANFD_BRS = 0x01
CANFD_ESI = 0x02
CANFD_LENGTHS = frozenset((0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64))

_HEX = "0123456789abcdefABCDEF"
_new = tuple.__new__  # builds a Frame from a ready tuple in C: several times cheaper than Frame(...)
_F = False


class BadLine(NamedTuple):
    """One malformed line: 1-based line number, why it is bad, and its text."""

    lineno: int
    reason: str
    text: str


@dataclass
class ReadStats:
    """What a reader saw; pass one to :func:`read_log` to have it filled in.

    Counts are updated as the log is read (a chunk at a time on the candump fast
    path) and add up when the same object is passed to several calls.
    """

    path: str = ""
    format: str = ""
    lines: int = 0
    """Text lines read, blank and comment lines included (0 for binary formats)."""
    frames: int = 0
    bad_lines: int = 0
    """Malformed lines skipped with ``skip_bad=True``."""
    bad_examples: list[BadLine] = field(default_factory=list)
    """The first :data:`MAX_BAD_EXAMPLES` bad lines."""
    backwards_timestamps: int = 0
    """Frames whose timestamp is earlier than the previous frame's."""
    repeated_timestamps: int = 0
    """Frames whose timestamp equals the previous frame's."""
    bytes_total: int = 0
    """Size of the file on disk (compressed size for ``.gz``)."""
    bytes_read: int = 0
    """Position reached in the file on disk, updated a chunk at a time (drives progress bars)."""

    @property
    def backward(self) -> int:
        """Alias of :attr:`backwards_timestamps`."""
        return self.backwards_timestamps

    @property
    def repeated(self) -> int:
        """Alias of :attr:`repeated_timestamps`."""
        return self.repeated_timestamps


class LogFrames(Iterator[Frame]):
    """The frames of one log, streamed: what :func:`read_log` returns.

    ``for frame in log_frames`` iterates the reader's generator directly (no
    per-frame wrapper cost). ``stats`` is the :class:`ReadStats` being filled;
    ``progress`` (settable until iteration ends) is updated with the file
    position after each chunk and closed when the log has been read.
    """

    def __init__(self, path: Path, stats: ReadStats, progress: ProgressBar | None) -> None:
        self.path = path
        self.stats = stats
        self.progress = progress
        self._frames: Iterator[Frame] = iter(())
        self._chunks: Iterator[Columns | list[Frame]] = iter(())

    def chunks(self) -> Iterator[Columns | list[Frame]]:
        """The same frames a block at a time: :class:`Columns` (plain candump blocks) or lists of frames.

        For consumers that work on whole blocks (the replay engine); use either
        this or the frame iterator, not both.
        """
        return self._chunks

    def __iter__(self) -> Iterator[Frame]:
        return self._frames

    def __next__(self) -> Frame:
        return next(self._frames)

    def _position(self, position: int) -> None:
        self.stats.bytes_read = position
        if self.progress is not None:
            self.progress.update(position)

    def _done(self) -> None:
        if self.progress is not None:
            self.progress.close()


class _Bad(Exception):
    """Raised by the line parsers; carries the reason only (the caller adds file:line)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


# --------------------------------------------------------------------------- format choice


def log_format(path: str | Path) -> tuple[str, bool]:
    """Return ``(format, gzipped)`` for a log path, chosen by extension.

    ``format`` is ``candump``, ``asc``, ``blf``, ``trc``, ``csv`` or ``mf4``.
    Raises :class:`LogFormatError` for an unknown extension.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    gz = suffix == ".gz"
    if gz:
        suffix = Path(p.stem).suffix.lower()
    if suffix in CANDUMP_SUFFIXES:
        return "candump", gz
    if suffix in PYTHON_CAN_SUFFIXES:
        return suffix[1:], gz
    known = ", ".join(CANDUMP_SUFFIXES + PYTHON_CAN_SUFFIXES)
    raise LogFormatError(
        f"{p}: unknown log format {(suffix or p.name)!r}: expected one of {known} (optionally + .gz)"
    )


def read_log(
    path: str | Path,
    *,
    skip_bad: bool = False,
    stats: ReadStats | None = None,
    progress: ProgressBar | None = None,
) -> LogFrames:
    """Stream the frames of a recorded log, in file order.

    The path, extension and (for ``.mf4``) the optional dependency are checked at
    once, when this is called; the log itself is read lazily as the returned
    iterator is consumed, a chunk at a time.

    A malformed candump line raises :class:`LogFormatError` naming
    ``file:line``, the reason and the line's text; with ``skip_bad=True`` it is
    counted in ``stats`` instead and skipped. A log with no frame at all raises
    :class:`LogFormatError` when the iterator reaches its end. Errors inside
    python-can's readers (corrupt BLF, bad ASC...) are re-raised as
    :class:`LogFormatError` naming the file (they cannot be skipped).
    ``progress``, when given, is updated with the file position after each chunk
    and closed at the end (see also :func:`canguard.io.progress.wrap_progress`).

    Raises :class:`LogFormatError` for an unknown extension, a missing file, a
    directory, or a missing optional dependency.
    """
    p = Path(path)
    fmt, gz = log_format(p)
    if not p.exists():
        raise LogFormatError(f"{p}: no such file")
    if not p.is_file():
        raise LogFormatError(f"{p}: not a regular file")
    if fmt == "mf4" and importlib.util.find_spec("asammdf") is None:
        raise LogFormatError(f"{p}: reading .mf4 logs needs asammdf: pip install 'python-can[mf4]'")
    st = stats if stats is not None else ReadStats()
    st.path = str(p)
    st.format = fmt + (".gz" if gz else "")
    try:
        st.bytes_total += p.stat().st_size
    except OSError as exc:
        raise LogFormatError(f"{p}: cannot read: {exc.strerror or exc}") from None
    frames = LogFrames(p, st, progress)
    if fmt == "candump":
        frames._chunks = _candump_chunks(p, gz, skip_bad, st, stats is not None, frames)
        frames._frames = _flatten(frames._chunks)
    else:
        frames._frames = _read_python_can(p, fmt, gz, st, frames)
        frames._chunks = _batches(frames._frames)
    return frames


# --------------------------------------------------------------------------- candump text


_BULK_TABLE = str.maketrans({"(": None, ")": None, " ": "#", "\n": "#"})
_MARKERS = frozenset("TRtr")
_HEX_BYTES = b"0123456789abcdefABCDEF"
_TS_BYTES = b"0123456789."
_DATA_LENGTHS = frozenset(range(0, 17, 2))


class Columns(NamedTuple):
    """A block of plain candump -L lines, checked, kept as text columns: frames are built on demand.

    Every line has passed the checks the line parser would make; what is left is
    conversion, which costs only for the rows somebody asks for (:meth:`frame`)
    or for all of them (:meth:`frames`). ``ts`` are the timestamp texts, all of
    one width with the dot at one place, so text order is time order;
    ``ordered`` is True when they never go back (in the block) and distinct texts
    are distinct floats. ``ids`` are the id texts as written (3 hex digits:
    standard, 8: extended; any case).
    """

    n: int
    ts: list[str]
    chans: list[str]
    ids: list[str]
    data: list[str]
    ordered: bool
    channel: str | None
    """The channel of every row, or None when the block has several."""

    def frame(self, i: int) -> Frame:
        """The frame of row ``i``."""
        id_text = self.ids[i]
        return _new(Frame, (float(self.ts[i]), self.chans[i], int(id_text, 16), bytes.fromhex(self.data[i]),
                            len(id_text) == 8, _F, _F, _F, _F, _F, -1))

    def frames(self) -> Iterator[Frame]:
        """The frames of every row, in order (converted in C-level passes over the columns)."""
        ext = map((8).__eq__, map(len, self.ids))
        return map(
            _new,
            repeat(Frame),
            zip(map(float, self.ts), self.chans, map(int, self.ids, repeat(16)), map(bytes.fromhex, self.data),
                ext, repeat(_F), repeat(_F), repeat(_F), repeat(_F), repeat(_F), repeat(-1)),
        )


def candump_id_texts(arbitration_id: int, is_extended_id: bool) -> list[str]:
    """Every way candump -L may write an id: 3 (standard) or 8 (extended) hex digits, letters in any case."""
    text = f"{arbitration_id:08X}" if is_extended_id else f"{arbitration_id:03X}"
    variants = [""]
    for ch in text:
        cases = {ch.upper(), ch.lower()}
        variants = [v + c for v in variants for c in sorted(cases)]
    return variants


def _bulk_columns(block: str, n: int) -> Columns | None:
    """Check ``n`` candump -L lines of plain shape at once, or return None if any line is not plain.

    Plain shape: ``(secs.usecs) channel ID#HEX`` with an optional T/R marker on
    every line, timestamps of one width (digits, one dot), 3- or 8-digit ids,
    classic data of at most 8 bytes, no error frame. Nothing is returned unless
    every line passed, so a None costs no frame. Each check is one C-level pass
    over a column; nothing is converted here.
    """
    if not block.isascii() or "\t" in block or block.count("(") != n:
        return None
    plain = block.translate(_BULK_TABLE)
    if len(block) - len(plain) != 2 * n:  # n "(" were deleted: then n ")" too, no more, no less
        return None
    tok = plain.split("#")
    k, r = divmod(len(tok) - 1, n)
    if r or not 4 <= k <= 5:
        return None
    if k == 5 and not set(tok[4:-1:5]) <= _MARKERS:
        return None
    ts = tok[0:-1:k]
    width = len(ts[0])
    dot = ts[0].find(".")
    if not 0 < dot < width - 1 or set(map(len, ts)) != {width}:
        return None
    joined = "".join(ts).encode()
    # n dots in all, one at the same place in each: one per timestamp; the rest digits
    if joined.count(b".") != n or joined[dot::width].count(b".") != n or joined.translate(None, _TS_BYTES):
        return None
    ids = tok[2:-1:k]
    # a busy bus has a few dozen distinct ids in a block: check those, not every row
    for text in set(ids):
        size = len(text)
        if size == 3:
            if text[0] > "7" or not _is_hex(text):  # standard ids go up to 7FF
                return None
        elif size != 8 or text[0] > "1" or not _is_hex(text):  # extended: 1FFFFFFF; above: error frames
            return None
    data = tok[3:-1:k]
    if not set(map(len, data)) <= _DATA_LENGTHS or "".join(data).encode().translate(None, _HEX_BYTES):
        return None
    ordered = all(map(operator.le, ts, islice(ts, 1, None))) and math.ulp(float(ts[-1])) < 10.0 ** (dot + 1 - width)
    chans = tok[1:-1:k]
    first = chans[0]
    if first.strip(_HEX + ".") and first not in _MARKERS:
        # a name no other token can equal (timestamps: digits and a dot; ids, data: hex; markers)
        single = plain.count(f"#{first}#") == n
    else:
        single = chans.count(first) == n
    return Columns(n, ts, chans, ids, data, ordered, first if single else None)


def _is_hex(s: str) -> bool:
    """True for a non-empty string of hex digits only."""
    return bool(s) and not s.strip(_HEX)


def _hex_data(text: str) -> bytes:
    if len(text) % 2:
        raise _Bad(f"odd number of hex digits in data {text!r}")
    if text and not _is_hex(text):
        raise _Bad(f"data {text!r} is not hex")
    return bytes.fromhex(text)


def _parse_id(text: str) -> tuple[int, bool, bool]:
    """``(arbitration_id, is_extended_id, is_error_frame)`` of a candump id field."""
    if len(text) not in (3, 8) or not _is_hex(text):
        raise _Bad(f"bad CAN id {text!r}: expected 3 (standard) or 8 (extended) hex digits")
    cid = int(text, 16)
    if len(text) == 3:
        if cid > CAN_SFF_MASK:
            raise _Bad(f"standard CAN id {text!r} is above 7FF")
        return cid, False, False
    if cid & CAN_ERR_FLAG:
        return cid & CAN_EFF_MASK, True, True
    if cid > CAN_EFF_MASK:
        raise _Bad(f"extended CAN id {text!r} is above 1FFFFFFF")
    return cid, True, False


def _parse_timestamp(text: str) -> float:
    sec, dot, frac = text.partition(".")
    if sec.isdigit() and sec.isascii() and (not dot or (frac.isdigit() and frac.isascii())):
        return float(text)
    if " " in text or ":" in text:
        raise _Bad("absolute date timestamps (candump -tA) are not supported: record with candump -ta or -L")
    raise _Bad(f"bad timestamp {text!r}: expected (seconds.microseconds)")


def _parse_compact(t: float, channel: str, text: str) -> Frame:
    """One ``ID#DATA`` field of candump -L: classic, FD (``##F``), remote (``R``/``R8``), error."""
    id_text, sep, d = text.partition("#")
    if not sep:
        raise _Bad("expected ID#DATA")
    cid, ext, err = _parse_id(id_text)
    if d[:1] == "#":
        if d[1:2] == "#":
            raise _Bad("CAN XL frames are not supported")
        if len(d) < 2 or not _is_hex(d[1]):
            raise _Bad("CAN FD frame needs one hex flags digit after '##'")
        flags = int(d[1], 16)
        data = _hex_data(d[2:])
        if len(data) not in CANFD_LENGTHS:
            raise _Bad(f"{len(data)} data bytes is not a CAN FD length")
        brs, esi = bool(flags & CANFD_BRS), bool(flags & CANFD_ESI)
        return _new(Frame, (t, channel, cid, data, ext, True, err, False, brs, esi, -1))
    if d[:1] in ("R", "r"):
        dlc_text = d[1:]
        if not dlc_text:
            dlc = -1
        elif len(dlc_text) == 1 and dlc_text in "012345678":
            dlc = int(dlc_text) or -1
        else:
            raise _Bad(f"bad remote frame DLC {dlc_text!r}: expected one digit 0-8")
        return _new(Frame, (t, channel, cid, b"", ext, False, err, True, False, False, dlc))
    data_text, underscore, raw_dlc = d.partition("_")
    data = _hex_data(data_text)
    if len(data) > 8:
        raise _Bad(f"{len(data)} data bytes in a classic CAN frame (at most 8; CAN FD frames use '##')")
    dlc = -1
    if underscore:
        # candump's len8_dlc: 8 data bytes with a raw DLC of 9..F
        if len(data) != 8 or len(raw_dlc) != 1 or raw_dlc not in "9ABCDEFabcdef":
            raise _Bad(f"bad raw DLC suffix '_{raw_dlc}': expected _9 .. _F after 8 data bytes")
        dlc = int(raw_dlc, 16)
    return _new(Frame, (t, channel, cid, data, ext, False, err, False, False, False, dlc))


_SHAPE = "expected '(secs) channel ID#DATA' (candump -L) or '(secs) channel ID [len] DATA' (candump -ta)"


def _parse_long(t: float | None, ts_text: str, toks: list[str]) -> Frame:
    """One line of plain candump output: ``can0  123   [8]  11 22 ...`` with a -ta timestamp."""
    i = 1
    brs = esi = False
    if len(toks) > 4 and toks[1] in ("RX", "TX"):  # candump -x: direction and B/E flag columns
        brs, esi, i = toks[2] == "B", toks[3] == "E", 4
    if len(toks) < i + 2:
        raise _Bad(_SHAPE)
    len_tok = toks[i + 1]
    if len(len_tok) < 3 or len_tok[0] != "[" or len_tok[-1] != "]":
        raise _Bad(_SHAPE)
    if t is None:
        raise _Bad("plain candump output without timestamps is not supported: record with candump -ta or -L")
    if len(ts_text.partition(".")[0]) < 10:
        raise _Bad("relative timestamps (candump -td / -tz) are not supported: record with candump -ta or -L")
    len_text = len_tok[1:-1]
    if not (len_text.isdigit() and len_text.isascii()):
        raise _Bad(f"bad length {len_tok!r}")
    length = int(len_text)
    is_fd = len(len_text) == 2  # candump prints [%d] for classic CAN, [%02d] for CAN FD
    cid, ext, err = _parse_id(toks[i])
    channel = toks[0]
    rest = toks[i + 2 :]
    if rest[:2] == ["remote", "request"]:
        if len(rest) != 2 or is_fd or length > 8:
            raise _Bad("bad remote request")
        return _new(Frame, (t, channel, cid, b"", ext, False, err, True, False, False, length or -1))
    byte_toks = rest[:length]
    if len(byte_toks) < length or any(len(b) != 2 for b in byte_toks):
        raise _Bad(f"[{length}] announces {length} data bytes: expected {length} two-digit hex bytes")
    data = _hex_data("".join(byte_toks))
    tail = rest[length:]
    if tail and not (tail[0][:1] == "'" or (tail[0] == "ERRORFRAME" and err)):
        raise _Bad(f"unexpected text after the data: {' '.join(tail)!r}")
    if is_fd:
        if length not in CANFD_LENGTHS:
            raise _Bad(f"{length} data bytes is not a CAN FD length")
    elif length > 8:
        raise _Bad(f"{length} data bytes in a classic CAN frame (at most 8)")
    return _new(Frame, (t, channel, cid, data, ext, is_fd, err, False, brs, esi, -1))


def _parse_line(line: str) -> Frame | None:
    """Parse one candump line of any supported shape; None for blank and ``#`` comment lines."""
    s = line.strip()
    if not s or s[0] == "#":
        return None
    t: float | None = None
    ts_text = ""
    if s[0] == "(":
        close = s.find(")")
        if close < 0:
            raise _Bad("timestamp has no closing ')'")
        ts_text = s[1:close]
        t = _parse_timestamp(ts_text)
        toks = s[close + 1 :].split()
    else:
        toks = s.split()
    if len(toks) >= 2 and "#" in toks[1]:
        if t is None:
            raise _Bad("missing '(seconds.microseconds)' timestamp")
        if len(toks) > 3 or (len(toks) == 3 and toks[2] not in _MARKERS):
            raise _Bad(f"unexpected text after the frame: {' '.join(toks[2:])!r}")
        return _parse_compact(t, toks[0], toks[1])
    return _parse_long(t, ts_text, toks)


def _open_text(p: Path, gz: bool) -> tuple[io.BufferedReader, TextIO]:
    raw = open(p, "rb")  # noqa: SIM115 -- closed by the caller's finally
    binary: Any = gzip.GzipFile(fileobj=raw, mode="rb") if gz else raw
    # utf-8-sig drops a BOM; errors=replace turns binary junk into malformed lines, not a UnicodeDecodeError
    return raw, io.TextIOWrapper(binary, encoding="utf-8-sig", errors="replace")


def _note_order(st: ReadStats, t: float, last_t: float) -> None:
    """Count ``t`` in ``st`` as going back or repeating when it does, against the previous frame's ``last_t``."""
    if t < last_t:
        st.backwards_timestamps += 1
    elif t == last_t:
        st.repeated_timestamps += 1


def _flatten(chunks: Iterator[Columns | list[Frame]]) -> Iterator[Frame]:
    """The frames of a chunk stream, one by one."""
    for chunk in chunks:
        yield from (chunk if type(chunk) is list else chunk.frames())  # type: ignore[union-attr]


def _candump_chunks(
    p: Path, gz: bool, skip_bad: bool, st: ReadStats, want_ts_stats: bool, owner: LogFrames
) -> Iterator[Columns | list[Frame]]:
    """The candump text reader: plain blocks as :class:`Columns`, others as lists of frames parsed line by line."""
    raw, f = _open_text(p, gz)
    frames = 0
    lineno = 0  # lines before the current block
    last_t = -math.inf
    last_was_error = False
    rest = ""
    lt, eq = operator.lt, operator.eq
    try:
        while True:
            try:
                chunk = f.read(CHUNK_CHARS)
            except (OSError, EOFError, zlib.error) as exc:
                raise LogFormatError(f"{p}: cannot read{' gzip' if gz else ''} log: {exc}") from None
            if chunk:
                block = rest + chunk if rest else chunk
                cut = block.rfind("\n") + 1
                if cut == 0:
                    if len(block) > 4 * CHUNK_CHARS:
                        raise LogFormatError(
                            f"{p}:{lineno + 1}: no line break in {len(block)} characters: not a candump log"
                        )
                    rest = block
                    continue
                rest = block[cut:]
                block = block[:cut]
            elif rest:
                block, rest = rest + "\n", ""
            else:
                break
            n = block.count("\n")
            cols = None if last_was_error else _bulk_columns(block, n)
            if cols is not None:
                ts = cols.ts
                if want_ts_stats:
                    _note_order(st, float(ts[0]), last_t)
                    nxt = islice(ts, 1, None)
                    if cols.ordered:  # text order is time order; the usual case, increasing, costs one pass
                        if not all(map(lt, ts, nxt)):
                            st.repeated_timestamps += sum(map(eq, ts, islice(ts, 1, None)))
                    else:
                        times = list(map(float, ts))
                        st.backwards_timestamps += sum(map(lt, islice(times, 1, None), times))
                        st.repeated_timestamps += sum(map(eq, islice(times, 1, None), times))
                last_t = float(ts[-1])
                frames += n
                st.lines += n
                st.frames += n
                yield cols
            else:
                lines = block.split("\n")
                lines.pop()  # the empty string after the block's last newline
                st.lines += n
                out: list[Frame] = []
                for no, line in enumerate(lines, lineno + 1):
                    if last_was_error and line[:1] == "\t":
                        continue  # candump -e explains an error frame on indented lines below it
                    try:
                        fr = _parse_line(line)
                    except _Bad as bad:
                        if not skip_bad:
                            if out:
                                yield out  # every frame before the bad line is processed first
                            raise LogFormatError(f"{p}:{no}: {bad.reason}: {line!r}") from None
                        st.bad_lines += 1
                        if len(st.bad_examples) < MAX_BAD_EXAMPLES:
                            st.bad_examples.append(BadLine(no, bad.reason, line))
                        continue
                    if fr is None:
                        continue
                    last_was_error = fr.is_error_frame
                    _note_order(st, fr.t, last_t)
                    last_t = fr.t
                    frames += 1
                    st.frames += 1
                    out.append(fr)
                if out:
                    yield out
            lineno += n
            owner._position(raw.tell())
    finally:
        f.close()
        raw.close()
        owner._done()
    if frames == 0:
        skipped = f" ({st.bad_lines} bad lines skipped)" if st.bad_lines else ""
        raise LogFormatError(f"{p}: empty log: no frames{skipped}")


# --------------------------------------------------------------------------- python-can formats


def channel_name(channel: Any) -> str:
    """A python-can channel as a string: ints (and digit strings) become ``canN``, None becomes ``""``."""
    if channel is None:
        return ""
    if isinstance(channel, int) or (isinstance(channel, str) and channel.isdigit()):
        return f"can{channel}"
    return str(channel)


def frame_from_message(msg: can.Message, channel: str | None = None) -> Frame:
    """Convert a ``can.Message`` to a :class:`Frame` (``channel`` overrides the message's)."""
    data = bytes(msg.data) if msg.data is not None else b""
    dlc = msg.dlc if msg.dlc != len(data) else -1
    return _new(
        Frame,
        (
            float(msg.timestamp or 0.0),
            channel_name(msg.channel) if channel is None else channel,
            int(msg.arbitration_id),
            data,
            bool(msg.is_extended_id),
            bool(msg.is_fd),
            bool(msg.is_error_frame),
            bool(msg.is_remote_frame),
            bool(msg.bitrate_switch),
            bool(msg.error_state_indicator),
            -1 if dlc == 0 and msg.is_remote_frame else dlc,
        ),
    )


def _reader_class(fmt: str) -> Callable[[Any], Iterable[can.Message]]:
    import can

    classes: dict[str, Callable[[Any], Iterable[can.Message]]] = {
        "asc": can.ASCReader,
        "blf": can.BLFReader,
        "trc": can.TRCReader,
        "csv": can.CSVReader,
        "mf4": can.MF4Reader,
    }
    return classes[fmt]


_PROGRESS_EVERY = 4096  # messages between progress updates for python-can readers


_BATCH = 4096


def _batches(frames: Iterator[Frame]) -> Iterator[list[Frame]]:
    """``frames`` in lists of up to :data:`_BATCH`."""
    while batch := list(islice(frames, _BATCH)):
        yield batch


def _read_python_can(p: Path, fmt: str, gz: bool, st: ReadStats, owner: LogFrames) -> Iterator[Frame]:
    """Frames from one of python-can's readers; its errors become LogFormatError naming the file."""
    raw = open(p, "rb")  # noqa: SIM115 -- closed in the finally below
    try:
        binary: Any = gzip.GzipFile(fileobj=raw, mode="rb") if gz else raw
        fobj: Any = binary
        if fmt in _TEXT_PYTHON_CAN:
            fobj = io.TextIOWrapper(binary, encoding="utf-8", errors="replace")
        name = fmt.upper()
        frames = 0
        last_t = -math.inf
        try:
            messages = iter(_reader_class(fmt)(fobj))
        except Exception as exc:  # python-can raises many types for a bad header; none may escape raw
            raise LogFormatError(f"{p}: not a valid {name} log: {type(exc).__name__}: {exc}") from exc
        while True:
            try:
                msg = next(messages)
            except StopIteration:
                break
            except Exception as exc:  # corrupt input deep inside python-can: name the file instead
                raise LogFormatError(
                    f"{p}: {name} reader failed after {frames} frames: {type(exc).__name__}: {exc}"
                ) from exc
            fr = frame_from_message(msg)
            _note_order(st, fr.t, last_t)
            last_t = fr.t
            frames += 1
            st.frames += 1
            if frames % _PROGRESS_EVERY == 0 and not raw.closed:
                owner._position(raw.tell())
            yield fr
        owner._position(st.bytes_total if raw.closed else raw.tell())
    finally:
        raw.close()
        owner._done()
    if frames == 0:
        raise LogFormatError(f"{p}: empty log: no frames")


# --------------------------------------------------------------------------- writing candump -L


def format_candump_line(frame: Frame, default_channel: str = "can0") -> str:
    """One candump -L line for ``frame``, without the newline.

    ``(%.6f) channel ID#DATA``: 3 hex digits for standard ids, 8 for extended
    ids and error frames (with CAN_ERR_FLAG), ``##F`` + data for CAN FD, ``R`` or
    ``R<dlc>`` for remote frames, ``_<dlc>`` for a classic raw DLC above 8.
    ``default_channel`` names frames whose channel is empty. Raises ValueError
    for an id out of range or a channel with whitespace in it.
    """
    channel = frame.channel or default_channel
    if not channel or channel.split() != [channel]:
        raise ValueError(f"channel {channel!r} cannot be written to a candump log (empty or has whitespace)")
    cid = frame.arbitration_id
    if frame.is_error_frame:
        id_text = f"{(cid & CAN_EFF_MASK) | CAN_ERR_FLAG:08X}"
    elif frame.is_extended_id:
        if not 0 <= cid <= CAN_EFF_MASK:
            raise ValueError(f"extended id {cid:#x} out of range")
        id_text = f"{cid:08X}"
    else:
        if not 0 <= cid <= CAN_SFF_MASK:
            raise ValueError(f"standard id {cid:#x} out of range (use is_extended_id=True above 0x7FF)")
        id_text = f"{cid:03X}"
    if frame.is_remote_frame:
        body = f"R{frame.dlc}" if 0 < frame.dlc <= 8 else "R"
    elif frame.is_fd:
        flags = (CANFD_BRS if frame.bitrate_switch else 0) | (CANFD_ESI if frame.error_state_indicator else 0)
        body = f"#{flags:X}{frame.data.hex().upper()}"
    else:
        body = frame.data.hex().upper()
        if len(frame.data) == 8 and 8 < frame.dlc <= 15:
            body += f"_{frame.dlc:X}"
    return f"({frame.t:.6f}) {channel} {id_text}#{body}"


def write_candump(frames: Iterable[Frame], out: TextIO, default_channel: str = "can0") -> int:
    """Write ``frames`` to ``out`` as a candump -L log (one line each); return how many were written.

    python-can's ``can.CanutilsLogReader`` and :func:`read_log` both read the result
    back (the latter to equal frames, for timestamps with at most 6 decimals).
    """
    count = 0
    write = out.write
    for frame in frames:
        write(format_candump_line(frame, default_channel) + "\n")
        count += 1
    return count
