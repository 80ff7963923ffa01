"""Write an MCAP file (what Foxglove opens) with many small messages at numpy speed.

A column of messages of one size is one structured array (:meth:`McapWriter.messages`); the file is indexed, its
chunks zstd-compressed when ``zstandard`` is there.
"""

from __future__ import annotations

import contextlib
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from canguard.io.bagscan import MAGIC, OP_CHANNEL, OP_CHUNK, OP_DATA_END, OP_FOOTER, OP_MESSAGE, OP_SCHEMA

OP_HEADER, OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_SUMMARY_OFFSET = 0x01, 0x07, 0x08, 0x0B, 0x0E
CHUNK_BYTES = 1 << 20
"""Records gathered before a chunk is written."""


def ns_of(t: Any) -> np.ndarray:
    """Seconds as whole nanoseconds (int64), whole seconds and fraction apart (``t * 1e9`` rounds to 256 ns)."""
    s = np.asarray(t, dtype=np.float64)
    whole = np.floor(s)
    return whole.astype(np.int64) * 1_000_000_000 + np.rint((s - whole) * 1e9).astype(np.int64)


def _str(text: str) -> bytes:
    raw = text.encode("utf-8")
    return struct.pack("<I", len(raw)) + raw


def _record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _map(entries: dict[int, int], fmt: str) -> bytes:
    """An MCAP map of integers (``fmt``: the key's and value's struct codes)."""
    body = b"".join(struct.pack("<" + fmt, k, v) for k, v in sorted(entries.items()))
    return struct.pack("<I", len(body)) + body


