"""Writing candump -L logs (what ``--emit`` and ``canguard simulate --out`` write)."""

from __future__ import annotations

from collections.abc import Iterable
from typing import TextIO

from canguard.io.frame import Frame
from canguard.io.logtypes import CAN_EFF_MASK, CAN_ERR_FLAG, CAN_SFF_MASK, CANFD_BRS, CANFD_ESI


def format_candump_line(frame: Frame, default_channel: str = "can0") -> str:
    """One candump -L line for ``frame``, without the newline (``default_channel`` for an empty channel).

    ``(%.6f) channel ID#DATA``: 3 hex digits for standard ids, 8 for extended ids and error frames (with
    CAN_ERR_FLAG), ``##F`` + data for CAN FD, ``R`` or ``R<dlc>`` for remote frames, ``_<dlc>`` for a classic raw
    DLC above 8. ValueError for an id out of range or a channel with whitespace in it.
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
    """Write ``frames`` to ``out`` as a candump -L log (one line each); return how many were written."""
    count = 0
    for frame in frames:
        out.write(format_candump_line(frame, default_channel) + "\n")
        count += 1
    return count
