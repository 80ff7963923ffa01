"""The daemon and its monitor process talk over one ``AF_UNIX`` ``SOCK_SEQPACKET`` socket pair.

A seqpacket socket keeps message boundaries and takes a message whole or not at all, so the
daemon can send without ever waiting: a send the socket cannot take now fails with
``BlockingIOError`` and the daemon keeps the latest snapshot for its next try (the process is
slow: it skips snapshots, never holds up the loop).

Daemon → monitor process: pickled messages, cut into frames of at most :data:`FRAME_BYTES`
(a flag byte, ``M`` more follows or ``E`` end, then the bytes): the monitor process unpickles
only what its own daemon sent. Monitor process → daemon: a few fixed byte strings and one JSON
answer at start (:data:`WANT_BLACKBOARD`, :func:`ready`): the daemon never unpickles what comes
from the side the network can reach.
"""

from __future__ import annotations

import json
import pickle
import socket
from typing import Any

FRAME_BYTES = 32 * 1024
"""Largest frame (a seqpacket message must fit the socket's send buffer, 208 kB by default on Linux)."""
SEND_BUFFER_BYTES = 1 << 20
"""Send buffer asked for (Linux caps it at ``net.core.wmem_max``)."""
MORE, END = b"M", b"E"
WANT_BLACKBOARD = b"B"
"""Monitor process → daemon: a Groot2 client asked for the blackboard (put it in the snapshots for 1 s)."""


def fields(record: Any) -> tuple[Any, ...]:
    """A frozen dataclass's field values in their order (``type(record)(*fields(record))`` rebuilds it).

    Pickling plain tuples takes a third of the time pickling the dataclasses does.
    """
    return tuple(vars(record).values())


def socket_pair() -> tuple[socket.socket, socket.socket]:
    """(the daemon's end, the monitor process's end); neither is inherited by other children."""
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    for sock in (ours, theirs):
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
    return ours, theirs


def frames(message: Any) -> list[bytes]:
    """``message`` pickled and cut into frames (one for all but the largest messages)."""
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    size = FRAME_BYTES - 1
    parts = [data[i:i + size] for i in range(0, len(data), size)] or [b""]
    return [MORE + p for p in parts[:-1]] + [END + parts[-1]]


class Assembler:
    """Frames back into messages (the monitor process's side)."""

    def __init__(self) -> None:
        self._parts: list[bytes] = []

    def feed(self, frame: bytes) -> tuple[bool, Any]:
        """(True, message) when ``frame`` completes one; (False, None) while more is to come."""
        if not frame:
            raise ValueError("empty frame: the daemon's end of the socket closed")
        self._parts.append(frame[1:])
        if frame[:1] == MORE:
            return False, None
        data = b"".join(self._parts)
        self._parts = []
        return True, pickle.loads(data)  # only ever from our own daemon, over a private socket pair


def answer(sock: socket.socket, doc: dict[str, Any]) -> None:
    """Monitor process → daemon: its one JSON answer at start (``ready`` with addresses, or ``error``)."""
    sock.send(json.dumps(doc).encode())


def read_answer(data: bytes) -> dict[str, Any]:
    """The monitor process's start answer; ValueError when it is not one."""
    doc = json.loads(data.decode())
    if not isinstance(doc, dict) or not ({"ready", "error"} & set(doc)):
        raise ValueError(f"not a start answer: {data[:80]!r}")
    return doc
