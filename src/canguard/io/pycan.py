"""python-can's own log readers (ASC, BLF, TRC, CSV, MF4) as :class:`~canguard.io.block.Block` s.

Each batch of up to :data:`BLOCK` messages becomes one block (:meth:`~canguard.io.block.Block.of_messages`).
"""

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
    """Free now, without a word, what a reader that failed to open left behind (``exc`` keeps its message): asammdf
    leaves a truncated .mf4's MDF4 in a cycle of the traceback's frames, whose ``__del__`` fails again later
    ("Exception ignored in MDF4.__del__" and a traceback after canguard's one-line error)."""
    exc.__traceback__ = None
    hook = sys.unraisablehook
    sys.unraisablehook = lambda _: None
    try:
        gc.collect()
    finally:
        sys.unraisablehook = hook


class _Messages:
    """python-can's reader of one log, opened: its messages, with python-can's errors as LogFormatError (raised
    by the call after the one that gave the messages read before the failure, as the candump reader does)."""

    def __init__(self, p: Path, fmt: str, gz: str) -> None:
        self.p, self.name = p, fmt.upper()
        self.raw = open(p, "rb")  # noqa: SIM115 -- closed by close()
        self.count = 0
        self._failed: LogFormatError | None = None
        self.length: BlfLength | None = None  # a BLF's framing, followed as python-can reads it
        try:
            fobj: Any = open_decompressed(self.raw, gz)
            if fmt == "blf":
                fobj = self.length = BlfLength(fobj)
            if fmt in _TEXT_FORMATS:
                fobj = io.TextIOWrapper(fobj, encoding="utf-8", errors="replace")
            import can

            try:
                reader = getattr(can, f"{self.name}Reader")(fobj)  # ASCReader, BLFReader, ... MF4Reader
            except Exception as exc:  # python-can raises many types for a bad header; none may escape raw
                _free_quietly(exc)
                raise self._cut(0) or LogFormatError(
                    f"{p}: not a valid {self.name} log: {type(exc).__name__}: {clip(str(exc))}") from exc
            self.messages: Iterator[can.Message] = iter(reader)
            if self.length is not None:
                self.length.note_file_size(int(getattr(reader, "file_size", 0) or 0))
        except BaseException:
            self.raw.close()
            raise

    def _cut(self, read: int) -> LogFormatError | None:
        """The error of a log that ended where its framing says it may not, after ``read`` frames; None: whole."""
        why = self.length.cut() if self.length is not None else ""
        if not why:
            return None
        return LogFormatError(f"{self.p}: truncated {self.name} log: {why}; {read} frames were read before the cut")

    def next_batch(self, size: int) -> list[can.Message]:
        """Up to ``size`` messages; [] at the end of the log."""
        if self._failed is not None:
            raise self._failed
        batch: list[can.Message] = []
        try:
            batch.extend(islice(self.messages, size))
        except Exception as exc:  # corrupt input deep inside python-can: name the file instead
            # python-can fails on a cut object header (struct.error): then the cut is the news
            self._failed = self._cut(self.count + len(batch)) or LogFormatError(
                f"{self.p}: {self.name} reader failed after {self.count + len(batch)} frames: "
                f"{type(exc).__name__}: {clip(str(exc))}"
            )
            self._failed.__cause__ = exc
        else:
            if len(batch) < size:  # the end of the log: python-can stops quietly where the file stops
                self._failed = self._cut(self.count + len(batch))
        if self._failed is not None and not batch:
            raise self._failed
        self.count += len(batch)
        return batch

    def position(self, size: int) -> int:
        """The position reached in the file on disk (its ``size`` once python-can has closed it)."""
        return size if self.raw.closed else self.raw.tell()

    def close(self) -> None:
        self.raw.close()


BLOCK = 2048
"""Messages taken from python-can's reader at a time: one block (replays a BLF log faster than 1024 or 4096)."""


def python_can_blocks(p: Path, fmt: str, gz: str, size: int) -> Blocks:
    """One of python-can's readers as blocks (``size``: the file's on disk); its errors as LogFormatError."""
    reader = _Messages(p, fmt, gz)
    try:
        while msgs := reader.next_batch(BLOCK):
            try:
                block = Block.of_messages(msgs)
            except LogFormatError as exc:
                raise LogFormatError(f"{p}: {exc}") from None
            yield block, reader.position(size)
    finally:
        reader.close()
    return ""
