"""python-can's own log readers (ASC, BLF, TRC, CSV, MF4) as :class:`~canguard.io.block.Block` s."""

from __future__ import annotations

import gc
import io
import sys
from collections.abc import Iterator
from itertools import islice
from pathlib import Path
from typing import TYPE_CHECKING, Any

from canguard.errors import LogFormatError, clip
from canguard.io.blf_length import BlfLength
from canguard.io.block import Block
from canguard.io.logtypes import Blocks, open_decompressed

if TYPE_CHECKING:
    import can

_TEXT_FORMATS = ("asc", "trc", "csv")


def _free_quietly(exc: BaseException) -> None:
    """Free now, quietly, what a reader that failed to open left behind: asammdf leaves a truncated .mf4's MDF4 in a
    cycle whose ``__del__`` fails later (a traceback after canguard's one-line error)."""
    exc.__traceback__ = None
    hook = sys.unraisablehook
    sys.unraisablehook = lambda _: None
    try:
        gc.collect()
    finally:
        sys.unraisablehook = hook


BLOCK = 2048
"""Messages taken from python-can's reader at a time: one block (replays a BLF log faster than 1024 or 4096)."""


def python_can_blocks(p: Path, fmt: str, gz: str, size: int) -> Blocks:
    """One of python-can's readers as blocks (``size``: on disk); its errors as LogFormatError after the frames read."""
    name = fmt.upper()
    raw = open(p, "rb")  # noqa: SIM115 -- closed below
    try:
        fobj = open_decompressed(raw, gz)
        length = BlfLength(fobj) if fmt == "blf" else None  # a BLF's framing, followed as python-can reads it
        messages = _messages(p, name, length or fobj, fmt in _TEXT_FORMATS, length)
        count = 0
        while True:
            batch: list[can.Message] = []
            failed: LogFormatError | None = None
            try:
                batch.extend(islice(messages, BLOCK))
            except Exception as exc:  # corrupt input deep inside python-can: name the file instead
                # python-can fails on a cut object header (struct.error): then the cut is the news
                failed = _cut(p, name, length, count + len(batch)) or LogFormatError(
                    f"{p}: {name} reader failed after {count + len(batch)} frames: {type(exc).__name__}: "
                    f"{clip(str(exc))}")
                failed.__cause__ = exc
            else:
                if len(batch) < BLOCK:  # the end of the log: python-can stops quietly where the file stops
                    failed = _cut(p, name, length, count + len(batch))
            if batch:
                count += len(batch)
                try:
                    block = Block.of_messages(batch)
                except LogFormatError as exc:
                    raise LogFormatError(f"{p}: {exc}") from None
                yield block, size if raw.closed else raw.tell()  # python-can closes the file at its end
            if failed is not None:
                raise failed
            if len(batch) < BLOCK:
                return ""
    finally:
        raw.close()


def _messages(p: Path, name: str, fobj: Any, text: bool, length: BlfLength | None) -> Iterator[can.Message]:
    """python-can's reader of format ``name`` over ``fobj``; LogFormatError when it does not open."""
    import can

    try:
        reader = getattr(can, f"{name}Reader")(io.TextIOWrapper(fobj, encoding="utf-8", errors="replace")
                                               if text else fobj)  # ASCReader, BLFReader, ... MF4Reader
    except Exception as exc:  # python-can raises many types for a bad header; none may escape raw
        _free_quietly(exc)
        raise _cut(p, name, length, 0) or LogFormatError(
            f"{p}: not a valid {name} log: {type(exc).__name__}: {clip(str(exc))}") from exc
    if length is not None:
        length.file_size = int(getattr(reader, "file_size", 0) or 0)
    return iter(reader)


def _cut(p: Path, name: str, length: BlfLength | None, read: int) -> LogFormatError | None:
    """The error of a log that ended where its framing says it may not, after ``read`` frames; None: whole."""
    why = length.cut() if length is not None else ""
    if not why:
        return None
    return LogFormatError(f"{p}: truncated {name} log: {why}; {read} frames were read before the cut")
