"""ROS bags as CAN logs: rosbag2 (a directory with ``metadata.yaml``, a ``.db3`` or ``.mcap``) and ROS 1 ``.bag``.

A block of raw messages at a time (:class:`BagSource`), every field gathered by numpy at once (:func:`unpack`);
what a frame, a bad message or a bad bag is: docs/commands.md.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, fields
from itertools import islice
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from canguard.errors import LogFormatError, clip
from canguard.io.bagopts import BagOptions
from canguard.io.bagscan import McapCut, McapScan, Messages, Ros1Scan, padded, uint_at
from canguard.io.block import FLAG_ERROR, FLAG_FD, FLAG_REMOTE, Block
from canguard.io.logtypes import (
    CAN_EFF_MASK,
    CAN_SFF_MASK,
    CANFD_LENGTHS,
    Blocks,
    ReadStats,
)
from canguard.io.rosmsgs import (
    DEFINITIONS,
    HEADER_SIZE,
    KVASER_ERROR_FRAME,
    KVASER_EXT,
    KVASER_RTR,
    STAMP_AT,
    Layout,
    layout_for,
    looks_like_can,
)

BLOCK = 4096
"""Raw messages taken at a time from a sqlite3 storage (an MCAP or ROS 1 block is one chunk)."""


class Topic(NamedTuple):
    """A topic read: its channel's index (:attr:`BagSource.channels`) and the layout of its messages."""

    lane: int
    layout: Layout


