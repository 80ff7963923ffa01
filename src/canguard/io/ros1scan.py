"""A ROS 1 bag's message records a chunk at a time, as arrays (as :mod:`canguard.io.mcapscan` reads MCAP).

A ROS 1 chunk holds records ``header length, header (op, conn, time fields), data
length, data``. A CAN topic's message records all have one length and their fields in
one order, so from the first message record of a chunk to its end they are found at
once when they do (one check over the chunk's bytes); otherwise record by record. The
chunks (where each lies, how it is compressed) come from rosbags' reader of the bag's
index.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np

from canguard.io.mcapscan import PAD, Messages

_U32 = struct.Struct("<I")
_OP_MESSAGE = 0x02


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


def chunk_messages(data: bytes) -> Messages | None:
    """The message records of a chunk's (decompressed) ``data``: connection id, record time (ns), where each
    message's data lies. None: no message record."""
    size = len(data)
    buf = np.zeros(size + PAD, dtype=np.uint8)
    buf[:size] = np.frombuffer(data, dtype=np.uint8)
    conns: list[int] = []
    times: list[int] = []
    starts: list[int] = []
    lens: list[int] = []
    pos = 0
    while pos + 8 <= size:
        (hlen,) = _U32.unpack_from(data, pos)
        header = data[pos + 4:pos + 4 + hlen]
        (dlen,) = _U32.unpack_from(data, pos + 4 + hlen)
        fields = _fields(header)
        if fields.get(b"op", (0, b""))[1] == bytes([_OP_MESSAGE]):
            if not conns:  # the first message record: the rest of the chunk at once, when it can be
                run = _same_shape(buf, data, pos, hlen, dlen, fields)
                if run is not None:
                    return run
            conns.append(_U32.unpack(fields[b"conn"][1])[0])
            secs, nsecs = struct.unpack("<II", fields[b"time"][1])
            times.append(secs * 1_000_000_000 + nsecs)
            starts.append(pos + 8 + hlen)
            lens.append(dlen)
        pos += 8 + hlen + dlen
    if not conns:
        return None
    return Messages(np.array(conns, dtype=np.int64), np.array(times, dtype=np.int64), buf,
                    np.array(starts, dtype=np.int64), np.array(lens, dtype=np.int64))


def _same_shape(buf: np.ndarray, data: bytes, pos: int, hlen: int, dlen: int,
                fields: dict[bytes, tuple[int, bytes]]) -> Messages | None:
    """The message records from ``pos`` to the chunk's end, when each has the first one's lengths and its
    ``op`` field at the same place."""
    step = 8 + hlen + dlen
    size = len(data)
    if (size - pos) % step or b"conn" not in fields or b"time" not in fields:
        return None
    rec = np.arange(pos, size, step, dtype=np.int64)
    op_at = fields[b"op"][0]
    same = (_u32(buf, rec) == hlen) & (_u32(buf, rec + 4 + hlen) == dlen) & (buf[rec + 4 + op_at] == _OP_MESSAGE)
    same &= buf[rec + 4 + op_at - 3] == ord("o")  # "op=" is where the first record has it
    if not same.all():
        return None
    conn = _u32(buf, rec + 4 + fields[b"conn"][0])
    time_at = rec + 4 + fields[b"time"][0]
    ns = _u32(buf, time_at) * 1_000_000_000 + _u32(buf, time_at + 4)
    return Messages(conn, ns, buf, rec + 8 + hlen, np.full(rec.size, dlen, dtype=np.int64))


def _u32(buf: np.ndarray, at: np.ndarray) -> np.ndarray:
    return buf[at[:, None] + np.arange(4)].view("<u4").ravel().astype(np.int64)


def chunks(path: Path, where: Sequence[tuple[int, int, Callable[[bytes], bytes]]]) -> Iterator[Messages]:
    """The messages of each chunk (``(data position, data size, decompressor)``, in file order)."""
    with open(path, "rb") as f:
        for pos, size, decompress in where:
            f.seek(pos)
            found = chunk_messages(decompress(f.read(size)))
            if found is not None:
                yield found
