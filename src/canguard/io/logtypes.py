"""What every log reader shares: statistics, bad lines, the frame stream, format constants."""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Generator, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from canguard.errors import LogFormatError
from canguard.io.block import Block
from canguard.io.frame import Frame
from canguard.io.progress import ProgressBar

COMPRESSIONS = (".gz", ".xz", ".zst")
"""Compressed logs: any format may carry one of these on top (``robot.log.xz``)."""

CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF
CAN_SFF_MASK = 0x7FF
CANFD_BRS = 0x01
CANFD_ESI = 0x02
CANFD_LENGTHS = frozenset((0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64))


def open_decompressed(raw: Any, compression: str) -> Any:
    """A binary file object reading ``raw`` through its ``compression`` ("", "gz", "xz" or "zst")."""
    if compression == "gz":
        import gzip

        return gzip.GzipFile(fileobj=raw, mode="rb")
    if compression == "xz":
        import lzma

        return lzma.LZMAFile(raw, mode="rb")
    if compression == "zst":
        import zstandard  # checked by read_log: a LogFormatError says how to install it

        # buffered: zstandard's reader has no readline (the candump reader completes a block's last line with it)
        return io.BufferedReader(zstandard.ZstdDecompressor().stream_reader(raw, read_across_frames=True))
    return raw


@dataclass
class ReadStats:
    """What a reader saw, added up over :func:`read_log` calls: frames, bad lines skipped, times back or repeated,
    bytes on disk, bag frames timed by ``header`` or ``record``."""

    frames: int = 0
    bad_lines: int = 0
    backwards_timestamps: int = 0
    repeated_timestamps: int = 0
    bytes_total: int = 0
    stamps: dict[str, int] = field(default_factory=dict)


Blocks = Generator[tuple[Block | None, int | None], None, str]
"""A reader's blocks (None: none this time) with the position on disk; returns what was read (`` on /can``)."""


class LogFrames(Iterable[Frame]):
    """The frames of one log (:func:`read_log`): frame by frame, or by :meth:`chunks`; ``progress`` follows it."""

    def __init__(self, path: Path, stats: ReadStats, read: Callable[[], Blocks]) -> None:
        self.path = path
        self.stats = stats
        self.progress: ProgressBar | None = None
        self._chunks = self._counted(read)

    def chunks(self) -> Iterator[Block]:
        """The same frames a block at a time (:class:`~canguard.io.block.Block`)."""
        return self._chunks

    def __iter__(self) -> Iterator[Frame]:
        return (frame for block in self._chunks for frame in block.frames())

    def _counted(self, read: Callable[[], Blocks]) -> Iterator[Block]:
        """The reader's blocks, counted in :attr:`stats` as they pass; a log without a frame a LogFormatError."""
        st = self.stats
        before = st.frames
        last_t = -math.inf
        blocks = read()
        try:
            while True:
                try:
                    block, position = next(blocks)
                except StopIteration as end:
                    where = end.value or ""
                    break
                if block is not None and block.n:
                    backwards, repeated = block.order
                    first = float(block.time_s[0])
                    st.backwards_timestamps += backwards + (first < last_t)
                    st.repeated_timestamps += repeated + (first == last_t)
                    st.frames += block.n
                    last_t = float(block.time_s[-1])
                    yield block
                if position is not None and self.progress is not None:
                    self.progress.update(position)
        finally:
            if self.progress is not None:
                self.progress.close()
        if st.frames == before:
            skipped = f" ({st.bad_lines} bad lines skipped)" if st.bad_lines else ""
            raise LogFormatError(f"{self.path}: empty log: no frames{where}{skipped}")
