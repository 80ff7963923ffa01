"""A ROS 1 bag's messages a chunk at a time, as arrays (as :mod:`canguard.io.mcapscan` reads MCAP).

A ROS 1 bag (format 2.0) is a bag header, chunks (each followed by its index records), then the index (the
connections, where each chunk is). Read from the start, so a bag cut short (no index) gives every chunk before the
cut, then :class:`~canguard.io.mcapscan.McapCut`; a whole bag's connections are read from its index first, a cut
bag's as their records are met. A chunk's records are ``header length, header (op, conn, time), data length,
data``; a CAN topic's all have one length and one field order, so they are found at once where they do.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import numpy as np

from canguard.io.mcapscan import Channel, McapCut, Messages, decompressed, padded, uint_at

MAGIC = b"#ROSBAG V2.0\n"
_U32 = struct.Struct("<I")
OP_MESSAGE, OP_BAG_HEADER, OP_CHUNK, OP_CONNECTION = 0x02, 0x03, 0x05, 0x07


def _fields(header: bytes) -> dict[bytes, tuple[int, bytes]]:
    """A record header's fields: name -> (where its value starts in the header, the value)."""
    out = {}
    pos = 0
    while pos + 4 <= len(header):
        (n,) = _U32.unpack_from(header, pos)
        name, _eq, value = header[pos + 4:pos + 4 + n].partition(b"=")
        out[name] = (pos + 4 + len(name) + 1, value)
        pos += 4 + n
    return out


def _op(fields: dict[bytes, tuple[int, bytes]]) -> int:
    value = fields.get(b"op", (0, b""))[1]
    return value[0] if len(value) == 1 else -1


