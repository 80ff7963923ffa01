"""candump text logs (``-L``, ``-l``, plain ``-ta``): read a block of lines at a time, parsed by numpy.

The parser (:func:`canguard.io.candump_np.parse_block`) gives each block's frames and its bad
lines; the reader names a bad line's file:line and says what is wrong with it
(:func:`why_bad`: the checks of each field, in the order a reader of the line would make them)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from canguard.errors import LogFormatError, quote
from canguard.io.block import Block
from canguard.io.candump_np import parse_block
from canguard.io.logtypes import (
    CAN_EFF_MASK,
    CAN_ERR_FLAG,
    CAN_SFF_MASK,
    CANFD_LENGTHS,
    MAX_BAD_EXAMPLES,
    BadLine,
    Blocks,
    CrLines,
    ReadStats,
    _Bad,
    decompress_errors,
    open_decompressed,
)

# --------------------------------------------------------------------------- candump text


CHUNK_CHARS = 1 << 20
"""Bytes per chunk (~22,000 -L lines): the engine's work per message and block spread over more rows; twice as
many make the parser slower (its passes outgrow the caches)."""

_MARKERS = frozenset("TRtr")
_HEX = "0123456789abcdefABCDEF"


def _is_hex(s: str) -> bool:
    """True for a non-empty string of hex digits only."""
    return bool(s) and not s.strip(_HEX)


def _check_data(text: str) -> int:
    """The number of bytes of a hex data field."""
    if len(text) % 2:
        raise _Bad(f"odd number of hex digits in data {text!r}")
    if text and not _is_hex(text):
        raise _Bad(f"data {text!r} is not hex")
    return len(text) // 2


def _check_id(text: str) -> bool:
    """A candump id field: 3 (standard) or 8 (extended) hex digits; True for an error frame's."""
    if len(text) not in (3, 8) or not _is_hex(text):
        raise _Bad(f"bad CAN id {text!r}: expected 3 (standard) or 8 (extended) hex digits")
    cid = int(text, 16)
    if len(text) == 3:
        if cid > CAN_SFF_MASK:
            raise _Bad(f"standard CAN id {text!r} is above 7FF")
        return False
    if cid & CAN_ERR_FLAG:
        return True
    if cid > CAN_EFF_MASK:
        raise _Bad(f"extended CAN id {text!r} is above 1FFFFFFF")
    return False


def _check_timestamp(text: str) -> None:
    sec, dot, frac = text.partition(".")
    if sec.isdigit() and sec.isascii() and (not dot or (frac.isdigit() and frac.isascii())):
        return
    if " " in text or ":" in text:
        raise _Bad("absolute date timestamps (candump -tA) are not supported: record with candump -ta or -L")
    raise _Bad(f"bad timestamp {text!r}: expected (seconds.microseconds)")


def _check_compact(text: str) -> None:
    """One ``ID#DATA`` field of candump -L: classic, FD (``##F``), remote (``R``/``R8``), error."""
    id_text, sep, d = text.partition("#")
    if not sep:
        raise _Bad("expected ID#DATA")
    _check_id(id_text)
    if d[:1] == "#":
        if d[1:2] == "#":
            raise _Bad("CAN XL frames are not supported")
        if len(d) < 2 or not _is_hex(d[1]):
            raise _Bad("CAN FD frame needs one hex flags digit after '##'")
        if (size := _check_data(d[2:])) not in CANFD_LENGTHS:
            raise _Bad(f"{size} data bytes is not a CAN FD length")
    elif d[:1] in ("R", "r"):
        dlc_text = d[1:]
        if dlc_text and (len(dlc_text) != 1 or dlc_text not in "012345678"):
            raise _Bad(f"bad remote frame DLC {dlc_text!r}: expected one digit 0-8")
    else:
        data_text, underscore, raw_dlc = d.partition("_")
        size = _check_data(data_text)
        if size > 8:
            raise _Bad(f"{size} data bytes in a classic CAN frame (at most 8; CAN FD frames use '##')")
        # candump's len8_dlc: 8 data bytes with a raw DLC of 9..F
        if underscore and (size != 8 or len(raw_dlc) != 1 or raw_dlc not in "9ABCDEFabcdef"):
            raise _Bad(f"bad raw DLC suffix '_{raw_dlc}': expected _9 .. _F after 8 data bytes")


