"""Is a BLF log whole? Its file header and object headers say how much should follow.

python-can's BLF reader stops quietly where the file stops (a log cut in half replays as half a log):
:class:`BlfLength` follows the headers as python-can reads, and says where it was cut.
"""

from __future__ import annotations

import io
import struct
from typing import Any

_FILE_HEADER = struct.Struct("<4sL")
"""The start of the file header: signature ``LOGG``, the header's size."""
_OBJ_HEADER = struct.Struct("<4sHHLL")
"""An object's base header: signature ``LOBJ``, header size, header version, object size, object type."""
_LOG_CONTAINER = 10


class BlfLength:
    """A binary file object that follows the BLF framing of what is read through it (``read`` and ``close``)."""

    def __init__(self, raw: Any) -> None:
        self.raw = raw
        self.pos = 0  # bytes read so far
        self.ended = False  # a read came back short: the file ended there
        self.file_size = 0  # the file size the file header records (python-can's reader tells it; 0: none)
        self._header_size = 0  # the file header's size, once its first 8 bytes are in
        self._next = 0  # where the next header starts (the file header's at 0)
        self._head = b""  # its bytes read so far
        self._object = (0, 0, -1)  # the last object whose header was read: start, size, type (-1: the file header)
        self._lost = False  # a header without its signature: not BLF framing (python-can says what it is)

    def read(self, size: int = -1) -> bytes:
        """Read from the file; what comes back advances the framing."""
        data: bytes = self.raw.read(size)
        if size is None or size < 0 or len(data) < size:
            self.ended = True
        start = self.pos
        self.pos += len(data)
        while not self._lost and self._next + len(self._head) < self.pos:
            need = (_OBJ_HEADER if self._header_size else _FILE_HEADER).size
            at = self._next + len(self._head) - start
            self._head += data[at:at + need - len(self._head)]
            if len(self._head) < need:
                break
            if not self._header_size:  # the file header's first bytes: its size; the rest is skipped
                signature, length = _FILE_HEADER.unpack(self._head)
                self._lost = signature != b"LOGG"
                self._header_size = self._next = max(length, _FILE_HEADER.size)
            else:
                signature, _, _, length, kind = _OBJ_HEADER.unpack(self._head)
                self._lost = signature != b"LOBJ"
                self._object = (self._next, length, kind)
                self._next += max(length, _OBJ_HEADER.size) + length % 4  # then ``size % 4`` padding
            self._head = b""
        return data

    def close(self) -> None:
        """Close the file."""
        self.raw.close()

    def write(self, data: bytes) -> int:
        """Refused (python-can before 4.6 takes an object for a file only when it has ``read`` and ``write``)."""
        raise io.UnsupportedOperation("write")

    def cut(self) -> str:
        """Why the file read so far is not whole ("" when it is, not ended yet, or not BLF framing at all)."""
        if not self.ended or self._lost:
            return ""
        if not self._header_size or self.pos < self._header_size:
            return f"the file ends at byte {self.pos}, inside its file header"
        if self._head:
            return f"the file ends at byte {self.pos}, inside the header of the object at byte {self._next}"
        start, size, kind = self._object
        if kind >= 0 and self.pos < start + max(size, _OBJ_HEADER.size):
            what = "log container" if kind == _LOG_CONTAINER else f"object (type {kind})"
            return (f"the file ends at byte {self.pos}, {self.pos - start} bytes into the {size}-byte {what} "
                    f"at byte {start}")
        if self.file_size > self._header_size and self.pos < self.file_size:
            return f"the file ends at byte {self.pos}; its header says {self.file_size}"
        return ""