class Ros1Scan:
    """One ROS 1 bag, read from its start."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.channels: dict[int, Channel] = {}
        self.f: BinaryIO = open(path, "rb")  # noqa: SIM115 -- closed by close()
        try:
            self.size = self.f.seek(0, 2)
            self.f.seek(0)
            if self.f.read(len(MAGIC)) != MAGIC:
                raise McapCut("no '#ROSBAG V2.0' at its start: not a ROS 1 bag")
            self.whole = self._index()
        except BaseException:
            self.f.close()
            raise

    def close(self) -> None:
        """Close the file."""
        self.f.close()

    def _record(self) -> tuple[int, dict[bytes, tuple[int, bytes]], int] | None:
        """The next record's (start, header fields, data length), the file at its data; None at the end."""
        at = self.f.tell()
        head = self.f.read(4)
        if not head:
            return None
        hlen = _U32.unpack(head)[0] if len(head) == 4 else 0
        header = self.f.read(hlen)
        size = self.f.read(4)
        if len(head) < 4 or len(header) < hlen or len(size) < 4:
            raise McapCut(f"the file ends at byte {self.size}, inside the header of the record at byte {at}")
        (dlen,) = _U32.unpack(size)
        if self.f.tell() + dlen > self.size:
            what = "chunk" if _op(_fields(header)) == OP_CHUNK else "record"
            raise McapCut(f"the file ends at byte {self.size}, inside the {what} of {dlen} bytes that starts at "
                          f"byte {at}")
        return at, _fields(header), dlen

    def _index(self) -> bool:
        """Read the connections of the index when the bag has a whole one; the file then at the first chunk."""
        found = self._record()
        if found is None or _op(found[1]) != OP_BAG_HEADER:
            raise McapCut("no bag header record after the magic: not a ROS 1 bag")
        _at, fields, dlen = found
        first = self.f.tell() + dlen
        index = struct.unpack("<Q", fields.get(b"index_pos", (0, bytes(8)))[1])[0]
        count = _U32.unpack(fields.get(b"conn_count", (0, bytes(4)))[1])[0]
        whole = 0 < index < self.size
        if whole:
            self.f.seek(index)
            try:
                for _ in range(count):
                    if (found := self._record()) is None or _op(found[1]) != OP_CONNECTION:
                        raise McapCut("not a connection record where the index says")
                    self._take_connection(found[1], self.f.read(found[2]))
            except McapCut:
                whole = False
        self.f.seek(first)
        return whole and len(self.channels) == count

    def _take_connection(self, fields: dict[bytes, tuple[int, bytes]], data: bytes) -> None:
        conn = _U32.unpack(fields[b"conn"][1])[0]
        info = {k: v for k, (_at, v) in _fields(data).items()}
        self.channels[conn] = Channel(conn, fields.get(b"topic", (0, info.get(b"topic", b"")))[1].decode("utf-8"),
                                      info.get(b"type", b"").decode("utf-8"), "ros1msg",
                                      info.get(b"message_definition", b"").decode("utf-8", "replace"), "ros1")

    def messages(self) -> Iterator[Messages]:
        """Every chunk's messages, in file order."""
        while (found := self._record()) is not None:
            at, fields, dlen = found
            op = _op(fields)
            if op == OP_CHUNK:
                compression = fields.get(b"compression", (0, b"none"))[1].decode("latin-1")
                messages = self._chunk(decompressed(compression, self.f.read(dlen), 0, at))
                if messages is not None:
                    yield messages
            elif op == OP_CONNECTION:
                self._take_connection(fields, self.f.read(dlen))
            else:
                self.f.seek(dlen, 1)

    def _chunk(self, data: bytes) -> Messages | None:
        """The message records of a chunk's records (its connection records taken on the way)."""
        size = len(data)
        buf = padded(data)
        rows: list[tuple[int, int, int, int]] = []  # conn, time (ns), start, length
        pos = 0
        while pos + 8 <= size:
            (hlen,) = _U32.unpack_from(data, pos)
            fields = _fields(data[pos + 4:pos + 4 + hlen])
            (dlen,) = _U32.unpack_from(data, pos + 4 + hlen)
            op = _op(fields)
            if op == OP_MESSAGE:
                if not rows:  # the first message record: the rest of the chunk at once, when it can be
                    run = _same_shape(buf, size, pos, hlen, dlen, fields)
                    if run is not None:
                        return run
                secs, nsecs = struct.unpack("<II", fields[b"time"][1])
                rows.append((_U32.unpack(fields[b"conn"][1])[0], secs * 1_000_000_000 + nsecs, pos + 8 + hlen, dlen))
            elif op == OP_CONNECTION:
                self._take_connection(fields, data[pos + 8 + hlen:pos + 8 + hlen + dlen])
            pos += 8 + hlen + dlen
        if not rows:
            return None
        conns, times, starts, lens = np.array(rows, dtype=np.int64).T
        return Messages(conns, times, buf, starts, lens)


def _same_shape(buf: np.ndarray, size: int, pos: int, hlen: int, dlen: int,
                fields: dict[bytes, tuple[int, bytes]]) -> Messages | None:
    """The message records from ``pos`` to the chunk's end, when each has the first one's lengths and its
    ``op`` field at the same place."""
    step = 8 + hlen + dlen
    if (size - pos) % step or b"conn" not in fields or b"time" not in fields:
        return None
    rec = np.arange(pos, size, step, dtype=np.int64)
    op_at = fields[b"op"][0]
    same = (uint_at(buf, rec, 4) == hlen) & (uint_at(buf, rec + 4 + hlen, 4) == dlen)
    same &= (buf[rec + 4 + op_at] == OP_MESSAGE) & (buf[rec + 4 + op_at - 3] == ord("o"))  # "op=" as in the first
    if not same.all():
        return None
    conn = uint_at(buf, rec + 4 + fields[b"conn"][0], 4)
    time_at = rec + 4 + fields[b"time"][0]
    ns = uint_at(buf, time_at, 4) * 1_000_000_000 + uint_at(buf, time_at + 4, 4)
    return Messages(conn, ns, buf, rec + 8 + hlen, np.full(rec.size, dlen, dtype=np.int64))

