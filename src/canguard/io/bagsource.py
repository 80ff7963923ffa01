"""A bag's raw CAN messages a block at a time: which topics are read, and where each message's bytes lie.

Blocks of :class:`~canguard.io.mcapscan.Messages` with the :class:`Topic` of each of their channels. MCAP and ROS 1
files are read by canguard's own chunk readers (:mod:`canguard.io.mcapscan`, :mod:`canguard.io.ros1scan`: no
object per message, a cut file read up to the cut); a ``.db3`` through its ``messages`` table, in record time
order; a rosbag2 directory's metadata comes from rosbags.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from itertools import islice
from pathlib import Path
from typing import Any

import numpy as np

from canguard.errors import LogFormatError, clip
from canguard.io.bagopts import BagOptions
from canguard.io.mcapscan import McapCut, McapScan, Messages, padded
from canguard.io.ros1scan import Ros1Scan
from canguard.io.rosmsgs import DEFINITIONS, Layout, layout_for, looks_like_can

BLOCK = 4096
"""Raw messages taken at a time from a sqlite3 storage (an MCAP or ROS 1 block is one chunk)."""


@dataclass(frozen=True)
class Topic:
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
        why = exc.what if isinstance(exc, McapCut) else f"{type(exc).__name__}: {clip(str(exc))}"
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
            raise LogFormatError(f"{self.path}: not a {self.kind}: {exc.what}") from None
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
        """Choose the topics to read among ``(topic, type, stored definition)``; LogFormatError saying what the
        bag holds when nothing is left to read or a topic asked for is missing."""
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