_SHAPE = "expected '(secs) channel ID#DATA' (candump -L) or '(secs) channel ID [len] DATA' (candump -ta)"


def _check_long(stamped: bool, ts_text: str, toks: list[str]) -> None:
    """One line of plain candump output: ``can0  123   [8]  11 22 ...`` with a -ta timestamp."""
    i = 4 if len(toks) > 4 and toks[1] in ("RX", "TX") else 1  # candump -x: direction and B/E flag columns
    if len(toks) < i + 2:
        raise _Bad(_SHAPE)
    len_tok = toks[i + 1]
    if len(len_tok) < 3 or len_tok[0] != "[" or len_tok[-1] != "]":
        raise _Bad(_SHAPE)
    if not stamped:
        raise _Bad("plain candump output without timestamps is not supported: record with candump -ta or -L")
    if len(ts_text.partition(".")[0]) < 10:
        raise _Bad("relative timestamps (candump -td / -tz) are not supported: record with candump -ta or -L")
    len_text = len_tok[1:-1]
    if not (len_text.isdigit() and len_text.isascii()):
        raise _Bad(f"bad length {len_tok!r}")
    length = int(len_text)
    is_fd = len(len_text) == 2  # candump prints [%d] for classic CAN, [%02d] for CAN FD
    err = _check_id(toks[i])
    rest = toks[i + 2 :]
    if rest[:2] == ["remote", "request"]:
        if len(rest) != 2 or is_fd or length > 8:
            raise _Bad("bad remote request")
        return
    byte_toks = rest[:length]
    if len(byte_toks) < length or any(len(b) != 2 for b in byte_toks):
        raise _Bad(f"[{length}] announces {length} data bytes: expected {length} two-digit hex bytes")
    _check_data("".join(byte_toks))
    tail = rest[length:]
    if tail and not (tail[0][:1] == "'" or (tail[0] == "ERRORFRAME" and err)):
        raise _Bad(f"unexpected text after the data: {' '.join(tail)!r}")
    if is_fd and length not in CANFD_LENGTHS:
        raise _Bad(f"{length} data bytes is not a CAN FD length")
    if not is_fd and length > 8:
        raise _Bad(f"{length} data bytes in a classic CAN frame (at most 8)")


def _check_line(line: str) -> None:
    """Check one candump line of any supported shape (raises :class:`_Bad` with the reason)."""
    s = line.strip()
    ts_text = ""
    stamped = s[:1] == "("
    if stamped:
        close = s.find(")")
        if close < 0:
            raise _Bad("timestamp has no closing ')'")
        ts_text = s[1:close]
        _check_timestamp(ts_text)
        toks = s[close + 1 :].split()
    else:
        toks = s.split()
    if len(toks) >= 2 and "#" in toks[1]:
        if not stamped:
            raise _Bad("missing '(seconds.microseconds)' timestamp")
        if len(toks) > 3 or (len(toks) == 3 and toks[2] not in _MARKERS):
            raise _Bad(f"unexpected text after the frame: {' '.join(toks[2:])!r}")
        _check_compact(toks[1])
        return
    _check_long(stamped, ts_text, toks)


def why_bad(line: str) -> str:
    """What is wrong with a line the parser refused (the first field at fault, as a reader of it checks them)."""
    try:
        _check_line(line)
    except _Bad as bad:
        return bad.reason
    return _SHAPE


def _as_text(block: bytes) -> str:
    r"""A block's bytes as the text parsers read them: UTF-8 (junk replaced), ``\r\n`` / ``\r`` ending a line."""
    text = block.decode("utf-8", "replace")
    return text.replace("\r\n", "\n").replace("\r", "\n") if "\r" in text else text


