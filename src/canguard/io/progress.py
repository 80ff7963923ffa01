"""A tiny progress bar on stderr for long logs.

Drawn only when the stream is a terminal: in CI, under systemd or with stderr
redirected to a file, :class:`ProgressBar` is silent and each ``update`` is a
couple of attribute reads, so the log readers can call it unconditionally.

Progress is measured in bytes of the file on disk (for a ``.gz`` log: the
compressed bytes), read from the position of the underlying file object, so it
needs no line counting and costs nothing per frame.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TextIO, TypeVar

_FramesT = TypeVar("_FramesT", bound=Iterator[Any])

_BAR_WIDTH = 30
_MIN_INTERVAL_S = 0.2  # redraw at most five times a second: a terminal write is expensive


def _is_tty(stream: TextIO) -> bool:
    """True when ``stream`` is an interactive terminal (False for closed or odd streams)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False


class ProgressBar:
    """``[#####.....]  42%  19.5/46.5 MB  label`` on one line of ``stream``, redrawn in place.

    ``total_bytes`` is the size of the file being read (0 or less: unknown, the
    bar shows bytes only). ``enabled`` is decided once, at construction: True
    only when ``stream`` is a TTY, unless forced with ``enabled=True/False``.
    :meth:`close` at the end finishes the line.
    """

    def __init__(
        self,
        total_bytes: int,
        stream: TextIO | None = None,
        *,
        label: str = "",
        enabled: bool | None = None,
        min_interval_s: float = _MIN_INTERVAL_S,
    ) -> None:
        self.total_bytes = int(total_bytes)
        self.stream: TextIO = sys.stderr if stream is None else stream
        self.label = label
        self.enabled: bool = _is_tty(self.stream) if enabled is None else enabled
        self.min_interval_s = min_interval_s
        self.position = 0
        self._last_draw = float("-inf")
        self._drawn = False
        self._closed = False

    def update(self, position: int) -> None:
        """Record that ``position`` bytes of the file have been read; redraw if due."""
        if not self.enabled:
            return
        self.position = position
        # monotonic: a wall-clock step must not freeze the bar (this is display only, not model time)
        now = time.monotonic()
        if now - self._last_draw >= self.min_interval_s:
            self._last_draw = now
            self._draw()

    def render(self) -> str:
        """The bar's text for the current position (without the leading carriage return)."""
        done_mb = self.position / 1e6
        if self.total_bytes > 0:
            frac = min(max(self.position / self.total_bytes, 0.0), 1.0)
            filled = int(frac * _BAR_WIDTH)
            bar = "#" * filled + "." * (_BAR_WIDTH - filled)
            text = f"[{bar}] {frac * 100:3.0f}%  {done_mb:.1f}/{self.total_bytes / 1e6:.1f} MB"
        else:
            text = f"{done_mb:.1f} MB"
        return f"{text}  {self.label}" if self.label else text

    def _draw(self) -> None:
        try:
            self.stream.write("\r" + self.render())
            self.stream.flush()
        except (OSError, ValueError):
            # a progress bar must never stop a replay: a closed or broken terminal just disables it
            self.enabled = False
            return
        self._drawn = True

    def close(self) -> None:
        """Draw the final state and end the line (nothing when disabled or never drawn)."""
        if self._closed:
            return
        self._closed = True
        if not self.enabled:
            return
        self._draw()
        if self._drawn:
            try:
                self.stream.write("\n")
                self.stream.flush()
            except (OSError, ValueError):
                pass


def wrap_progress(frames: _FramesT, path: str | Path, stream: TextIO | None = None) -> _FramesT:
    """Show a :class:`ProgressBar` for ``path`` while ``frames`` (from ``read_log``) is consumed.

    The bar is attached to the reader itself (its ``progress`` attribute), which
    updates it once per chunk from the file position and closes it at the end:
    no per-frame cost. When ``stream`` is not a terminal, or ``frames`` is not a
    reader that takes a bar, ``frames`` is returned unchanged.
    """
    p = Path(path)
    try:
        total = p.stat().st_size
    except OSError:
        total = 0
    bar = ProgressBar(total, stream, label=p.name)
    if bar.enabled and hasattr(frames, "progress"):
        frames.progress = bar  # a LogFrames (checked by hasattr)
    return frames