class BagSource:
    """One bag: the topics read, their channels, and the raw messages a block at a time."""

    def __init__(self, path: Path, opts: BagOptions) -> None:
        self.path = path
        self.opts = opts
        suffix = path.suffix.lower()
        self.kind = "MCAP" if suffix == ".mcap" and path.is_file() else "ROS 1 bag" if suffix == ".bag" else "rosbag2"
        self.channels: list[str] = []
        """The topics read, in the order their channels are numbered."""
        self.total = 0
        """Messages of the topics read as the bag's index counts them (0: unknown)."""
        self._layouts: dict[tuple[str, str], Layout] = {}
        self._seen: dict[str, str] = {}  # every topic met, with its type (the errors list them)
        self.reader: Any = None
        self.scans: list[McapScan] = []

    def failed(self, what: str, exc: BaseException) -> LogFormatError:
        """The error of a bag that could not be read (``what``: where and how far), naming the bag."""
        why = str(exc) if isinstance(exc, McapCut) else f"{type(exc).__name__}: {clip(str(exc))}"
        return LogFormatError(f"{self.path}: not a readable {self.kind} ({what}): {why}")

    def open(self) -> None:
        """Open the bag and choose its topics (LogFormatError: it cannot be read, or has none to read)."""
        try:
            if self.kind in ("MCAP", "ROS 1 bag"):
                scan: Any = McapScan(self.path) if self.kind == "MCAP" else Ros1Scan(self.path)
                self.scans = [scan]
                if scan.whole:
                    self.choose([(c.topic, c.schema_name, self._definition(c)) for c in scan.channels.values()])
                return
            import rosbags.rosbag2

            reader = rosbags.rosbag2.Reader(self.path)
            reader.open()
            self.reader = reader
        except LogFormatError:
            raise
        except McapCut as exc:
            self.close()
            raise LogFormatError(f"{self.path}: not a {self.kind}: {exc}") from None
        except Exception as exc:  # rosbags raises its ReaderError, but also struct, yaml and OS errors on a cut bag
            self.close()
            raise self.failed("cut short, unindexed or not a bag; 0 frames were read", exc) from None
        conns = self.reader.connections
        self.choose([(c.topic, c.msgtype, c.msgdef.data) for c in conns])
        self.total = sum(int(c.msgcount or 0) for c in conns if c.topic in self.channels)
        files = [Path(s.path) for s in getattr(self.reader.storage, "storages", None) or ()]
        if files and all(f.suffix == ".mcap" for f in files):  # read file by file by canguard's chunk
            # reader (rosbags' stays open: it may hold the files decompressed in a temporary directory)
            self.scans = [McapScan(f) for f in files]

    @staticmethod
    def _definition(channel: Any) -> str:
        """A channel's stored ``.msg`` definition ("" when it has none canguard can compare: an IDL one)."""
        return channel.schema if channel.schema_encoding in ("ros2msg", "ros1msg") else ""

    def choose(self, connections: list[tuple[str, str, str]]) -> None:
        """Choose the topics to read; LogFormatError saying what the bag holds when none is or one is missing."""
        types: dict[str, str] = {}
        for topic, msgtype, _definition in connections:
            types.setdefault(topic, msgtype)
        self._seen.update(types)
        chosen = list(dict.fromkeys(self.opts.topics)) or sorted(t for t, typ in types.items() if looks_like_can(typ))
        self._check_found(chosen)
        for topic, msgtype, definition in connections:
            if topic in chosen:
                self.topic(topic, msgtype, definition)  # refused now, not at its first message

    def _check_found(self, chosen: list[str]) -> None:
        """LogFormatError listing the topics met when a topic asked for is not among them or nothing is chosen."""
        missing = [t for t in self.opts.topics if t not in self._seen]
        if missing:
            why = f"no topic {', '.join(missing)}"
        elif not chosen:
            why = f"no topic of a CAN frame type ({', '.join(DEFINITIONS)})"
        else:
            return
        found = ", ".join(f"{t} ({typ})" for t, typ in sorted(self._seen.items())) or "none"
        raise LogFormatError(f"{self.path}: {why} in the bag; its topics: {found}")

    def topic(self, topic: str, msgtype: str, definition: str) -> Topic:
        """The :class:`Topic` of a chosen topic's connection (its channel numbered at its first)."""
        lay = layout_for(self.path, topic, msgtype, definition, self.kind != "ROS 1 bag")
        lay = self._layouts.setdefault((lay.msgtype, repr(lay)), lay)  # one object per layout: one unpack
        if topic not in self.channels:
            self.channels.append(topic)
        return Topic(self.channels.index(topic), lay)

    def _wants(self, topic: str, msgtype: str) -> bool:
        """A topic met in a cut MCAP (no summary): read it?"""
        self._seen.setdefault(topic, msgtype)
        return topic in self.opts.topics if self.opts.topics else looks_like_can(msgtype)

    def blocks(self) -> Iterator[tuple[Messages, dict[int, Topic]]]:
        """The chosen topics' raw messages a block at a time, in the storage's order, with their channels' topics."""
        for scan in self.scans:
            yield from self._scan_blocks(scan)
        if not self.scans:
            storage = self.reader.storage
            for db in getattr(storage, "storages", None) or [storage]:
                yield from self._sqlite_blocks(db)

    def _scan_blocks(self, scan: Any) -> Iterator[tuple[Messages, dict[int, Topic]]]:
        """The chosen topics' messages of a file canguard reads itself (:class:`McapScan`, :class:`Ros1Scan`)."""
        met: set[int] = set()
        topics: dict[int, Topic] = {}
        for found in scan.messages():
            for cid in set(np.unique(found.channel).tolist()) - met:
                met.add(cid)
                channel = scan.channels.get(cid)
                if channel is None:
                    raise McapCut(f"a message of channel {cid}, which no channel record defines")
                if channel.message_encoding in ("cdr", "ros1") and (channel.topic in self.channels or (
                        not scan.whole and self._wants(channel.topic, channel.schema_name))):
                    topics[cid] = self.topic(channel.topic, channel.schema_name, self._definition(channel))
            keep = np.isin(found.channel, list(topics))
            if keep.all():
                yield found, topics
            elif keep.any():
                rows = np.flatnonzero(keep)
                yield Messages(found.channel[rows], found.log_ns[rows], found.buf, found.start[rows],
                               found.lengths[rows]), topics

    def _sqlite_blocks(self, db: Any) -> Iterator[tuple[Messages, dict[int, Topic]]]:
        """One sqlite3 storage's messages of the chosen topics, in record time order."""
        mine = {c.id: self.topic(c.topic, c.msgtype, self._stored(c)) for c in db.connections
                if c.topic in self.channels}
        if not mine:
            return
        ids = ",".join(str(int(i)) for i in mine)
        cursor = db.dbconn.execute(
            f"SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN ({ids}) ORDER BY timestamp")
        while batch := list(islice(cursor, BLOCK)):
            chans, stamps, raws = zip(*batch, strict=True)
            lens = np.fromiter(map(len, raws), np.int64, len(raws))
            yield Messages(np.fromiter(chans, np.int64, len(chans)), np.fromiter(stamps, np.int64, len(stamps)),
                           padded(b"".join(raws)), np.concatenate(([0], np.cumsum(lens[:-1]))), lens), mine

    def _stored(self, conn: Any) -> str:
        """A storage's connection's definition, or the bag's (a directory keeps them with its connections)."""
        if conn.msgdef.data:
            return str(conn.msgdef.data)
        return next((str(c.msgdef.data) for c in self.reader.connections if c.topic == conn.topic), "")

    def finish(self) -> None:
        """After the last block: the topics asked for that a cut MCAP never showed, or no CAN topic at all."""
        if self.scans and not self.scans[0].whole:
            self._check_found(self.channels)

    def close(self) -> None:
        """Close what is open."""
        for scan in self.scans:
            scan.close()
        if self.reader is not None:
            self.reader.close()
            self.reader = None