def candump_blocks(p: Path, gz: str, skip_bad: bool, st: ReadStats) -> Blocks:
    """The candump text reader's blocks (a bad line raises, naming its file:line, after the frames before it;
    with ``skip_bad`` it is counted)."""
    reader = _CandumpReader(p, gz, skip_bad, st)
    try:
        for block in reader.blocks():
            for frames in reader.parse(block):
                yield frames, None
            yield None, reader.raw.tell()
    finally:
        reader.close()
    return ""


class _CandumpReader:
    """One candump text log, read a block of whole lines at a time (see :func:`candump_blocks`)."""

    def __init__(self, p: Path, gz: str, skip_bad: bool, st: ReadStats) -> None:
        self.p, self.gz, self.skip_bad, self.st = p, gz, skip_bad, st
        self.raw = open(p, "rb")  # noqa: SIM115 -- closed by close()
        self.f: Any = open_decompressed(self.raw, gz)
        self.lineno = 0
        """Lines before the current block."""
        self.error_last = False
        """The last frame read is an error frame (``candump -e`` explains it on indented lines below)."""
        self.count = 0
        """Blocks read."""

    def close(self) -> None:
        self.f.close()
        self.raw.close()

    def _read(self, longest: int) -> bytes:
        """A chunk and the rest of its last line."""
        try:
            block: bytes = self.f.read(CHUNK_CHARS)
            if block and block[-1] != 10:
                block += self.f.readline(longest)
        except decompress_errors() as exc:
            kind = {"gz": " gzip", "xz": " xz", "zst": " zstd"}.get(self.gz, "")
            raise LogFormatError(f"{self.p}: cannot read{kind} log: {exc}") from None
        return block

    def blocks(self) -> Iterator[bytes]:
        """The log's blocks of whole lines, each ending in a line break."""
        longest = 4 * CHUNK_CHARS
        while True:
            block = self._read(longest)
            raw = self.raw
            if not self.count and b"\n" not in block and b"\r" in block and raw.seekable():
                if self.f is not raw:
                    self.f.close()  # a decompressor: raw stays open
                raw.seek(0)  # lines that end in a lone CR (old Mac tools): read again, each CR as a LF
                self.f = CrLines(open_decompressed(raw, self.gz))
                continue
            block = block[3:] if not self.count and block[:3] == b"\xef\xbb\xbf" else block  # a UTF-8 BOM
            if not block:
                return
            if block[-1] != 10:
                tail = len(block) - block.rfind(b"\n") - 1
                if tail >= longest:
                    at = self.lineno + _as_text(block).count("\n") + 1
                    raise LogFormatError(f"{self.p}:{at}: no line break in {tail} characters: not a candump log")
                block += b"\n"  # the last line of the log, without its line break
            self.count += 1
            yield block

    def parse(self, raw: bytes) -> Iterator[Block]:
        """The block's frames; a bad line raises after the frames before it, or is counted."""
        parsed = parse_block(raw, self.error_last)
        st = self.st
        bad = parsed.bad
        block = parsed.block
        if bad and not self.skip_bad:
            line = bad[0]
            if block is not None:
                before = int(np.searchsorted(parsed.rows_line, line))
                if before:
                    st.lines += line
                    yield block.select(slice(0, before))
            text = _line(raw, line)
            raise LogFormatError(f"{self.p}:{self.lineno + line + 1}: {why_bad(text)}: {quote(text)}")
        st.lines += parsed.lines
        if bad:
            st.bad_lines += len(bad)
            for line in bad[:max(0, MAX_BAD_EXAMPLES - len(st.bad_examples))]:
                text = _line(raw, line)
                st.bad_examples.append(BadLine(self.lineno + line + 1, why_bad(text), text))
        self.lineno += parsed.lines
        self.error_last = parsed.error_last
        if block is not None:
            yield block


def _line(raw: bytes, k: int) -> str:
    """Line ``k`` of a block, as text (UTF-8, junk replaced)."""
    return _as_text(raw).split("\n")[k]
