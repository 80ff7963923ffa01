"""``replay --emit FILE.mcap`` / ``--emit DIR``: the frames canguard would send, as a bag ``ros2 bag play`` sends."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from canguard.errors import ConfigError
from canguard.io.frame import Frame
from canguard.io.mcapwrite import McapWriter, ns_of
from canguard.io.rosmsgs import DEFINITIONS, cdr_frame, frame_type, full_definition

TOPICS = {False: "/to_can_bus", True: "/to_can_bus_fd"}


class BagEmit:
    """The frames sent during a replay, written as they come."""

    def __init__(self, path: Path) -> None:
        self._mcap: McapWriter | None = None
        self._out: Any
        self._channels: dict[bool, Any] = {}
        if path.suffix.lower() == ".mcap":
            self._out = self._mcap = McapWriter(path, profile="ros2")
            self._write = self._mcap.message
            return
        try:
            from rosbags.rosbag2 import StoragePlugin, Writer
        except ImportError:
            raise ConfigError(f"--emit {path}: writing a rosbag2 directory needs rosbags: "
                              "pip install 'canguard[rosbags]' (or --emit FILE.mcap)") from None
        self._out = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._out.open()
        self._write = self._out.write

    def _channel(self, fd: bool) -> Any:
        if fd not in self._channels:
            msgtype = frame_type(fd)
            if self._mcap is not None:
                schema = self._mcap.schema(msgtype, "ros2msg", full_definition(msgtype))
                self._channels[fd] = self._mcap.channel(TOPICS[fd], schema, "cdr")
            else:
                self._channels[fd] = self._out.add_connection(TOPICS[fd], msgtype, typestore=_typestore())
        return self._channels[fd]

    def sent(self, frames: Sequence[Frame]) -> None:
        """Write frames canguard sent."""
        for f in frames:
            ns = int(ns_of(f.t))
            raw = cdr_frame(ns, f.channel, f.arbitration_id, bytes(f.data), extended=f.is_extended_id, fd=f.is_fd)
            self._write(self._channel(f.is_fd), ns, raw)

    def close(self) -> None:
        """End the file (or the directory's storage and ``metadata.yaml``)."""
        self._out.close()


def _typestore() -> Any:
    """rosbags' ROS 2 types with the CAN frame types (the rosbag2 writer records their definitions and hashes)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)  # it holds the header's types
    for name, definitions in DEFINITIONS.items():
        store.register(get_types_from_msg(definitions[0], name))
    return store