_FD_OK = np.zeros(256, dtype=bool)
_FD_OK[sorted(CANFD_LENGTHS)] = True


@dataclass
class Rows:
    """A block's messages as numpy columns (:func:`unpack`); ``good``: the rows that hold a frame (else ``why``)."""

    t: np.ndarray
    by_record: np.ndarray
    """The rows timed by the record time (else by their header stamp)."""
    ids: np.ndarray
    extended: np.ndarray
    remote: np.ndarray
    error: np.ndarray
    fd: np.ndarray
    lengths: np.ndarray
    """Payload bytes (for a remote frame: its DLC, and no payload)."""
    data: np.ndarray
    """``rows x width`` bytes, the first ``lengths`` of each row its payload."""
    good: np.ndarray
    why: list[str]


def _field(buf: np.ndarray, body: np.ndarray, lay: Layout, name: str) -> np.ndarray:
    """Field ``name`` (a bool or an unsigned integer of 1, 2 or 4 bytes; an array of bytes) of every message."""
    f = lay.fields[name]
    at = body + f.offset
    return uint_at(buf, at, f.size) if f.count == 1 else buf[at[:, None] + np.arange(f.count)]


def _mark(rows: Rows, mask: np.ndarray, reason: Callable[[int], str]) -> None:
    """The rows of ``mask`` still good become bad, row ``i`` for ``reason(i)``."""
    hits = mask & rows.good
    for i in np.flatnonzero(hits).tolist():
        rows.why[i] = reason(i)
    rows.good &= ~hits


def unpack(lay: Layout, raw: Messages, at: Any, record: bool) -> Rows:
    """The frames of messages ``at`` of ``raw`` (one layout), read at once and checked (``record``: record times)."""
    buf, start, lens = raw.buf, raw.start[at], raw.lengths[at]
    name_len = np.minimum(uint_at(buf, start + 12, 4), lens)  # a cut or garbled length: the size check catches it
    body = start + HEADER_SIZE + name_len
    if lay.cdr:
        body = (body - start + 3) // 4 * 4 + start  # aligned as CDR aligns, from the message's first byte
    body = np.minimum(body, start + lens)  # stays inside the padded buffer
    end = body + lay.fixed
    seq_len = np.zeros(start.size, dtype=np.int64)
    if lay.sequence >= 0:
        seq_len = np.where(body + lay.sequence + 4 <= start + lens, uint_at(buf, body + lay.sequence, 4), 0)
        end = body + lay.sequence + 4 + seq_len
    sec = uint_at(buf, start + STAMP_AT, 4)
    if lay.cdr:
        sec = np.where(sec >= 1 << 31, sec - (1 << 32), sec)  # int32
    t, by_record = times(raw.log_ns[at], sec, uint_at(buf, start + STAMP_AT + 4, 4), record)
    rows = Rows(t, by_record, *_frame_fields(lay, buf, body, seq_len), np.ones(start.size, dtype=bool),
                [""] * start.size)
    _mark(rows, end > start + lens, lambda i: f"{int(lens[i])} bytes, shorter than its fields")
    if lay.cdr:
        _mark(rows, buf[start + 1] == 0, lambda i: "big-endian CDR, which canguard does not read")
    check(rows)
    return rows


