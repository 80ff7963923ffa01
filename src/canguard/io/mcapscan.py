"""An MCAP file's messages a chunk at a time, as arrays: where each message's bytes lie, its channel, its log time.

A chunk is decompressed once and its message records are found at once where they all have one length (a CAN
topic's messages do), one by one only where they do not: a Python object per message would cost more than the
whole replay of the same frames from candump text. The file is read from its start, so a file cut short (a
recorder that died: no summary) gives every chunk before the cut, then :class:`McapCut` saying where it ends; the
summary, when there is one, is read first, so the channels are known before the first message.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

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

    def __init__(self, what: str) -> None:
        super().__init__(what)
        self.what = what


@dataclass(frozen=True)
class Channel:
    """An MCAP channel with its schema (``schema_encoding``: ``ros2msg``, ``ros2idl``, ..., empty for none)."""

    id: int
    topic: str
    schema_name: str
    schema_encoding: str
    schema: str
    message_encoding: str


@dataclass
class Messages:
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
    """A chunk's records (MCAP: zstd or lz4; ROS 1: bz2 or lz4; ``size``: the uncompressed size, 0 unknown),
    with ``lz4`` and ``zstandard``, rosbags' own dependencies. McapCut when it does not decompress."""
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


class McapScan:
    """One MCAP file, read from its start."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.schemas: dict[int, tuple[str, str, str]] = {}
        self.channels: dict[int, Channel] = {}
        self.f: BinaryIO = open(path, "rb")  # noqa: SIM115 -- closed by close()
        try:
            self.size = self.f.seek(0, 2)
            self.f.seek(0)
            if self.f.read(8) != MAGIC:
                raise McapCut("no MCAP magic at its start: not an MCAP file")
            self.whole = self._summary()
            self.f.seek(8)
        except BaseException:
            self.f.close()
            raise

    def close(self) -> None:
        """Close the file."""
        self.f.close()

    def _summary(self) -> bool:
        """Read the summary's schemas and channels when the file ends as a whole MCAP does; False: it does not."""
        f = self.f
        if self.size < 8 + 9 + 20 + 8:
            return False
        f.seek(self.size - 8 - 9 - 20)
        op, _length, start, _offsets, _crc, magic = struct.unpack("<BQQQI8s", f.read(37))
        if magic != MAGIC or op != OP_FOOTER:
            return False
        if start:
            f.seek(start)
            summary = f.read(self.size - 8 - 29 - start)
            pos = 0
            while pos + 9 <= len(summary):
                op, length = _OPLEN.unpack_from(summary, pos)
                self._record(op, summary[pos + 9:pos + 9 + length])
                pos += 9 + length
        return True

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
            self.channels[cid] = Channel(cid, topic, name, schema_encoding, schema, encoding)

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
                yield _loose(loose)
                loose = []
            if op == OP_CHUNK:
                records = self._chunk(body, at)
                if records is not None:
                    yield records
            else:
                self._record(op, body)
        if loose:
            yield _loose(loose)

    def _chunk(self, body: bytes, at: int) -> Messages | None:
        """A chunk's message records as arrays (its schema and channel records taken on the way)."""
        (size,) = _U64.unpack_from(body, 16)
        compression, pos = _string(body, 28)
        (n,) = _U64.unpack_from(body, pos)
        return _chunk_messages(decompressed(compression, body[pos + 8:pos + 8 + n], size, at), self._record)


def _loose(records: list[bytes]) -> Messages:
    """Unchunked message records as arrays."""
    found = _chunk_messages(b"".join(records), lambda op, body: None)
    assert found is not None
    return found


def _chunk_messages(data: bytes, other: Callable[[int, bytes], None]) -> Messages | None:
    """The message records of a chunk's ``data``; other records go to ``other``. None: no message."""
    size = len(data)
    buf = padded(data)
    starts: list[Any] = []
    pos = 0
    tried = False
    while pos + 9 <= size:
        op, length = _OPLEN.unpack_from(data, pos)
        if op == OP_MESSAGE and not tried:
            tried = True  # once a chunk: records of one length from here to its end are found at once
            run = _same_length(buf, pos, length, size)
            if run is not None:
                starts.append(run)
                break
        if op == OP_MESSAGE:
            starts.append(np.array([pos], dtype=np.int64))
        else:
            other(op, data[pos + 9:pos + 9 + length])
        pos += 9 + length
    if not starts:
        return None
    rec = np.concatenate(starts)
    lens = uint_at(buf, rec + 1, 8)
    if (rec + 9 + lens > size).any() or (lens < _MESSAGE_HEAD).any():
        raise McapCut("a message record inside a chunk runs past the chunk's end")
    return Messages(uint_at(buf, rec + 9, 2), uint_at(buf, rec + 9 + 6, 8), buf, rec + 9 + _MESSAGE_HEAD,
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

