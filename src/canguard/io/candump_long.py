"""Blocks of ``candump -ta`` lines (the long format) rewritten as candump -L, then read by numpy.

``(1700000000.000010)  can0  014   [8]  F4 CA 7A 3F 1F 32 6C 3F   '..z?.2l?'`` becomes
``(1700000000.000010) can0 014#F4CA7A3F1F326C3F`` (``[NN]``, two digits: CAN FD, ``ID##0...``):
one regular-expression pass per block in C, then :func:`canguard.io.candump_np.byte_columns`.
The line parser (:func:`canguard.io.candump._parse_long`) stays the reference: a block is
taken only when every line has the plain shape it reads the same way (an absolute timestamp
of 10+ integer digits, a channel, a 3- or 8-digit id, ``[len]``, exactly ``len`` two-digit
bytes, then nothing or an ASCII dump starting with ``'``), and the announced lengths are
checked against the bytes. Anything else (``-x`` columns, remote requests, error frames, tabs,
indented lines) gives None: the block is then read line by line, bad lines named file:line.
"""

from __future__ import annotations

import re

import numpy as np

from canguard.io.block import Block
from canguard.io.candump_np import byte_columns

_HEAD = r"^\((\d{10,}\.\d+)\)[ ]+([^ \n]+)[ ]+([0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})[ ]+"
_DATA = r"((?:[ ]+[0-9A-Fa-f]{2})*)(?:[ ]+'[^\n]*|[ ]*)$"  # the ASCII dump tried first: no step back on a -a line
_CLASSIC = re.compile(_HEAD + r"\[([0-8])\]" + _DATA, re.M)
_CLASSIC_FIELDS = re.compile(_HEAD + r"\[[0-8]\]" + _DATA, re.M)
"""The same lines, their length not captured: (stamp, channel, id, data) per line, joined in C below."""
_FD = re.compile(_HEAD + r"\[(\d\d)\]" + _DATA, re.M)
_LENGTH = re.compile(r"\[(\d\d?)\]")


def long_columns(text: str, n: int) -> Block | None:
    """The block ``text`` of ``n`` candump -ta lines (< 0: count them) as a :class:`~canguard.io.block.Block`, or None (read it line
    by line)."""
    if "[" not in text or "\x01" in text or "\t" in text or "\r" in text:
        return None
    if n < 0:
        n = text.count("\n")
    lengths = _LENGTH.findall(text)
    if len(lengths) != n:
        return None  # a line without [len], or one with two (in its ASCII dump, say)
    found = _CLASSIC_FIELDS.findall(text)
    if len(found) == n:  # all classic: each line rewritten by %-formatting (re's template runs in Python, ~2 us a line)
        rows = "\n".join(map("(%s)\x01%s\x01%s#%s".__mod__, found)) + "\n"
    else:
        rows, classic = _CLASSIC.subn("(\\1)\x01\\2\x01\\3#\\5", text)
        rows, fd = _FD.subn("(\\1)\x01\\2\x01\\3##0\\5", rows)
        if classic + fd != n:
            return None
    cols = byte_columns(rows.replace(" ", "").replace("\x01", " "), n)
    if cols is None:
        return None
    announced = np.array(lengths).astype(np.int64)
    if not (cols.length == announced).all():
        return None  # [len] announces another number of bytes than the line has
    return cols


def numpy_block(block: bytes, n: int) -> Block | None:
    """A block of candump -L or -ta lines (their bytes) read by numpy, or None (the text parsers read it)."""
    if b"[" not in block:
        return byte_columns(block, n)
    return long_columns(block.decode("ascii"), n) if block.isascii() else None
