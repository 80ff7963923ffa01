"""Read recorded CAN logs as :class:`~canguard.io.frame.Frame` streams; write candump -L logs.

:func:`read_log` picks the reader by file extension (``.gz`` on any of them)::

    .log .candump .txt   candump text: ``candump -L`` / ``-l`` lines (the fast path)
                         or plain ``candump -ta`` output
    .asc                 canguard's reader for plain data lines, python-can's for the rest (io.asc_blocks)
    .blf .trc .csv       python-can's own readers
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

import importlib.util
from pathlib import Path
from typing import TYPE_CHECKING

from canguard.errors import LogFormatError
from canguard.io.candump import _candump_chunks, _flatten
from canguard.io.logtypes import CANDUMP_SUFFIXES, COMPRESSIONS, PYTHON_CAN_SUFFIXES, LogFrames, ReadStats
from canguard.io.progress import ProgressBar
from canguard.io.pycan import _read_python_can
from canguard.io.pycan_blocks import python_can_chunks

if TYPE_CHECKING:
    pass

from canguard.io.candump import CHUNK_CHARS, Columns
from canguard.io.candump_write import format_candump_line, write_candump
from canguard.io.logtypes import BadLine, candump_id_texts
from canguard.io.pycan import frame_from_message

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


# --------------------------------------------------------------------------- format choice


def log_format(path: str | Path) -> tuple[str, str]:
    """Return ``(format, compression)`` for a log path, chosen by extension.

    ``format`` is ``candump``, ``asc``, ``blf``, ``trc``, ``csv`` or ``mf4``;
    ``compression`` is ``""``, ``gz``, ``xz`` or ``zst`` (``robot.log.xz``).
    Raises :class:`LogFormatError` for an unknown extension.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    compression = ""
    if suffix in COMPRESSIONS:
        compression = suffix[1:]
        suffix = Path(p.stem).suffix.lower()
    if suffix in CANDUMP_SUFFIXES:
        return "candump", compression
    if suffix in PYTHON_CAN_SUFFIXES:
        return suffix[1:], compression
    known = ", ".join(CANDUMP_SUFFIXES + PYTHON_CAN_SUFFIXES)
    raise LogFormatError(
        f"{p}: unknown log format {(suffix or p.name)!r}: expected one of {known} "
        f"(optionally + {' / '.join(COMPRESSIONS)})"
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
    fmt, gz = log_format(p)  # gz: the compression ("" none)
    if not p.exists():
        raise LogFormatError(f"{p}: no such file")
    if not p.is_file():
        raise LogFormatError(f"{p}: not a regular file")
    if fmt == "mf4" and importlib.util.find_spec("asammdf") is None:
        raise LogFormatError(f"{p}: reading .mf4 logs needs asammdf: pip install 'python-can[mf4]'")
    if gz == "zst" and importlib.util.find_spec("zstandard") is None:
        raise LogFormatError(f"{p}: reading .zst logs needs zstandard: pip install zstandard")
    st = stats if stats is not None else ReadStats()
    st.path = str(p)
    st.format = fmt + (f".{gz}" if gz else "")
    try:
        st.bytes_total += p.stat().st_size
    except OSError as exc:
        raise LogFormatError(f"{p}: cannot read: {exc.strerror or exc}") from None
    frames = LogFrames(p, st, progress)
    if fmt == "candump":
        frames._chunks = _candump_chunks(p, gz, skip_bad, st, stats is not None, frames)
        frames._frames = _flatten(frames._chunks)
    elif fmt == "asc":  # canguard's own reader, python-can's for whatever it does not take (io.asc_blocks)
        from canguard.io.asc_blocks import asc_chunks  # its regexes are compiled for ASC logs only

        frames._chunks = asc_chunks(p, gz, st, frames)
        frames._frames = _flatten(frames._chunks)
    else:
        # two lazy generators over the same file: only the one consumed opens it
        frames._frames = _read_python_can(p, fmt, gz, st, frames)
        frames._chunks = python_can_chunks(p, fmt, gz, st, frames)
    return frames
