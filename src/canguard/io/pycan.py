"""python-can's own log readers (ASC, BLF, TRC, CSV, MF4) as :class:`~canguard.io.block.Block` s.

Each batch of up to :data:`BLOCK` messages becomes one block, field for field
(:meth:`Block.of_messages <canguard.io.block.Block.of_messages>`); python-can's integer
channels are named as python-can's candump writer names them: ``0`` -> ``can0``.
"""

from __future__ import annotations

import gc
import io
import math
import sys
from collections.abc import Callable, Iterable, Iterator
from itertools import islice
from pathlib import Path
from typing import TYPE_CHECKING, Any

from canguard.errors import LogFormatError, clip
from canguard.io.blf_length import BlfLength
from canguard.io.block import Block, channel_name
from canguard.io.frame import Frame
from canguard.io.logtypes import _TEXT_PYTHON_CAN, LogFrames, ReadStats, _new, open_decompressed

if TYPE_CHECKING:
    import can

# --------------------------------------------------------------------------- python-can formats


def frame_from_message(msg: can.Message, channel: str | None = None) -> Frame:
    """Convert a ``can.Message`` to a :class:`Frame` (``channel`` overrides the message's)."""
    return frames_from_messages((msg,), channel)[0]


def frames_from_messages(msgs: Iterable[can.Message], channel: str | None = None) -> list[Frame]:
    """Convert ``can.Message`` objects to :class:`Frame` s (``channel`` overrides each message's): a live bus's
    batch in one call. A remote frame keeps its DLC; a data frame's DLC is -1 when it is the data's length."""
    out: list[Frame] = []
    append = out.append
    for msg in msgs:
        data = bytes(msg.data) if msg.data is not None else b""
        dlc = msg.dlc
        remote = bool(msg.is_remote_frame)
        append(_new(Frame, (
            float(msg.timestamp or 0.0),
            channel_name(msg.channel) if channel is None else channel,
            int(msg.arbitration_id),
            data,
            bool(msg.is_extended_id),
            bool(msg.is_fd),
            bool(msg.is_error_frame),
            remote,
            bool(msg.bitrate_switch),
            bool(msg.error_state_indicator),
            -1 if dlc == len(data) or (dlc == 0 and remote) else dlc,
        )))
    return out


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


def _free_quietly(exc: BaseException) -> None:
    """Free now, without a word, what a reader that failed to open left behind (``exc`` keeps its message).

    asammdf leaves the MDF4 it half-read from a truncated .mf4 in a reference cycle of
    the traceback's frames; its ``__del__`` fails again (AttributeError: no ``header``)
    whenever the garbage collector gets to it, which printed "Exception ignored in
    MDF4.__del__" and a traceback after canguard's one-line error.
    """
    exc.__traceback__ = None
    hook = sys.unraisablehook
    sys.unraisablehook = lambda _: None
    try:
        gc.collect()
    finally:
        sys.unraisablehook = hook


_PROGRESS_EVERY = 4096  # messages between progress updates for python-can readers


class _Messages:
    """python-can's reader of one log, opened: its messages, with python-can's errors as LogFormatError.

    ``next_batch`` gives up to ``size`` messages; when the reader fails part-way it
    gives the messages read before the failure first and raises on the next call,
    so that every frame before the failure is processed (as the candump reader does).
    """

    def __init__(self, p: Path, fmt: str, gz: str) -> None:
        self.p, self.name = p, fmt.upper()
        self.raw = open(p, "rb")  # noqa: SIM115 -- closed by close()
        self.count = 0
        self._failed: LogFormatError | None = None
        self.length: BlfLength | None = None
        """A BLF's framing, followed as python-can reads it: where a cut file ends (:mod:`canguard.io.blf_length`)."""
        try:
            binary: Any = open_decompressed(self.raw, gz)
            if fmt == "blf":
                binary = self.length = BlfLength(binary)
            fobj: Any = binary
            if fmt in _TEXT_PYTHON_CAN:
                fobj = io.TextIOWrapper(binary, encoding="utf-8", errors="replace")
            try:
                reader = _reader_class(fmt)(fobj)
            except Exception as exc:  # python-can raises many types for a bad header; none may escape raw
                _free_quietly(exc)
                cut = self._cut(0)
                if cut is not None:
                    raise cut from exc
                raise LogFormatError(
                    f"{p}: not a valid {self.name} log: {type(exc).__name__}: {clip(str(exc))}"
                ) from exc
            self.messages: Iterator[can.Message] = iter(reader)
            if self.length is not None:
                self.length.note_file_size(int(getattr(reader, "file_size", 0) or 0))
        except BaseException:
            self.raw.close()
            raise

    def _cut(self, read: int) -> LogFormatError | None:
        """A LogFormatError (exit 2, as a truncated .gz gives) when the log ended where its framing says it may
        not, after ``read`` frames; None when it is whole (or not a BLF)."""
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
            if not batch:
                raise self._failed from exc
        else:
            if len(batch) < size:  # the end of the log: python-can stops quietly where the file stops
                self._failed = self._cut(self.count + len(batch))
                if self._failed is not None and not batch:
                    raise self._failed
        self.count += len(batch)
        return batch

    def position(self, st: ReadStats) -> int:
        """The position reached in the file on disk (its size once python-can has closed it)."""
        return st.bytes_total if self.raw.closed else self.raw.tell()

    def close(self) -> None:
        self.raw.close()


BLOCK = 2048
"""Messages taken from python-can's reader at a time: one block (2048 replayed a 600 k-frame BLF log 3-5 % faster
than 4096 or 1024: caches, and fewer live messages for the garbage collector)."""


def python_can_chunks(p: Path, fmt: str, gz: str, st: ReadStats, owner: LogFrames) -> Iterator[Block]:
    """One of python-can's readers as blocks; its errors as LogFormatError."""
    reader: _Messages | None = None
    frames = 0
    last_t = -math.inf
    try:
        reader = _Messages(p, fmt, gz)
        while msgs := reader.next_batch(BLOCK):
            try:
                block = Block.of_messages(msgs)
            except LogFormatError as exc:
                raise LogFormatError(f"{p}: {exc}") from None
            backwards, repeated = block.order
            first = float(block.time_s[0])
            st.backwards_timestamps += backwards + (first < last_t)
            st.repeated_timestamps += repeated + (first == last_t)
            st.frames += block.n
            frames += block.n
            last_t = float(block.time_s[-1])
            yield block
            owner.reached(reader.position(st))
    finally:
        if reader is not None:
            reader.close()
        owner.finished()
    if frames == 0:
        raise LogFormatError(f"{p}: empty log: no frames")
