"""The ROS message types of CAN frames canguard reads, their definitions, and where each field lies in a message.

Each type is a ``std_msgs/Header`` then fixed-size fields (the last maybe a ``uint8`` sequence), so the fields lie
at fixed offsets from the end of the header's ``frame_id`` (:class:`Layout`), in CDR (aligned) or ROS 1 (packed).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from canguard.errors import LogFormatError

TIME = "int32 sec\nuint32 nanosec\n"
HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"

CAN_MSGS_FRAME = ("std_msgs/Header header\nuint32 id\nbool is_rtr\nbool is_extended\nbool is_error\nuint8 dlc\n"
                  "uint8[8] data\n")
"""``can_msgs/msg/Frame`` (ROS 2; ``can_msgs/Frame`` in ROS 1): a classic frame, ``data[:dlc]`` its payload."""
SOCKETCAN_FD_FRAME = "std_msgs/Header header\nuint32 id\nbool is_extended\nbool is_error\nuint8 len\nuint8[<=64] data\n"
"""``ros2_socketcan_msgs/msg/FdFrame``: a CAN FD frame of ``len`` bytes (no BRS / ESI flags)."""
SOCKETCAN_FRAME = ("std_msgs/Header header\nuint32 id\nbool is_rtr\nbool is_extended\nbool is_error\n"
                   "bool is_fd_frame\nuint8 dlc\nuint8[64] data\n")
"""``ros2_socketcan_msgs/msg/Frame`` while it carried CAN FD too (``is_fd_frame``; ``dlc`` is the length)."""
SOCKETCAN_FRAME_SEQ = SOCKETCAN_FRAME.replace("uint8[64] data", "uint8[<=64] data")
"""The same with its data as a bounded sequence, as it was for a while: told apart by the bag's definition."""
AUTOWARE_CAN_PACKET = ("std_msgs/Header header\nuint32 count\nuint32 id\nuint8 len\nuint8[8] dat\nuint16 flag\n"
                       "uint32 time\n")
"""``autoware_can_msgs/CANPacket`` (Autoware's Kvaser driver): ``flag`` holds Kvaser's message flags."""

DEFINITIONS: dict[str, tuple[str, ...]] = {
    "can_msgs/msg/Frame": (CAN_MSGS_FRAME,),
    "ros2_socketcan_msgs/msg/FdFrame": (SOCKETCAN_FD_FRAME,),
    "ros2_socketcan_msgs/msg/Frame": (SOCKETCAN_FRAME, SOCKETCAN_FRAME_SEQ),
    "autoware_can_msgs/msg/CANPacket": (AUTOWARE_CAN_PACKET,),
}
"""The CAN frame types canguard reads, by ROS 2 name, with their definitions (the first assumed when none)."""

DEPENDENCIES = {"std_msgs/msg/Header": HEADER, "builtin_interfaces/msg/Time": TIME}
"""The types the definitions name (ROS 2 spelling)."""

KVASER_RTR, KVASER_EXT, KVASER_ERROR_FRAME = 0x01, 0x04, 0x20
"""Kvaser CANlib's ``canMSG_RTR``, ``canMSG_EXT`` and ``canMSG_ERROR_FRAME`` (``CANPacket.flag``)."""

HEADER_SIZE = 16
"""Bytes before ``frame_id``'s characters: CDR encapsulation or ROS 1 ``seq``, the stamp, the string's length."""
STAMP_AT = 4
"""Where ``stamp``'s two 32-bit fields start, from the message's first byte (both serialisations)."""

_SIZES = {"bool": 1, "uint8": 1, "int8": 1, "byte": 1, "char": 1, "uint16": 2, "int16": 2, "uint32": 4,
          "int32": 4}


def ros2_name(msgtype: str) -> str:
    """``pkg/msg/Type`` for ``pkg/Type`` (ROS 1) or ``pkg/msg/Type``."""
    parts = msgtype.strip("/").split("/")
    return f"{parts[0]}/msg/{parts[-1]}" if len(parts) == 2 else msgtype


def looks_like_can(msgtype: str) -> bool:
    """A type whose name says CAN frame: read, or refused by name, never passed over as if no CAN topic."""
    low = msgtype.lower()
    return "can" in low.split("/")[0] or any(w in low.rsplit("/", 1)[-1] for w in ("can", "fdframe"))


