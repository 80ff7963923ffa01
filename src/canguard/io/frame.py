"""The two values that flow through canguard: frames in, samples out.

Tuples: replay makes millions, and a tuple is several times cheaper to build than a ``can.Message``."""

from __future__ import annotations

from typing import NamedTuple


class Frame(NamedTuple):
    """One CAN frame: ``t`` in epoch seconds, ``channel`` as recorded (``can0``) or, live, the bus name."""

    t: float
    channel: str
    arbitration_id: int
    data: bytes
    is_extended_id: bool = False
    is_fd: bool = False
    is_error_frame: bool = False
    is_remote_frame: bool = False
    bitrate_switch: bool = False
    error_state_indicator: bool = False
    dlc: int = -1
    """Data length code as recorded; -1 means ``len(data)``. Remote frames carry a DLC and no data."""


# Reasons a sample is not a usable value. Guards treat every one of them as unsafe.
INVALID_NAN = "nan"
INVALID_INF = "inf"
INVALID_RANGE = "out_of_range"
INVALID_LENGTH = "bad_length"
INVALID_PAYLOAD = "undecodable"


class Sample(NamedTuple):
    """One decoded value: ``signal`` its role in the source (``current``, ``present``, a joint's ``name``);
    ``reason`` empty when valid, else one of the ``INVALID_*`` above (and ``value`` nan)."""

    source: str
    signal: str
    value: float
    t: float
    reason: str = ""
