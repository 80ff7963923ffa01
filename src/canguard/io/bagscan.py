"""A bag file's messages a chunk at a time, as arrays: where each message's bytes lie, its channel, its log time.

MCAP and ROS 1 bags, no Python object per message, read from the start: one cut short gives every chunk before the
cut, then :class:`McapCut` saying where it ends.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import numpy as np

MAGIC = b"\x89MCAP0\r\n"
OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_DATA_END = 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F
_MESSAGE_HEAD = 22
"""Bytes of a message record before its data: channel id, sequence, log time, publish time."""
PAD = 128
"""Zero bytes after a block's buffer: fields read past a short message's end read them, not past the array."""

_NAMES = {OP_SCHEMA: "schema", OP_CHANNEL: "channel", OP_MESSAGE: "message", OP_CHUNK: "chunk"}
_OPLEN = struct.Struct("<BQ")
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")


class McapCut(Exception):
    """The file ends (or turns to garbage) before its data section does: where, and what was found there."""


class Channel(NamedTuple):
    """An MCAP channel with its schema (``schema_encoding``: ``ros2msg``, ``ros2idl``, ..., empty for none)."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema: str
    message_encoding: str


class Messages(NamedTuple):
    """A chunk's messages: each one's channel, log time (ns), and where its data lies in ``buf`` (zero-padded)."""

    channel: np.ndarray
    log_ns: np.ndarray
    buf: np.ndarray
    start: np.ndarray
    lengths: np.ndarray