_Cols = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _frame_fields(lay: Layout, buf: np.ndarray, body: np.ndarray, seq_len: np.ndarray) -> _Cols:
    """(ids, extended, remote, error, fd, lengths, data) of a block, as each type holds them."""
    false = np.zeros(body.size, dtype=bool)
    ids = _field(buf, body, lay, "id")
    if lay.msgtype == "autoware_can_msgs/msg/CANPacket":
        flag = _field(buf, body, lay, "flag")
        extended = ((flag & KVASER_EXT) != 0) | (ids > CAN_SFF_MASK)
        remote, error = (flag & KVASER_RTR) != 0, (flag & KVASER_ERROR_FRAME) != 0
        return ids, extended, remote, error, false, _field(buf, body, lay, "len"), _field(buf, body, lay, "dat")
    extended = _field(buf, body, lay, "is_extended") != 0
    error = _field(buf, body, lay, "is_error") != 0
    remote = _field(buf, body, lay, "is_rtr") != 0 if "is_rtr" in lay.fields else false
    fd = _field(buf, body, lay, "is_fd_frame") != 0 if "is_fd_frame" in lay.fields else false
    if lay.msgtype == "ros2_socketcan_msgs/msg/FdFrame":
        fd = ~false
    lengths = _field(buf, body, lay, "len" if "len" in lay.fields else "dlc")
    if lay.sequence < 0:
        return ids, extended, remote, error, fd, lengths, _field(buf, body, lay, "data")
    data = buf[(body + lay.sequence + 4)[:, None] + np.arange(64)]
    lengths = np.where(lengths > seq_len, -1, lengths)  # more than the data holds: refused by check
    return ids, extended, remote, error, fd, lengths, data


def check(rows: Rows) -> None:
    """Mark the rows that are no CAN frame as candump knows one."""
    lengths, ids = rows.lengths, rows.ids
    _mark(rows, ~rows.fd & ((lengths < 0) | (lengths > 8)),
          lambda i: f"a classic frame's length {lengths[i]} is not 0-8")
    _mark(rows, rows.fd & ((lengths < 0) | ~_FD_OK[np.clip(lengths, 0, 255)] | rows.remote),
          lambda i: f"a CAN FD frame's length {lengths[i]} is not a CAN FD length")
    _mark(rows, ~rows.extended & ~rows.error & (ids > CAN_SFF_MASK), lambda i: f"11-bit id {ids[i]:X} is above 7FF")
    _mark(rows, rows.extended & ~rows.error & (ids > CAN_EFF_MASK),
          lambda i: f"29-bit id {ids[i]:X} is above 1FFFFFFF")