def fields_of(definition: str) -> list[tuple[str, str]]:
    """The ``(type, name)`` of a ``.msg`` definition's own fields (no comments, constants or dependencies)."""
    out = []
    for raw in definition.splitlines():
        if raw.startswith("=" * 10):
            break  # ROS 1 and MCAP append the definitions of the types used
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) < 2 or "=" in parts[1] or (len(parts) > 2 and parts[2].startswith("=")):
            continue  # a constant
        out.append((parts[0], parts[1]))
    return out


@dataclass(frozen=True)
class Field:
    """Where one fixed-size field lies in a body: ``offset``, ``size`` bytes (``count`` items for an array)."""

    offset: int
    size: int
    count: int = 1


@dataclass(frozen=True)
class Layout:
    """Where a frame type's fields lie from the *body* (after ``frame_id``, 4-aligned in CDR): ``fixed``: bytes to the
    last fixed-size field's end; ``sequence``: the offset of a trailing ``uint8`` sequence's length (-1: none)."""

    msgtype: str
    cdr: bool
    fields: dict[str, Field]
    fixed: int
    sequence: int = -1


def layout(msgtype: str, definition: str, cdr: bool) -> Layout:
    """The :class:`Layout` of ``definition`` (one of :data:`DEFINITIONS`) serialised as CDR or ROS 1."""
    fields: dict[str, Field] = {}
    pos = 0
    sequence = -1
    own = fields_of(definition)
    for k, (typ, name) in enumerate(own[1:], 1):
        base, _, count_text = typ.partition("[")
        size = _SIZES[base]
        if count_text == "]" or count_text.startswith("<="):
            if k != len(own) - 1 or size != 1:
                raise ValueError(f"{msgtype}: a sequence is only read as the last field, of bytes")
            pos = (pos + 3) // 4 * 4 if cdr else pos
            sequence = pos
            break
        count = int(count_text[:-1]) if count_text else 1
        if cdr:
            pos = (pos + size - 1) // size * size
        fields[name] = Field(pos, size, count)
        pos += size * count
    return Layout(msgtype, cdr, fields, pos, sequence)


def layout_for(path: object, topic: str, msgtype: str, stored: str, cdr: bool) -> Layout:
    """The layout of ``topic``'s messages by its ``stored`` definition (else the first known); LogFormatError."""
    name = ros2_name(msgtype)
    known = DEFINITIONS.get(name)
    if known is None:
        raise LogFormatError(f"{path}: topic {topic} has type {msgtype}, not a CAN frame type canguard reads "
                             f"(it reads {', '.join(DEFINITIONS)})")
    if not stored.strip():
        return layout(name, known[0], cdr)
    have = [(t.rsplit("/", 1)[-1], n) for t, n in fields_of(stored)]  # a type's package is not compared
    for definition in known:
        if [(t.rsplit("/", 1)[-1], n) for t, n in fields_of(definition)] == have:
            return layout(name, definition, cdr)
    found = " ".join(f"{t} {n};" for t, n in fields_of(stored))
    raise LogFormatError(f"{path}: topic {topic}: its type {msgtype} is defined in the bag with fields "
                         f"{found.rstrip(';')}: not a definition of {name} canguard knows")


def full_definition(msgtype: str) -> str:
    """The ``.msg`` text of a carried type with its dependencies appended, as rosbag2's MCAP schemas hold it."""
    deps = "".join(f"{'=' * 80}\nMSG: {dep.replace('/msg/', '/')}\n{text}" for dep, text in DEPENDENCIES.items())
    return DEFINITIONS[ros2_name(msgtype)][0] + deps


def cdr_frame(stamp_ns: int, frame_id: str, arbitration_id: int, data: bytes, *, extended: bool = False,
              remote: bool = False, error: bool = False, fd: bool = False) -> bytes:
    """A frame serialised as rosbag2 stores it (little-endian CDR), as :func:`frame_type`."""
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    name = frame_id.encode("utf-8") + b"\x00"
    head = struct.pack("<4siII", b"\x00\x01\x00\x00", sec, nanosec, len(name)) + name
    head += b"\x00" * (-(len(head) - 4) % 4)  # the body starts 4-aligned (from the encapsulation's end)
    if fd:
        return head + struct.pack("<I??BxI", arbitration_id, extended, error, len(data), len(data)) + data
    return head + struct.pack("<I???B", arbitration_id, remote, extended, error, len(data)) + data.ljust(8, b"\x00")


def frame_type(fd: bool) -> str:
    """The type :func:`cdr_frame` serialises a frame as."""
    return "ros2_socketcan_msgs/msg/FdFrame" if fd else "can_msgs/msg/Frame"
