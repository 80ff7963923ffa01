"""candump text logs (``-L``, ``-l``, plain ``-ta``): the block fast path and the line parser.

A plain ``candump -L`` block is parsed at once with C-level string operations; any
other block line by line by the general parser, which names the file:line of a bad line."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from canguard.errors import LogFormatError, quote
from canguard.io.block import Block
from canguard.io.candump_long import numpy_block
from canguard.io.frame import Frame
from canguard.io.logtypes import (
    _HEX,
    CAN_EFF_MASK,
    CAN_ERR_FLAG,
    CAN_SFF_MASK,
    CANFD_BRS,
    CANFD_ESI,
    CANFD_LENGTHS,
    MAX_BAD_EXAMPLES,
    BadLine,
    CrLines,
    LogFrames,
    ReadStats,
    _Bad,
    _new,
    decompress_errors,
    note_order,
    open_decompressed,
)

# --------------------------------------------------------------------------- candump text


CHUNK_CHARS = 1 << 19
"""Bytes per chunk (~11,000 -L lines). Against 1 << 17: 10-20 % less replay time on four of five
shapes of 2 M frames, the fifth the same; 1 << 20 and more no faster (a block's arrays outgrow L2)."""

_MARKERS = frozenset("TRtr")


def _is_hex(s: str) -> bool:
    """True for a non-empty string of hex digits only."""
    return bool(s) and not s.strip(_HEX)


def _hex_data(text: str) -> bytes:
    if len(text) % 2:
        raise _Bad(f"odd number of hex digits in data {text!r}")
    if text and not _is_hex(text):
        raise _Bad(f"data {text!r} is not hex")
    return bytes.fromhex(text)


def _parse_id(text: str) -> tuple[int, bool, bool]:
    """``(arbitration_id, is_extended_id, is_error_frame)`` of a candump id field."""
    if len(text) not in (3, 8) or not _is_hex(text):
        raise _Bad(f"bad CAN id {text!r}: expected 3 (standard) or 8 (extended) hex digits")
    cid = int(text, 16)
    if len(text) == 3:
        if cid > CAN_SFF_MASK:
            raise _Bad(f"standard CAN id {text!r} is above 7FF")
        return cid, False, False
    if cid & CAN_ERR_FLAG:
        return cid & CAN_EFF_MASK, True, True
    if cid > CAN_EFF_MASK:
        raise _Bad(f"extended CAN id {text!r} is above 1FFFFFFF")
    return cid, True, False


def _parse_timestamp(text: str) -> float:
    sec, dot, frac = text.partition(".")
    if sec.isdigit() and sec.isascii() and (not dot or (frac.isdigit() and frac.isascii())):
        return float(text)
    if " " in text or ":" in text:
        raise _Bad("absolute date timestamps (candump -tA) are not supported: record with candump -ta or -L")
    raise _Bad(f"bad timestamp {text!r}: expected (seconds.microseconds)")


def _parse_compact(t: float, channel: str, text: str) -> Frame:
    """One ``ID#DATA`` field of candump -L: classic, FD (``##F``), remote (``R``/``R8``), error."""
    id_text, sep, d = text.partition("#")
    if not sep:
        raise _Bad("expected ID#DATA")
    cid, ext, err = _parse_id(id_text)
    if d[:1] == "#":
        if d[1:2] == "#":
            raise _Bad("CAN XL frames are not supported")
        if len(d) < 2 or not _is_hex(d[1]):
            raise _Bad("CAN FD frame needs one hex flags digit after '##'")
        flags = int(d[1], 16)
        data = _hex_data(d[2:])
        if len(data) not in CANFD_LENGTHS:
            raise _Bad(f"{len(data)} data bytes is not a CAN FD length")
        brs, esi = bool(flags & CANFD_BRS), bool(flags & CANFD_ESI)
        return _new(Frame, (t, channel, cid, data, ext, True, err, False, brs, esi, -1))
    if d[:1] in ("R", "r"):
        dlc_text = d[1:]
        if not dlc_text:
            dlc = -1
        elif len(dlc_text) == 1 and dlc_text in "012345678":
            dlc = int(dlc_text) or -1
        else:
            raise _Bad(f"bad remote frame DLC {dlc_text!r}: expected one digit 0-8")
        return _new(Frame, (t, channel, cid, b"", ext, False, err, True, False, False, dlc))
    data_text, underscore, raw_dlc = d.partition("_")
    data = _hex_data(data_text)
    if len(data) > 8:
        raise _Bad(f"{len(data)} data bytes in a classic CAN frame (at most 8; CAN FD frames use '##')")
    dlc = -1
    if underscore:
        # candump's len8_dlc: 8 data bytes with a raw DLC of 9..F
        if len(data) != 8 or len(raw_dlc) != 1 or raw_dlc not in "9ABCDEFabcdef":
            raise _Bad(f"bad raw DLC suffix '_{raw_dlc}': expected _9 .. _F after 8 data bytes")
        dlc = int(raw_dlc, 16)
    return _new(Frame, (t, channel, cid, data, ext, False, err, False, False, False, dlc))


_SHAPE = "expected '(secs) channel ID#DATA' (candump -L) or '(secs) channel ID [len] DATA' (candump -ta)"


def _parse_long(t: float | None, ts_text: str, toks: list[str]) -> Frame:
    """One line of plain candump output: ``can0  123   [8]  11 22 ...`` with a -ta timestamp."""
    i = 1
    brs = esi = False
    if len(toks) > 4 and toks[1] in ("RX", "TX"):  # candump -x: direction and B/E flag columns
        brs, esi, i = toks[2] == "B", toks[3] == "E", 4
    if len(toks) < i + 2:
        raise _Bad(_SHAPE)
    len_tok = toks[i + 1]
    if len(len_tok) < 3 or len_tok[0] != "[" or len_tok[-1] != "]":
        raise _Bad(_SHAPE)
    if t is None:
        raise _Bad("plain candump output without timestamps is not supported: record with candump -ta or -L")
    if len(ts_text.partition(".")[0]) < 10:
        raise _Bad("relative timestamps (candump -td / -tz) are not supported: record with candump -ta or -L")
    len_text = len_tok[1:-1]
    if not (len_text.isdigit() and len_text.isascii()):
        raise _Bad(f"bad length {len_tok!r}")
    length = int(len_text)
    is_fd = len(len_text) == 2  # candump prints [%d] for classic CAN, [%02d] for CAN FD
    cid, ext, err = _parse_id(toks[i])
    channel = toks[0]
    rest = toks[i + 2 :]
    if rest[:2] == ["remote", "request"]:
        if len(rest) != 2 or is_fd or length > 8:
            raise _Bad("bad remote request")
        return _new(Frame, (t, channel, cid, b"", ext, False, err, True, False, False, length or -1))
    byte_toks = rest[:length]
    if len(byte_toks) < length or any(len(b) != 2 for b in byte_toks):
        raise _Bad(f"[{length}] announces {length} data bytes: expected {length} two-digit hex bytes")
    data = _hex_data("".join(byte_toks))
    tail = rest[length:]
    if tail and not (tail[0][:1] == "'" or (tail[0] == "ERRORFRAME" and err)):
        raise _Bad(f"unexpected text after the data: {' '.join(tail)!r}")
    if is_fd:
        if length not in CANFD_LENGTHS:
            raise _Bad(f"{length} data bytes is not a CAN FD length")
    elif length > 8:
        raise _Bad(f"{length} data bytes in a classic CAN frame (at most 8)")
    return _new(Frame, (t, channel, cid, data, ext, is_fd, err, False, brs, esi, -1))


def _parse_line(line: str) -> Frame | None:
    """Parse one candump line of any supported shape; None for blank and ``#`` comment lines."""
    s = line.strip()
    if not s or s[0] == "#":
        return None
    t: float | None = None
    ts_text = ""
    if s[0] == "(":
        close = s.find(")")
        if close < 0:
            raise _Bad("timestamp has no closing ')'")
        ts_text = s[1:close]
        t = _parse_timestamp(ts_text)
        toks = s[close + 1 :].split()
    else:
        toks = s.split()
    if len(toks) >= 2 and "#" in toks[1]:
        if t is None:
            raise _Bad("missing '(seconds.microseconds)' timestamp")
        if len(toks) > 3 or (len(toks) == 3 and toks[2] not in _MARKERS):
            raise _Bad(f"unexpected text after the frame: {' '.join(toks[2:])!r}")
        return _parse_compact(t, toks[0], toks[1])
    return _parse_long(t, ts_text, toks)


def _as_text(block: bytes) -> str:
    r"""A block's bytes as the text parsers read them: UTF-8 (junk replaced), ``\r\n`` / ``\r`` ending a line."""
    text = block.decode("utf-8", "replace")
    return text.replace("\r\n", "\n").replace("\r", "\n") if "\r" in text else text


def candump_chunks(p: Path, gz: str, skip_bad: bool, st: ReadStats, want_ts_stats: bool,
                   owner: LogFrames) -> Iterator[Block]:
    """The candump text reader's blocks: plain blocks read by numpy (:mod:`canguard.io.candump_np`), others
    parsed line by line (:func:`_parse_line`, which names the file:line of a bad line)."""
    reader = _CandumpReader(p, gz, skip_bad, st, want_ts_stats)
    try:
        for block in reader.blocks():
            cols = reader.numpy(block)
            if cols is not None:
                yield cols
            else:
                yield from map(Block.of_frames, reader.lines(block))
            owner.reached(reader.position())
    finally:
        reader.close()
        owner.finished()
    if reader.frames == 0:
        skipped = f" ({st.bad_lines} bad lines skipped)" if st.bad_lines else ""
        raise LogFormatError(f"{p}: empty log: no frames{skipped}")


class _CandumpReader:
    """One candump text log, read a block of whole lines at a time (see :func:`candump_chunks`)."""

    def __init__(self, p: Path, gz: str, skip_bad: bool, st: ReadStats, want_ts_stats: bool) -> None:
        self.p, self.gz, self.skip_bad, self.st, self.want_ts_stats = p, gz, skip_bad, st, want_ts_stats
        self.raw = open(p, "rb")  # noqa: SIM115 -- closed by close()
        self.f: Any = open_decompressed(self.raw, gz)  # bytes: numpy reads them as they are; lines get _as_text
        self.frames = 0
        self.lineno = 0
        """Lines before the current block."""
        self.last_t = -math.inf
        self.last_was_error = False
        self.count = 0
        """Blocks read."""

    def position(self) -> int:
        """The position reached in the file on disk."""
        return self.raw.tell()

    def close(self) -> None:
        self.f.close()
        self.raw.close()

    def _read(self, longest: int) -> bytes:
        """A chunk and the rest of its last line, grown in place: no block-sized copies to fault in (Dask)."""
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

    def numpy(self, block: bytes) -> Block | None:
        """The block read by numpy (counted), or None: its lines are parsed one by one."""
        if self.last_was_error:
            return None
        cols = numpy_block(block, -1)  # it counts the lines
        if cols is None:
            return None
        n, st = cols.n, self.st
        ts = cols.time_s
        if self.want_ts_stats:
            note_order(st, float(ts[0]), self.last_t)
            backwards, repeated = cols.order
            st.backwards_timestamps += backwards
            st.repeated_timestamps += repeated
        self.last_t = float(ts[-1])
        self.frames += n
        self.lineno += n
        st.lines += n
        st.frames += n
        return cols

    def lines(self, block: bytes) -> Iterator[list[Frame]]:
        """The block's frames parsed line by line (a bad line raises, or is counted with ``skip_bad``)."""
        text = _as_text(block)
        lines = text.split("\n")
        lines.pop()  # the empty string after the block's last newline
        st = self.st
        st.lines += len(lines)
        out: list[Frame] = []
        for no, line in enumerate(lines, self.lineno + 1):
            if self.last_was_error and line[:1] == "\t":
                continue  # candump -e explains an error frame on indented lines below it
            try:
                fr = _parse_line(line)
            except _Bad as bad:
                if not self.skip_bad:
                    if out:
                        yield out  # every frame before the bad line is processed first
                    raise LogFormatError(f"{self.p}:{no}: {bad.reason}: {quote(line)}") from None
                st.bad_lines += 1
                if len(st.bad_examples) < MAX_BAD_EXAMPLES:
                    st.bad_examples.append(BadLine(no, bad.reason, line))
                continue
            if fr is None:
                continue
            self.last_was_error = fr.is_error_frame
            note_order(st, fr.t, self.last_t)
            self.last_t = fr.t
            self.frames += 1
            st.frames += 1
            out.append(fr)
        self.lineno += len(lines)
        if out:
            yield out
