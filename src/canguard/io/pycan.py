"""python-can's own log readers (ASC, BLF, TRC, CSV, MF4) as frame streams."""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Iterable, Iterator
from itertools import islice
from pathlib import Path
from typing import TYPE_CHECKING, Any

from canguard.errors import LogFormatError
from canguard.io.candump import _note_order
from canguard.io.frame import Frame
from canguard.io.logtypes import _TEXT_PYTHON_CAN, LogFrames, ReadStats, _new, open_decompressed

if TYPE_CHECKING:
    import can

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


def _read_python_can(p: Path, fmt: str, gz: str, st: ReadStats, owner: LogFrames) -> Iterator[Frame]:
    """Frames from one of python-can's readers; its errors become LogFormatError naming the file."""
    raw = open(p, "rb")  # noqa: SIM115 -- closed in the finally below
    try:
        binary: Any = open_decompressed(raw, gz)
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