def times(record_ns: np.ndarray, sec: np.ndarray, nanosec: np.ndarray, record: bool) -> tuple[np.ndarray, np.ndarray]:
    """Each row's time in seconds (header stamp, else record time), and which rows took the record time."""
    use = np.ones(sec.size, dtype=bool) if record else (sec == 0) & (nanosec == 0)
    sec = np.where(use, record_ns // 1_000_000_000, sec)
    nsec = np.where(use, record_ns % 1_000_000_000, nanosec)
    t = (sec * 1_000_000 + nsec // 1000) / 1e6
    sub = nsec % 1000
    return (t + sub * 1e-9 if sub.any() else t), use


def block_of(rows: Rows, lanes: np.ndarray, channels: list[str]) -> Block:
    """The good rows as a :class:`~canguard.io.block.Block`: where a bag's columns become what every reader gives."""
    keep = np.flatnonzero(rows.good)
    sel: Any = keep if keep.size < rows.good.size else slice(None)
    ids, ext, rem, err, fd = rows.ids[sel], rows.extended[sel], rows.remote[sel], rows.error[sel], rows.fd[sel]
    lengths = rows.lengths[sel]
    flags = np.where(fd, FLAG_FD, 0) | np.where(rem, FLAG_REMOTE, 0) | np.where(err, FLAG_ERROR, 0)
    payload_len = np.where(rem, 0, lengths)
    width = int(payload_len.max()) if payload_len.size else 0
    payload = rows.data[sel][:, :width] * (np.arange(width) < payload_len[:, None])  # data[:dlc], zeros after
    return Block(rows.t[sel], np.where(err, ids & CAN_EFF_MASK, ids).astype(np.uint32), ext | err,
                 flags.astype(np.uint8), lengths.astype(np.uint8), payload_len.astype(np.uint8),
                 payload.astype(np.uint8), lanes[sel].astype(np.uint16), tuple(channels))


def _block_rows(raw: Messages, topics: dict[int, Topic], record: bool) -> tuple[Rows, np.ndarray]:
    """A block's rows (unpacked one layout at a time when the block mixes them), and each row's channel."""
    ids, row_id = np.unique(raw.channel, return_inverse=True)
    mine = [topics[i] for i in ids.tolist()]
    lanes = np.array([t.lane for t in mine], dtype=np.intp)[row_id]
    layouts: dict[int, tuple[Layout, list[int]]] = {}  # by the layout's id: topics of one type share theirs
    for k, t in enumerate(mine):
        layouts.setdefault(id(t.layout), (t.layout, []))[1].append(k)
    if len(layouts) == 1:
        return unpack(mine[0].layout, raw, slice(None), record), lanes
    places = [np.flatnonzero(np.isin(row_id, ks)) for _lay, ks in layouts.values()]
    parts = [unpack(lay, raw, at, record) for (lay, _ks), at in zip(layouts.values(), places, strict=True)]
    order = np.argsort(np.concatenate(places), kind="stable")
    width = max(p.data.shape[1] for p in parts)
    cols = {f.name: np.concatenate([getattr(p, f.name) for p in parts])[order]
            for f in fields(Rows) if f.name not in ("data", "why")}
    data = np.concatenate([np.pad(p.data, ((0, 0), (0, width - p.data.shape[1]))) for p in parts])[order]
    why = [w for p in parts for w in p.why]
    return Rows(**cols, data=data, why=[why[i] for i in order.tolist()]), lanes


def _note_bad(st: ReadStats, bag: BagSource, rows: Rows, lanes: np.ndarray, first: int, skip_bad: bool) -> None:
    """Count the bad messages of a block, or raise naming the first (``first``: its first message's number - 1)."""
    if skip_bad:
        st.bad_lines += int(np.count_nonzero(~rows.good))
        return
    i = int(np.flatnonzero(~rows.good)[0])
    raise LogFormatError(f"{bag.path}: message {first + i + 1} (topic {bag.channels[int(lanes[i])]}): {rows.why[i]}; "
                         f"{st.frames + int(rows.good[:i].sum())} frames were read before it")


def _next(bag: BagSource, blocks: Iterator[tuple[Messages, dict[int, Topic]]],
          st: ReadStats) -> tuple[Messages, dict[int, Topic]] | None:
    """The next block, or None at the end; a cut or damaged storage as a LogFormatError saying how far it got."""
    try:
        return next(blocks, None)
    except LogFormatError:
        raise
    except McapCut as exc:
        raise LogFormatError(f"{bag.path}: truncated {bag.kind}: {exc}; {st.frames} frames were read before "
                             "the cut") from None
    except Exception as exc:  # a cut or damaged storage deep inside the readers
        raise bag.failed(f"cut or damaged; {st.frames} frames were read before it", exc) from None


def bag_blocks(p: Path, opts: BagOptions, st: ReadStats, skip_bad: bool) -> Blocks:
    """The frames of bag ``p`` a block at a time; every problem a LogFormatError naming the bag."""
    bag = BagSource(p, opts)
    read = 0
    try:
        bag.open()
        blocks = bag.blocks()
        while (raw := _next(bag, blocks, st)) is not None:
            rows, lanes = _block_rows(*raw, opts.stamp == "record")
            if not rows.good.all():
                _note_bad(st, bag, rows, lanes, read, skip_bad)
            read += lanes.size
            block = block_of(rows, lanes, bag.channels)
            by_record = int(np.count_nonzero(rows.by_record & rows.good))
            st.stamps["record"] = st.stamps.get("record", 0) + by_record
            st.stamps["header"] = st.stamps.get("header", 0) + block.n - by_record
            yield block, min(st.bytes_total, st.bytes_total * read // bag.total) if bag.total else None
        bag.finish()
    finally:
        bag.close()
    return f" on {', '.join(bag.channels) or 'its CAN topics'}"