class McapWriter:
    """An MCAP file being written: :meth:`schema`, :meth:`channel`, then messages; :meth:`close` ends it."""

    def __init__(self, path: Path, profile: str = "") -> None:
        self.f = open(path, "wb")  # noqa: SIM115 -- closed by close()
        self.f.write(MAGIC + _record(OP_HEADER, _str(profile) + _str("canguard")))
        self._schemas: list[bytes] = []
        self._channels: list[bytes] = []
        self._chunk: list[bytes] = []
        self._chunk_size = 0
        self._chunk_times = (2**64 - 1, 0)
        self._index: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}  # per channel: log times, offsets
        self._chunk_indexes: list[bytes] = []
        self._counts: dict[int, int] = {}
        self._times = (2**64 - 1, 0)
        self._compression, self._zstd = "", None
        with contextlib.suppress(ImportError):
            import zstandard

            self._compression, self._zstd = "zstd", zstandard.ZstdCompressor(level=1)

    def schema(self, name: str, encoding: str, data: str) -> int:
        """Add a schema (``ros2msg``, ``jsonschema``, ...); its id."""
        sid = len(self._schemas) + 1
        raw = data.encode("utf-8")
        rec = _record(OP_SCHEMA, struct.pack("<H", sid) + _str(name) + _str(encoding) + struct.pack("<I", len(raw))
                      + raw)
        self._schemas.append(rec)
        self.f.write(rec)
        return sid

    def channel(self, topic: str, schema_id: int, encoding: str) -> int:
        """Add a channel (messages of ``schema_id`` encoded as ``cdr``, ``json``, ...); its id."""
        cid = len(self._channels) + 1
        rec = _record(OP_CHANNEL, struct.pack("<HH", cid, schema_id) + _str(topic) + _str(encoding) + _map({}, "HH"))
        self._channels.append(rec)
        self.f.write(rec)
        self._counts[cid] = 0
        return cid

    def messages(self, channel_id: int, log_ns: np.ndarray, data: np.ndarray) -> None:
        """Messages on ``channel_id`` at ``log_ns`` (int64 ns), message ``i`` the bytes of row ``i`` of ``data``."""
        n = int(log_ns.size)
        if not n:
            return
        width = int(data.shape[1])
        rows = np.zeros(n, dtype=np.dtype([("op", "u1"), ("len", "<u8"), ("channel", "<u2"), ("seq", "<u4"),
                                           ("log", "<u8"), ("pub", "<u8"), ("data", "u1", (width,))]))
        rows["op"] = OP_MESSAGE
        rows["len"] = 22 + width
        rows["channel"] = channel_id
        rows["log"] = rows["pub"] = log_ns
        rows["data"] = data
        offsets = self._chunk_size + np.arange(n, dtype=np.int64) * (31 + width)
        self._index.setdefault(channel_id, []).append((np.asarray(log_ns, dtype=np.int64), offsets))
        self._chunk.append(rows.tobytes())
        self._chunk_size += int(rows.nbytes)
        self._counts[channel_id] += n
        self._chunk_times = (min(self._chunk_times[0], int(log_ns.min())), max(self._chunk_times[1], int(log_ns.max())))
        if self._chunk_size >= CHUNK_BYTES:
            self._flush()

    def message(self, channel_id: int, log_ns: int, data: bytes) -> None:
        """One message (an event, a frame: few of them)."""
        self.messages(channel_id, np.array([log_ns], dtype=np.int64), np.frombuffer(data, dtype=np.uint8)[None])

    def _flush(self) -> None:
        if not self._chunk:
            return
        raw = b"".join(self._chunk)
        data = self._zstd.compress(raw) if self._zstd is not None else raw
        start, end = self._chunk_times
        body = (struct.pack("<QQQI", start, end, len(raw), zlib.crc32(raw)) + _str(self._compression)
                + struct.pack("<Q", len(data)) + data)
        at = self.f.tell()
        self.f.write(_record(OP_CHUNK, body))
        index_start = self.f.tell()
        offsets = {}
        for channel, parts in sorted(self._index.items()):
            times = np.concatenate([p[0] for p in parts])
            where = np.concatenate([p[1] for p in parts])
            order = np.argsort(times, kind="stable")
            pairs = np.empty((times.size, 2), dtype="<u8")
            pairs[:, 0], pairs[:, 1] = times[order], where[order]
            offsets[channel] = self.f.tell()
            self.f.write(_record(OP_MESSAGE_INDEX, struct.pack("<HI", channel, pairs.nbytes) + pairs.tobytes()))
        self._chunk_indexes.append(_record(OP_CHUNK_INDEX, struct.pack("<QQQQ", start, end, at, 9 + len(body))
                                           + _map(offsets, "HQ") + struct.pack("<Q", self.f.tell() - index_start)
                                           + _str(self._compression) + struct.pack("<QQ", len(data), len(raw))))
        self._index = {}
        self._times = (min(self._times[0], start), max(self._times[1], end))
        self._chunk, self._chunk_size, self._chunk_times = [], 0, (2**64 - 1, 0)

    def close(self) -> None:
        """Write what is left, the summary and the footer; close the file."""
        try:
            self._flush()
            f = self.f
            f.write(_record(OP_DATA_END, struct.pack("<I", 0)))
            summary_start = f.tell()
            groups = []
            start, end = self._times if self._chunk_indexes else (0, 0)
            stats = _record(OP_STATISTICS, struct.pack("<QHIIII", sum(self._counts.values()), len(self._schemas),
                                                       len(self._channels), 0, 0, len(self._chunk_indexes))
                            + struct.pack("<QQ", start, end) + _map(self._counts, "HQ"))
            for op, records in ((OP_SCHEMA, self._schemas), (OP_CHANNEL, self._channels),
                                (OP_STATISTICS, [stats]), (OP_CHUNK_INDEX, self._chunk_indexes)):
                if records:
                    at = f.tell()
                    f.write(b"".join(records))
                    groups.append(struct.pack("<BQQ", op, at, f.tell() - at))
            offsets_start = f.tell()
            for group in groups:
                f.write(_record(OP_SUMMARY_OFFSET, group))
            f.write(_record(OP_FOOTER, struct.pack("<QQI", summary_start, offsets_start, 0)) + MAGIC)
        finally:
            self.f.close()