def _string(body: bytes, pos: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(body, pos)
    return body[pos + 4:pos + 4 + n].decode("utf-8", "replace"), pos + 4 + n


def padded(data: bytes) -> np.ndarray:
    """``data`` as uint8 with :data:`PAD` zero bytes after it."""
    buf = np.zeros(len(data) + PAD, dtype=np.uint8)
    buf[:len(data)] = np.frombuffer(data, dtype=np.uint8)
    return buf


def uint_at(buf: np.ndarray, at: np.ndarray, size: int) -> np.ndarray:
    """The little-endian unsigned integer of ``size`` bytes (1, 2, 4 or 8) at each of ``at``, as int64."""
    return buf[at[:, None] + np.arange(size)].view(f"<u{size}").ravel().astype(np.int64)


def decompressed(compression: str, data: bytes, size: int, at: int) -> bytes:
    """A chunk's records (``size``: uncompressed, 0 unknown); McapCut when it does not decompress."""
    try:
        if compression in ("", "none"):
            return data
        if compression == "zstd":
            import zstandard

            return bytes(zstandard.ZstdDecompressor().decompress(data, max_output_size=size))
        if compression == "lz4":
            import lz4.frame

            return bytes(lz4.frame.decompress(data))
        if compression == "bz2":
            import bz2

            return bz2.decompress(data)
    except Exception as exc:  # zstd / lz4 / bz2 errors of a damaged chunk
        raise McapCut(f"the chunk at byte {at} does not decompress ({compression}): {exc}") from None
    raise McapCut(f"a chunk compressed as {compression!r}, which canguard does not read")


class _Scan:
    """A bag file, read from its start; ``whole``: ``index`` read every channel first (the file then at its data)."""

    def __init__(self, path: Path, magic: bytes, not_one: str, index: Callable[[], bool]) -> None:
        self.channels: dict[int, Channel] = {}
        self.f: BinaryIO = open(path, "rb")  # noqa: SIM115 -- closed by close()
        try:
            self.size = self.f.seek(0, 2)
            self.f.seek(0)
            if self.f.read(len(magic)) != magic:
                raise McapCut(f"no {not_one}")
            self.whole = index()
        except BaseException:
            self.f.close()
            raise

    def close(self) -> None:
        """Close the file."""
        self.f.close()


class McapScan(_Scan):
    """One MCAP file, read from its start."""

    def __init__(self, path: Path) -> None:
        self.schemas: dict[int, tuple[str, str, str]] = {}
        super().__init__(path, MAGIC, "MCAP magic at its start: not an MCAP file", self._summary)

    def _summary(self) -> bool:
        """Read the summary's schemas and channels when the file ends as a whole MCAP does; False: it does not."""
        f = self.f
        if self.size < 8 + 9 + 20 + 8:
            return False
        f.seek(self.size - 8 - 9 - 20)
        op, _length, start, _offsets, _crc, magic = struct.unpack("<BQQQI8s", f.read(37))
        whole = magic == MAGIC and op == OP_FOOTER
        if whole and start:
            f.seek(start)
            summary = f.read(self.size - 8 - 29 - start)
            pos = 0
            while pos + 9 <= len(summary):
                op, length = _OPLEN.unpack_from(summary, pos)
                self._record(op, summary[pos + 9:pos + 9 + length])
                pos += 9 + length
        f.seek(8)
        return whole

    def _record(self, op: int, body: bytes) -> None:
        """Take a schema or channel record."""
        if op == OP_SCHEMA:
            (sid,) = _U16.unpack_from(body, 0)
            name, pos = _string(body, 2)
            encoding, pos = _string(body, pos)
            (n,) = _U32.unpack_from(body, pos)
            self.schemas[sid] = (name, encoding, body[pos + 4:pos + 4 + n].decode("utf-8", "replace"))
        elif op == OP_CHANNEL:
            cid, sid = struct.unpack_from("<HH", body, 0)
            topic, pos = _string(body, 4)
            encoding, pos = _string(body, pos)
            name, schema_encoding, schema = self.schemas.get(sid, ("", "", ""))
            self.channels[cid] = Channel(topic, name, schema_encoding, schema, encoding)

    def messages(self) -> Iterator[Messages]:
        """Every message of the data section, a chunk (or a run of unchunked messages) at a time, in file order."""
        loose: list[bytes] = []
        f = self.f
        while True:
            at = f.tell()
            head = f.read(9)
            if not head:
                break  # the file ends between records: no data end, no footer, nothing lost
            if len(head) < 9:
                raise McapCut(f"the file ends at byte {self.size}, inside the header of the record at byte {at}")
            op, length = _OPLEN.unpack(head)
            if op in (OP_DATA_END, OP_FOOTER):
                break
            what = f"{_NAMES.get(op, f'op {op:#04x}')} record of {length} bytes"
            if at + 9 + length > self.size:
                raise McapCut(f"the file ends at byte {self.size}, inside the {what} that starts at byte {at}")
            body = f.read(length)
            if op == OP_MESSAGE:
                loose.append(head + body)
                continue
            if loose:
                yield from _chunk_messages(b"".join(loose), self._record)
                loose = []
            if op == OP_CHUNK:
                (size,) = _U64.unpack_from(body, 16)
                compression, pos = _string(body, 28)
                (n,) = _U64.unpack_from(body, pos)
                yield from _chunk_messages(decompressed(compression, body[pos + 8:pos + 8 + n], size, at),
                                           self._record)
            else:
                self._record(op, body)
        yield from _chunk_messages(b"".join(loose), self._record)


def _chunk_messages(data: bytes, other: Callable[[int, bytes], None]) -> Iterator[Messages]:
    """The message records of a chunk's ``data`` (none, or one :class:`Messages`); other records go to ``other``."""
    size = len(data)
    buf = padded(data)
    starts: list[Any] = []
    pos = 0
    while pos + 9 <= size:
        op, length = _OPLEN.unpack_from(data, pos)
        if op != OP_MESSAGE:
            other(op, data[pos + 9:pos + 9 + length])
        elif not starts and (run := _same_length(buf, pos, length, size)) is not None:
            starts.append(run)  # the chunk's first message: records of one length from it to the end, found at once
            break
        else:
            starts.append(np.array([pos], dtype=np.int64))
        pos += 9 + length
    if not starts:
        return
    rec = np.concatenate(starts)
    lens = uint_at(buf, rec + 1, 8)
    if (rec + 9 + lens > size).any() or (lens < _MESSAGE_HEAD).any():
        raise McapCut("a message record inside a chunk runs past the chunk's end")
    yield Messages(uint_at(buf, rec + 9, 2), uint_at(buf, rec + 9 + 6, 8), buf, rec + 9 + _MESSAGE_HEAD,
                   lens - _MESSAGE_HEAD)


def _same_length(buf: np.ndarray, pos: int, length: int, size: int) -> np.ndarray | None:
    """The record starts from ``pos`` to the end when every record there is a message of ``length`` bytes."""
    step = 9 + length
    if (size - pos) % step:
        return None
    rec = np.arange(pos, size, step, dtype=np.int64)
    if not ((buf[rec] == OP_MESSAGE).all() and (uint_at(buf, rec + 1, 8) == length).all()):
        return None
    return rec


ROS1_MAGIC = b"#ROSBAG V2.0\n"
ROS1_MESSAGE, ROS1_BAG_HEADER, ROS1_CHUNK, ROS1_CONNECTION = 0x02, 0x03, 0x05, 0x07


def _ros1_fields(header: bytes) -> dict[bytes, tuple[int, bytes]]:
    """A record header's fields: name -> (where its value starts in the header, the value)."""
    out = {}
    pos = 0
    while pos + 4 <= len(header):
        (n,) = _U32.unpack_from(header, pos)
        name, _eq, value = header[pos + 4:pos + 4 + n].partition(b"=")
        out[name] = (pos + 4 + len(name) + 1, value)
        pos += 4 + n
    return out


def _ros1_op(fields: dict[bytes, tuple[int, bytes]]) -> int:
    value = fields.get(b"op", (0, b""))[1]
    return value[0] if len(value) == 1 else -1


class Ros1Scan(_Scan):
    """One ROS 1 bag, read from its start."""

    def __init__(self, path: Path) -> None:
        super().__init__(path, ROS1_MAGIC, "'#ROSBAG V2.0' at its start: not a ROS 1 bag", self._index)

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
            what = "chunk" if _ros1_op(_ros1_fields(header)) == ROS1_CHUNK else "record"
            raise McapCut(f"the file ends at byte {self.size}, inside the {what} of {dlen} bytes that starts at "
                          f"byte {at}")
        return at, _ros1_fields(header), dlen

    def _index(self) -> bool:
        """Read the connections of the index when the bag has a whole one; the file then at the first chunk."""
        found = self._record()
        if found is None or _ros1_op(found[1]) != ROS1_BAG_HEADER:
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
                    if (found := self._record()) is None or _ros1_op(found[1]) != ROS1_CONNECTION:
                        raise McapCut("not a connection record where the index says")
                    self._take_connection(found[1], self.f.read(found[2]))
            except McapCut:
                whole = False
        self.f.seek(first)
        return whole and len(self.channels) == count

    def _take_connection(self, fields: dict[bytes, tuple[int, bytes]], data: bytes) -> None:
        conn = _U32.unpack(fields[b"conn"][1])[0]
        info = {k: v for k, (_at, v) in _ros1_fields(data).items()}
        self.channels[conn] = Channel(fields.get(b"topic", (0, info.get(b"topic", b"")))[1].decode("utf-8"),
                                      info.get(b"type", b"").decode("utf-8"), "ros1msg",
                                      info.get(b"message_definition", b"").decode("utf-8", "replace"), "ros1")

    def messages(self) -> Iterator[Messages]:
        """Every chunk's messages, in file order."""
        while (found := self._record()) is not None:
            at, fields, dlen = found
            op = _ros1_op(fields)
            if op == ROS1_CHUNK:
                compression = fields.get(b"compression", (0, b"none"))[1].decode("latin-1")
                yield from self._chunk(decompressed(compression, self.f.read(dlen), 0, at))
            elif op == ROS1_CONNECTION:
                self._take_connection(fields, self.f.read(dlen))
            else:
                self.f.seek(dlen, 1)

    def _chunk(self, data: bytes) -> Iterator[Messages]:
        """The message records of a chunk (none, or one :class:`Messages`), its connection records taken."""
        size = len(data)
        buf = padded(data)
        rows: list[tuple[int, int, int, int]] = []  # conn, time (ns), start, length
        pos = 0
        while pos + 8 <= size:
            (hlen,) = _U32.unpack_from(data, pos)
            fields = _ros1_fields(data[pos + 4:pos + 4 + hlen])
            (dlen,) = _U32.unpack_from(data, pos + 4 + hlen)
            op = _ros1_op(fields)
            if op == ROS1_MESSAGE:
                if not rows:  # the first message record: the rest of the chunk at once, when it can be
                    run = _same_shape(buf, size, pos, hlen, dlen, fields)
                    if run is not None:
                        yield run
                        return
                secs, nsecs = struct.unpack("<II", fields[b"time"][1])
                rows.append((_U32.unpack(fields[b"conn"][1])[0], secs * 1_000_000_000 + nsecs, pos + 8 + hlen, dlen))
            elif op == ROS1_CONNECTION:
                self._take_connection(fields, data[pos + 8 + hlen:pos + 8 + hlen + dlen])
            pos += 8 + hlen + dlen
        if rows:
            conns, times, starts, lens = np.array(rows, dtype=np.int64).T
            yield Messages(conns, times, buf, starts, lens)


def _same_shape(buf: np.ndarray, size: int, pos: int, hlen: int, dlen: int,
                fields: dict[bytes, tuple[int, bytes]]) -> Messages | None:
    """The message records from ``pos`` to the chunk's end, when each has the first one's lengths and ``op``."""
    step = 8 + hlen + dlen
    if (size - pos) % step or b"conn" not in fields or b"time" not in fields:
        return None
    rec = np.arange(pos, size, step, dtype=np.int64)
    op_at = fields[b"op"][0]
    same = (uint_at(buf, rec, 4) == hlen) & (uint_at(buf, rec + 4 + hlen, 4) == dlen)
    same &= (buf[rec + 4 + op_at] == ROS1_MESSAGE) & (buf[rec + 4 + op_at - 3] == ord("o"))  # "op=" as in the first
    if not same.all():
        return None
    conn = uint_at(buf, rec + 4 + fields[b"conn"][0], 4)
    time_at = rec + 4 + fields[b"time"][0]
    ns = uint_at(buf, time_at, 4) * 1_000_000_000 + uint_at(buf, time_at + 4, 4)
    return Messages(conn, ns, buf, rec + 8 + hlen, np.full(rec.size, dlen, dtype=np.int64))
