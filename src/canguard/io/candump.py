"""candump text logs (``-L``, ``-l``, plain ``-ta``): read a block of lines at a time, written a line at a time.

Blocks are parsed by :func:`canguard.io.candump_np.parse_block`; a bad line is named by file:line and :func:`why_bad`.
"""

from __future__ import annotations

import io
from collections.abc import Iterable
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from canguard.errors import LogFormatError, quote
from canguard.io.candump_np import parse_block
from canguard.io.frame import Frame
from canguard.io.logtypes import (
    CAN_EFF_MASK,
    CAN_ERR_FLAG,
    CAN_SFF_MASK,
    CANFD_BRS,
    CANFD_ESI,
    CANFD_LENGTHS,
    Blocks,
    ReadStats,
    open_decompressed,
)


class _Bad(Exception):
    """Raised by the line parsers; carries the reason only (the caller adds file:line)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class CrLines:
    """A binary log whose lines end in CR, LF or CRLF, read with each ending as LF (latin-1, universal newlines)."""

    def __init__(self, f: Any) -> None:
        self._text = io.TextIOWrapper(f, encoding="latin-1", newline=None)

    def read(self, size: int = -1) -> bytes:
        return self._text.read(size).encode("latin-1")

    def readline(self, size: int = -1) -> bytes:
        return self._text.readline(size).encode("latin-1")

    def close(self) -> None:
        self._text.close()


def decompress_errors() -> tuple[type[BaseException], ...]:
    """What reading through a decompressor may raise on data that is not what its suffix says."""
    import lzma
    import zlib

    errors: tuple[type[BaseException], ...] = (OSError, EOFError, ValueError, zlib.error, lzma.LZMAError)
    try:
        import zstandard
    except ImportError:
        return errors
    return (*errors, zstandard.ZstdError)


CHUNK_CHARS = 1 << 20
"""Bytes per chunk (~22,000 -L lines); twice as many make the parser slower (its passes outgrow the caches)."""

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
    """The candump reader's blocks of whole lines; a bad line raises naming its file:line (or, ``skip_bad``, counts)."""
    raw = open(p, "rb")  # noqa: SIM115 -- closed below
    files = [open_decompressed(raw, gz)]  # the last one is read (lines that end in a lone CR: read again)
    lineno = 0  # lines before the current block
    error_last = False  # the last frame read is an error frame (``candump -e`` explains it on indented lines below)
    try:
        while text := _text(p, raw, gz, files, lineno):
            parsed = parse_block(text, error_last)
            bad, block = parsed.bad, parsed.block
            if bad and not skip_bad:
                line = bad[0]
                before = 0 if block is None else int(np.searchsorted(parsed.rows_line, line))
                if block is not None and before:
                    yield block.select(slice(0, before)), None
                text_of = _as_text(text).split("\n")[line]
                raise LogFormatError(f"{p}:{lineno + line + 1}: {why_bad(text_of)}: {quote(text_of)}")
            st.bad_lines += len(bad)
            lineno += parsed.lines
            error_last = parsed.error_last
            yield block, raw.tell()
    finally:
        files[-1].close()
        raw.close()
    return ""


def _text(p: Path, raw: Any, gz: str, files: list[Any], lineno: int) -> bytes:
    """The next block of whole lines (``files[-1]`` reading it; ``lineno``: lines before); b"" at the end."""
    longest = 4 * CHUNK_CHARS
    try:
        text: bytes = files[-1].read(CHUNK_CHARS)
        if text and text[-1] != 10:
            text += files[-1].readline(longest)
    except decompress_errors() as exc:
        kind = {"gz": " gzip", "xz": " xz", "zst": " zstd"}.get(gz, "")
        raise LogFormatError(f"{p}: cannot read{kind} log: {exc}") from None
    if not lineno:  # the first block
        if len(files) == 1 and b"\n" not in text and b"\r" in text and raw.seekable():
            if files[0] is not raw:
                files[0].close()  # a decompressor: raw stays open
            raw.seek(0)  # lines that end in a lone CR (old Mac tools): read again, each CR as a LF
            files.append(CrLines(open_decompressed(raw, gz)))
            return _text(p, raw, gz, files, lineno)
        text = text[3:] if text[:3] == b"\xef\xbb\xbf" else text  # a UTF-8 BOM
    if text and text[-1] != 10:
        tail = len(text) - text.rfind(b"\n") - 1
        if tail >= longest:
            at = lineno + _as_text(text).count("\n") + 1
            raise LogFormatError(f"{p}:{at}: no line break in {tail} characters: not a candump log")
        text += b"\n"  # the last line of the log, without its line break
    return text


def format_candump_line(frame: Frame) -> str:
    """One candump -L line for ``frame``, no newline; ValueError for an id out of range or a channel with spaces."""
    channel = frame.channel or "can0"
    if channel.split() != [channel]:
        raise ValueError(f"channel {channel!r} cannot be written to a candump log (empty or has whitespace)")
    cid = frame.arbitration_id
    if frame.is_error_frame:
        id_text = f"{(cid & CAN_EFF_MASK) | CAN_ERR_FLAG:08X}"
    elif frame.is_extended_id:
        if not 0 <= cid <= CAN_EFF_MASK:
            raise ValueError(f"extended id {cid:#x} out of range")
        id_text = f"{cid:08X}"
    else:
        if not 0 <= cid <= CAN_SFF_MASK:
            raise ValueError(f"standard id {cid:#x} out of range (use is_extended_id=True above 0x7FF)")
        id_text = f"{cid:03X}"
    if frame.is_remote_frame:
        body = f"R{frame.dlc}" if 0 < frame.dlc <= 8 else "R"
    elif frame.is_fd:
        flags = (CANFD_BRS if frame.bitrate_switch else 0) | (CANFD_ESI if frame.error_state_indicator else 0)
        body = f"#{flags:X}{frame.data.hex().upper()}"
    else:
        body = frame.data.hex().upper()
        if len(frame.data) == 8 and 8 < frame.dlc <= 15:
            body += f"_{frame.dlc:X}"
    return f"({frame.t:.6f}) {channel} {id_text}#{body}"


def write_candump(frames: Iterable[Frame], out: TextIO) -> int:
    """Write ``frames`` to ``out`` as a candump -L log (one line each); return how many were written."""
    count = 0
    for frame in frames:
        out.write(format_candump_line(frame) + "\n")
        count += 1
    return count
