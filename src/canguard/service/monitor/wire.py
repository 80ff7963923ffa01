"""The daemon and its monitor process talk over one ``AF_UNIX`` ``SOCK_SEQPACKET`` socket pair.

A seqpacket socket takes a message whole or not at all: the daemon sends without waiting. Daemon → monitor: pickled
messages in frames of at most :data:`FRAME_BYTES` (a flag byte, ``M`` more or ``E`` end). Monitor → daemon: fixed
byte strings and one JSON answer: the daemon never unpickles what comes from the side the network can reach.
"""

from __future__ import annotations

import ctypes
import errno
import os
import pickle
import socket
from collections.abc import Iterator
from typing import Any

FRAME_BYTES = 32 * 1024
"""Largest frame (a seqpacket message must fit the socket's send buffer, 208 kB by default on Linux)."""
SEND_BUFFER_BYTES = 1 << 20
"""Send buffer asked for (Linux caps it at ``net.core.wmem_max``)."""
MORE, END = b"M", b"E"
WANT_BLACKBOARD = b"B"
"""Monitor process → daemon: a Groot2 client asked for the blackboard (put it in the snapshots for 1 s)."""


class GilHoldingSocket:
    """Non-blocking send and receive on a socket's descriptor that keep the calling thread's GIL: ``socket.send``
    releases it around its system call, and the loop then waits to get it back; a non-blocking local socket
    returns within microseconds."""

    _libc = ctypes.PyDLL(None, use_errno=True)
    _send = _libc.send
    _send.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_size_t, ctypes.c_int)
    _send.restype = ctypes.c_ssize_t
    _recv = _libc.recv
    _recv.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_size_t, ctypes.c_int)
    _recv.restype = ctypes.c_ssize_t

    def __init__(self, sock: socket.socket) -> None:
        self._fd = sock.fileno()
        self._buf = ctypes.create_string_buffer(64)

    def send(self, data: bytes) -> bool:
        """Send one message whole; False when the socket cannot take it now. OSError when the other end is gone."""
        return self._send(self._fd, data, len(data), socket.MSG_DONTWAIT | socket.MSG_NOSIGNAL) >= 0 or _again()

    def recv(self) -> bytes | None:
        """One short message (at most 64 bytes), b"" when the other end closed, None when none waits."""
        n = self._recv(self._fd, self._buf, len(self._buf), socket.MSG_DONTWAIT)
        if n >= 0:
            return self._buf.raw[:n]
        _again()
        return None


def _again() -> bool:
    """False for ``EAGAIN`` (nothing done, try later); OSError for any other error of the call just made."""
    code = ctypes.get_errno()
    if code in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR):
        return False
    raise OSError(code, os.strerror(code))


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


def messages(sock: socket.socket) -> Iterator[Any]:
    """The daemon's messages, each put back together from its frames, until the daemon's end closes."""
    parts: list[bytes] = []
    while frame := sock.recv(FRAME_BYTES + 64):
        parts.append(frame[1:])
        if frame[:1] == END:
            yield pickle.loads(b"".join(parts))  # only ever from our own daemon, over a private socket pair
            parts = []
