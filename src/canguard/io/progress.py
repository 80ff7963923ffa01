"""A progress bar on stderr for long logs, in bytes of the file on disk (for a ``.gz`` log: the compressed bytes)."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any, TextIO, TypeVar

_FramesT = TypeVar("_FramesT", bound=Iterable[Any])

_BAR_WIDTH = 30
_MIN_INTERVAL_S = 0.2  # redraw at most five times a second: a terminal write is expensive


class ProgressBar:
    """``[#####.....]  42%  19.5/46.5 MB  label`` on one line of ``stream``, redrawn in place on a terminal."""

    def __init__(self, total_bytes: int, stream: TextIO | None = None, *, label: str = "") -> None:
        self.total_bytes = int(total_bytes)
        self.stream: TextIO = sys.stderr if stream is None else stream
        self.label = label
        try:
            self.enabled = bool(self.stream.isatty())
        except (AttributeError, ValueError, OSError):  # a closed or odd stream
            self.enabled = False
        self.position = 0
        self._last_draw = float("-inf")

    def update(self, position: int) -> None:
        """Record that ``position`` bytes of the file have been read; redraw if due."""
        if not self.enabled:
            return
        self.position = position
        now = time.monotonic()  # display only, not model time
        if now - self._last_draw >= _MIN_INTERVAL_S:
            self._last_draw = now
            self._draw()

    def _write(self, text: str) -> None:
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError):  # a closed or broken terminal never stops a replay: no more bar
            self.enabled = False

    def _draw(self) -> None:
        done = f"{self.position / 1e6:.1f}"
        text = f"{done} MB"
        if self.total_bytes > 0:
            frac = min(max(self.position / self.total_bytes, 0.0), 1.0)
            bar = "#" * int(frac * _BAR_WIDTH)
            text = f"[{bar:.<{_BAR_WIDTH}}] {frac * 100:3.0f}%  {done}/{self.total_bytes / 1e6:.1f} MB"
        self._write(f"\r{text}  {self.label}" if self.label else f"\r{text}")

    def close(self) -> None:
        """Draw the final state and end the line (once; nothing off a terminal)."""
        if self.enabled:
            self._draw()
            self._write("\n")
            self.enabled = False


def wrap_progress(frames: _FramesT, path: str | Path, stream: TextIO | None = None) -> _FramesT:
    """Attach a :class:`ProgressBar` for ``path`` to the reader ``frames`` when ``stream`` is a terminal."""
    p = Path(path)
    try:
        total = p.stat().st_size
    except OSError:
        total = 0
    bar = ProgressBar(total, stream, label=p.name)
    if bar.enabled and hasattr(frames, "progress"):
        frames.progress = bar
    return frames
