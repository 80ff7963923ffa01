"""Write CAN frames as ROS bags with the ``rosbags`` library's own writers and serialisers (not canguard's).

The messages are made by rosbags' typestore from the CAN types' ``.msg`` definitions, so
a bag written here is what a ROS tool writes, and canguard's block reader is held to
rosbags' serialisation.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from canguard.io import rosmsgs
from canguard.io.frame import Frame

rosbags = pytest.importorskip("rosbags")

from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

STORAGES = ("sqlite3", "mcap", "ros1")
"""The bag kinds a test writes: rosbag2 with either storage, and ROS 1."""

FRAME = "can_msgs/msg/Frame"
FD_FRAME = "ros2_socketcan_msgs/msg/FdFrame"


def typestore(ros1: bool = False, definitions: dict[str, str] | None = None) -> Any:
    """A rosbags typestore that knows the CAN types (the carried definitions, or ``definitions``)."""
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    for name, defs in (definitions or {n: d[0] for n, d in rosmsgs.DEFINITIONS.items()}).items():
        store.register(get_types_from_msg(defs, name))
    return store


def message(store: Any, msgtype: str, frame: Frame, stamp_ns: int, frame_id: str = "can0",
            leftover: int = 0xAA) -> Any:
    """``frame`` as a message of ``msgtype``, stamped ``stamp_ns``; the data's unused bytes are ``leftover``."""
    types = store.types
    stamp = types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    fields = [n for n, _t in store.fielddefs["std_msgs/msg/Header"][1]]
    header = types["std_msgs/msg/Header"](**({"seq": 7} if "seq" in fields else {}), stamp=stamp, frame_id=frame_id)
    data = bytes(frame.data)
    length = frame.dlc if frame.is_remote_frame and frame.dlc > 0 else len(data)
    if msgtype == FD_FRAME:
        return types[msgtype](header=header, id=frame.arbitration_id, is_extended=frame.is_extended_id,
                              is_error=frame.is_error_frame, len=len(data),
                              data=np.frombuffer(data.ljust(64, bytes([leftover])), np.uint8))
    return types[msgtype](header=header, id=frame.arbitration_id, is_rtr=frame.is_remote_frame,
                          is_extended=frame.is_extended_id, is_error=frame.is_error_frame, dlc=length,
                          data=np.frombuffer(data.ljust(8, bytes([leftover])), np.uint8))


def stamp_ns(t: float) -> int:
    """Seconds with at most 6 decimals (candump's) as whole nanoseconds."""
    return round(t * 1e6) * 1000


def write_bag(path: Path, storage: str, topics: dict[str, Iterable[Frame]], *, msgtype: str = FRAME,
              definitions: bool = True, record_ns: Any = None, zero_stamps: bool = False) -> Path:
    """Write ``topics`` (name -> frames, each topic in time order) as a bag of ``storage``; its path.

    Each message's ``frame_id`` is its topic's name (topics of names of several lengths: messages of several
    sizes). Messages are recorded at their frame's time (``record_ns(i, frame)`` when given) and written in record
    order; ``definitions=False`` stores no message definition (as rosbag2 before Iron);
    ``zero_stamps`` leaves every header stamp zero.
    """
    ros1 = storage == "ros1"
    store = typestore(ros1)
    rows = []
    for topic, frames in topics.items():
        for i, frame in enumerate(frames):
            rec = record_ns(i, frame) if record_ns is not None else stamp_ns(frame.t)
            rows.append((rec, topic, frame))
    rows.sort(key=lambda r: r[0])
    if ros1:
        target = path.with_suffix(".bag")
        with Writer1(target) as w:
            msgdef, md5sum = store.generate_msgdef(msgtype) if definitions else ("", "0" * 32)
            conns = {t: w.add_connection(t, msgtype, msgdef=msgdef, md5sum=md5sum) for t in topics}
            for rec, topic, frame in rows:
                raw = store.serialize_ros1(message(store, msgtype, frame, 0 if zero_stamps else stamp_ns(frame.t),
                                                   topic.strip("/")), msgtype)
                w.write(conns[topic], rec, raw)
        return target
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer2(path, version=9 if definitions else 8, storage_plugin=plugin) as w:
        conns = {t: w.add_connection(t, msgtype, typestore=store) if definitions else
                 w.add_connection(t, msgtype, msgdef="", rihs01="RIHS01_" + "0" * 64) for t in topics}
        for rec, topic, frame in rows:
            raw = store.serialize_cdr(message(store, msgtype, frame, 0 if zero_stamps else stamp_ns(frame.t),
                                              topic.strip("/")), msgtype)
            w.write(conns[topic], rec, raw)
    return path


def storage_file(bag: Path) -> Path:
    """The one storage file (``.db3`` / ``.mcap``) of a rosbag2 directory, or the ROS 1 bag itself."""
    if bag.is_file():
        return bag
    (found,) = [p for p in bag.iterdir() if p.suffix in (".db3", ".mcap")]
    return found
