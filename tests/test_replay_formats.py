"""Log readers and the candump -L writer of canguard.io.logs (formats, bad input, round trips)."""

from __future__ import annotations

import copy
import gzip
import io
from collections.abc import Callable, Iterable
from pathlib import Path

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canguard.errors import LogFormatError
from canguard.io import candump
from canguard.io.block import frame_from_message
from canguard.io.candump import format_candump_line, write_candump
from canguard.io.frame import Frame
from canguard.io.logs import ReadStats, log_format, read_log
from canguard.io.progress import ProgressBar, wrap_progress

T0 = 1547073727.670704


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _read(tmp_path: Path, text: str, name: str = "x.log", **kwargs: object) -> list[Frame]:
    return list(read_log(_write(tmp_path / name, text), **kwargs))  # type: ignore[arg-type]


def _frame(t: float, arb: int, data: bytes = b"", channel: str = "can0", **kw: object) -> Frame:
    return Frame(t, channel, arb, data, **kw)  # type: ignore[arg-type]


class TestCandumpCompact:
    """candump -L / -l lines: ``(secs) channel ID#DATA`` and every special case."""

    def test_classic_line(self, tmp_path: Path) -> None:
        """The line from the issue reads as one standard 8-byte frame with its timestamp and channel."""
        (fr,) = _read(tmp_path, "(1547073727.670704) can0 081#0000000008000000\n")
        assert fr == Frame(T0, "can0", 0x081, bytes.fromhex("0000000008000000"))
        assert fr.dlc == -1 and not fr.is_extended_id

    def test_extended_id_leading_zeros(self, tmp_path: Path) -> None:
        """Eight hex digits mean an extended id even when the value would fit in 11 bits."""
        frames = _read(tmp_path, "(1.000000) can0 00000123#11\n(2.000000) can0 18FF50E5#0102\n")
        assert [(f.arbitration_id, f.is_extended_id) for f in frames] == [(0x123, True), (0x18FF50E5, True)]

    def test_fd_flags(self, tmp_path: Path) -> None:
        """``##<flags>`` marks CAN FD; flag 1 is BRS, 2 is ESI, and data may exceed 8 bytes."""
        text = "(1.0) can1 123##0AABB\n(2.0) can1 123##1\n(3.0) can1 123##2\n"
        text += "(4.0) can1 123##3" + "11" * 64 + "\n"
        f0, f1, f2, f3 = _read(tmp_path, text)
        assert f0.is_fd and f0.data == b"\xaa\xbb" and not f0.bitrate_switch and not f0.error_state_indicator
        assert f1.bitrate_switch and not f1.error_state_indicator and f1.data == b""
        assert f2.error_state_indicator and not f2.bitrate_switch
        assert f3.bitrate_switch and f3.error_state_indicator and len(f3.data) == 64

    def test_remote_frames(self, tmp_path: Path) -> None:
        """``R`` is a remote frame without DLC, ``R8`` one with DLC 8, neither carries data."""
        f0, f1 = _read(tmp_path, "(1.0) can0 123#R\n(2.0) can0 00000124#R8\n")
        assert f0.is_remote_frame and f0.data == b"" and f0.dlc == -1
        assert f1.is_remote_frame and f1.dlc == 8 and f1.is_extended_id

    def test_error_frame(self, tmp_path: Path) -> None:
        """An id with CAN_ERR_FLAG set is an error frame whose id is the error class."""
        (fr,) = _read(tmp_path, "(1.0) can0 20000080#0000000000000000\n")
        assert fr.is_error_frame and fr.arbitration_id == 0x80 and fr.data == bytes(8)

    def test_direction_markers(self, tmp_path: Path) -> None:
        """Trailing T / R direction markers (python-can's writer adds them) are accepted."""
        frames = _read(tmp_path, "(1.0) can0 123#11 T\n(2.0) can0 124#22 R\n")
        assert [f.data for f in frames] == [b"\x11", b"\x22"]

    def test_raw_dlc_suffix(self, tmp_path: Path) -> None:
        """candump's ``_F`` len8_dlc suffix keeps the raw DLC of an 8-byte classic frame."""
        (fr,) = _read(tmp_path, "(1.0) can0 123#1122334455667788_F\n")
        assert fr.dlc == 15 and len(fr.data) == 8

    def test_blank_lines_and_comments(self, tmp_path: Path) -> None:
        """Blank lines and ``#`` comments are skipped but still counted as lines (a bad line's number)."""
        text = "# recorded on the bench\n\n(1.0) can0 123#11\n\n"
        assert len(_read(tmp_path, text)) == 1
        with pytest.raises(LogFormatError, match=r"x\.log:5: bad CAN id '12'"):
            _read(tmp_path, text + "(2.0) can0 12#11\n")

    def test_crlf_and_missing_final_newline(self, tmp_path: Path) -> None:
        """Windows line ends and a last line without a newline still give every frame."""
        path = tmp_path / "x.log"
        path.write_bytes(b"(1.0) can0 123#11\r\n(2.0) can0 124#22")
        assert [f.arbitration_id for f in read_log(path)] == [0x123, 0x124]

    def test_bom_and_line_ends(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """The reader reads bytes: a UTF-8 byte order mark, Windows and old-Mac line ends (some, or every one: a
        file of lone CRs longer than four blocks, plain or gzip'd), a block edge inside a \\r\\n and a junk byte
        read as text mode did (the same frames, the bad line at the same number)."""
        lines = [f"({T0 + i / 1000:.6f}) can0 {i % 0x7FF:03X}#{i % 256:02X}" for i in range(40)]
        clean = "".join(line + "\n" for line in lines).encode("ascii")
        for chunk in (64, 97, 1 << 19):
            monkeypatch.setattr(candump, "CHUNK_CHARS", chunk)
            expected = list(read_log(self._write(tmp_path, "clean.log", clean)))
            for name, data in (("bom.log", b"\xef\xbb\xbf" + clean), ("crlf.log", clean.replace(b"\n", b"\r\n")),
                               ("cr.log", clean.replace(b"\n", b"\r", 7)), ("last.log", clean[:-1]),
                               ("allcr.log", clean.replace(b"\n", b"\r")),
                               ("allcr.log.gz", gzip.compress(clean.replace(b"\n", b"\r")))):
                assert list(read_log(self._write(tmp_path, name, data))) == expected, (name, chunk)
            junk = clean.replace(b"\n", b"\n\xff\xfe junk\r\n", 1)
            with pytest.raises(LogFormatError, match=r"junk\.log:2: .*'\ufffd\ufffd junk'"):
                list(read_log(self._write(tmp_path, "junk.log", junk)))

    @staticmethod
    def _write(tmp_path: Path, name: str, data: bytes) -> Path:
        path = tmp_path / name
        path.write_bytes(data)
        return path

    def test_chunks_read_as_python_can_reads_the_log(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """Whole and in tiny chunks (every shape at a block's edge), the frames python-can's candump reader reads."""
        lines = [f"({T0 + i / 1000:.6f}) can{i % 2} {i % 0x7FF:03X}#{i % 256:02X}{'' if i % 7 else 'AA'}"
                 for i in range(300)]
        lines[17] = "(1547073727.900000) can0 123##1AABB"
        lines[133] = "(1547073727.950000) can0 20000080#0000000000000000"
        text = "\n".join(lines) + "\n"
        whole = _read(tmp_path, text)
        monkeypatch.setattr(candump, "CHUNK_CHARS", 97)
        chunked = _read(tmp_path, text, name="y.log")
        expected = [frame_from_message(m) for m in can.CanutilsLogReader(tmp_path / "x.log")]
        expected[133] = _frame(1547073727.95, 0x80, bytes(8), is_extended_id=True, is_error_frame=True)  # python-can
        assert whole == chunked == expected  # keeps neither the channel nor the id and data of an error frame


class TestCandumpPlain:
    """Plain candump output (``can0  123   [8]  11 22 ...``) with -ta timestamps."""

    def test_ta_lines(self, tmp_path: Path) -> None:
        """-ta lines of standard, extended, FD, remote and error frames read like their -L twins."""
        text = (
            "(1547073727.670704)  can0  081   [8]  00 00 00 00 08 00 00 00\n"
            "(1547073727.670705)  can0  00000123   [2]  11 22                     '.\"'\n"
            "(1547073727.670706)  can1       123  [03]  11 22 33\n"
            "(1547073727.670708)  can0       123   [4]  remote request\n"
            "(1547073727.670710)  can0  20000080   [8]  00 00 00 00 00 00 00 00   ERRORFRAME\n"
        )
        f0, f1, f2, f3, f4 = _read(tmp_path, text)
        assert f0 == Frame(T0, "can0", 0x81, bytes.fromhex("0000000008000000"))
        assert f1.is_extended_id and f1.arbitration_id == 0x123 and f1.data == b"\x11\x22"
        assert f2.is_fd and f2.channel == "can1" and f2.data == b"\x11\x22\x33"
        assert f3.is_remote_frame and f3.dlc == 4
        assert f4.is_error_frame and f4.arbitration_id == 0x80

    def test_log2long_output(self, tmp_path: Path) -> None:
        """Output in can-utils' log2long layout (indented standard ids, ASCII column) reads back."""
        text = "(1547073727.670704)  can0       081   [8]  00 00 00 00 08 00 00 00   '........'\n"
        assert _read(tmp_path, text) == [Frame(T0, "can0", 0x81, bytes.fromhex("0000000008000000"))]

    def test_extra_info_columns(self, tmp_path: Path) -> None:
        """candump -x columns (RX/TX, B, E) give the FD frame's BRS and ESI flags."""
        (fr,) = _read(tmp_path, "(1547073727.670704)  can0  RX B E  123  [02]  11 22\n")
        assert fr.is_fd and fr.bitrate_switch and fr.error_state_indicator

    def test_relative_timestamps_rejected(self, tmp_path: Path) -> None:
        """-td / -tz timestamps are refused with a message that says to use -ta or -L."""
        with pytest.raises(LogFormatError, match=r"x\.log:1: relative timestamps.*-ta or -L"):
            _read(tmp_path, "(000.000123)  can0  123   [1]  11\n")

    def test_no_timestamp_rejected(self, tmp_path: Path) -> None:
        """Plain output without timestamps is refused with a message that says to use -ta or -L."""
        with pytest.raises(LogFormatError, match=r"without timestamps.*-ta or -L"):
            _read(tmp_path, "  can0  123   [8]  11 22 33 44 55 66 77 88\n")

    def test_absolute_date_rejected(self, tmp_path: Path) -> None:
        """-tA date timestamps are refused with a message that says to use -ta or -L."""
        with pytest.raises(LogFormatError, match=r"-tA.*-ta or -L"):
            _read(tmp_path, "(2019-01-09 12:42:07.670704)  can0  123   [1]  11\n")

    def test_byte_count_mismatch(self, tmp_path: Path) -> None:
        """A length field that announces more bytes than the line has is a malformed line."""
        with pytest.raises(LogFormatError, match=r"x\.log:1: \[3\] announces 3 data bytes"):
            _read(tmp_path, "(1547073727.670704)  can0  123   [3]  11 22\n")


def _messages() -> list[can.Message]:
    """Messages every python-can writer supports: standard, extended, one channel."""
    return [
        can.Message(timestamp=T0 + i * 0.001, arbitration_id=0x81 + i, is_extended_id=False,
                    data=bytes([i] * (i % 9)), channel=0)
        for i in range(8)
    ] + [can.Message(timestamp=T0 + 0.5, arbitration_id=0x18FF50E5, is_extended_id=True, data=b"\x01\x02",
                     channel=0)]


def _log_with(writer: Callable[[str], can.io.generic.MessageWriter], path: Path,
              messages: Iterable[can.Message]) -> Path:
    w = writer(str(path))
    for m in messages:
        w.on_message_received(m)
    w.stop()
    return path


def _same_frames(frames: list[Frame], messages: list[can.Message], relative: bool = False) -> None:
    assert len(frames) == len(messages)
    base_t = messages[0].timestamp if relative else 0.0
    for f, m in zip(frames, messages, strict=True):
        assert f.t == pytest.approx(m.timestamp - base_t, abs=2e-6)
        assert (f.arbitration_id, f.is_extended_id) == (m.arbitration_id, m.is_extended_id)
        assert f.data == bytes(m.data)


class TestPythonCanFormats:
    """ASC, BLF, TRC and CSV logs written by python-can's own writers read back to the same frames."""

    def test_asc(self, tmp_path: Path) -> None:
        """ASC frames come back with timestamps relative to the measurement start and channel can0."""
        msgs = _messages()
        frames = list(read_log(_log_with(can.ASCWriter, tmp_path / "x.asc", msgs)))
        _same_frames(frames, msgs, relative=True)
        assert {f.channel for f in frames} == {"can0"}

    def test_blf(self, tmp_path: Path) -> None:
        """BLF frames come back with their absolute timestamps, FD and remote frames included."""
        msgs = [*_messages(),
                can.Message(timestamp=T0 + 1, arbitration_id=0x123, is_extended_id=False, is_fd=True,
                            bitrate_switch=True, data=bytes(range(12)), channel=0),
                can.Message(timestamp=T0 + 2, arbitration_id=0x124, is_extended_id=False,
                            is_remote_frame=True, dlc=4, channel=0)]
        path = _log_with(can.BLFWriter, tmp_path / "x.blf", msgs)
        frames = list(read_log(path))
        # The times as python-can's reader gives them: its writer rounded them to the millisecond before 4.6.
        expected = []
        for m, back in zip(msgs, can.BLFReader(str(path)), strict=True):
            assert back.timestamp == pytest.approx(m.timestamp, abs=5e-4 + 2e-6)
            expected.append(copy.copy(m))
            expected[-1].timestamp = back.timestamp
        _same_frames(frames, expected)
        assert frames[-2].is_fd and frames[-2].bitrate_switch
        assert frames[-1].is_remote_frame and frames[-1].dlc == 4

    def test_trc(self, tmp_path: Path) -> None:
        """TRC frames come back with their timestamps, ids and data."""
        msgs = _messages()
        _same_frames(list(read_log(_log_with(can.TRCWriter, tmp_path / "x.trc", msgs))), msgs)

    def test_csv(self, tmp_path: Path) -> None:
        """CSV frames come back with their timestamps, ids and data (CSV has no channel: empty name)."""
        msgs = _messages()
        frames = list(read_log(_log_with(can.CSVWriter, tmp_path / "x.csv", msgs)))
        _same_frames(frames, msgs)
        assert {f.channel for f in frames} == {""}

    def test_corrupt_blf(self, tmp_path: Path) -> None:
        """A file that is not BLF gives a LogFormatError naming the file, not a struct traceback."""
        path = tmp_path / "bad.blf"
        path.write_bytes(b"this is not a binary logging file" * 10)
        with pytest.raises(LogFormatError, match=r"bad\.blf"):
            list(read_log(path))

    def test_mf4_without_asammdf(self, tmp_path: Path) -> None:
        """An .mf4 log without asammdf installed names what to install (or reads, when it is installed)."""
        pytest.importorskip("can")
        import importlib.util

        if importlib.util.find_spec("asammdf") is not None:
            pytest.skip("asammdf is installed")
        path = _write(tmp_path / "x.mf4", "")
        with pytest.raises(LogFormatError, match=r"python-can\[mf4\]"):
            read_log(path)

    def test_frame_from_message(self) -> None:
        """A can.Message converts to a Frame with a string channel and -1 DLC when it equals the length."""
        msg = can.Message(timestamp=2.5, arbitration_id=0x7FF, is_extended_id=False, data=b"\x01", channel=3)
        assert frame_from_message(msg) == Frame(2.5, "can3", 0x7FF, b"\x01")
        assert frame_from_message(msg, channel="main").channel == "main"


class TestGzip:
    """``.gz`` on any format is read through gzip, streaming."""

    def test_candump_gz(self, tmp_path: Path) -> None:
        """A gzip'd candump log reads to the same frames as the plain one."""
        text = "".join(f"({T0 + i:.6f}) can0 {i:03X}#{i:02X}\n" for i in range(50))
        plain = _read(tmp_path, text)
        gz = tmp_path / "x.log.gz"
        with gzip.open(gz, "wt") as f:
            f.write(text)
        assert list(read_log(gz)) == plain

    def test_asc_gz(self, tmp_path: Path) -> None:
        """A gzip'd ASC log written by python-can reads back to the same frames."""
        msgs = _messages()
        asc = _log_with(can.ASCWriter, tmp_path / "x.asc", msgs)
        gz = tmp_path / "x.asc.gz"
        gz.write_bytes(gzip.compress(asc.read_bytes()))
        _same_frames(list(read_log(gz)), msgs, relative=True)

    def test_not_gzip(self, tmp_path: Path) -> None:
        """A .gz file that is not gzip data gives a LogFormatError naming the file."""
        path = tmp_path / "x.log.gz"
        path.write_bytes(b"(1.0) can0 123#11\n")
        with pytest.raises(LogFormatError, match=r"x\.log\.gz: cannot read gzip log"):
            list(read_log(path))


class TestXzZstd:
    """``.xz`` and ``.zst`` like ``.gz``: any format, streaming, the same frames and the same replay."""

    @staticmethod
    def _compress(data: bytes, suffix: str) -> bytes:
        import lzma

        import zstandard

        return lzma.compress(data) if suffix == ".xz" else zstandard.ZstdCompressor().compress(data)

    @pytest.mark.parametrize("chunk", [97, 1 << 19])
    @pytest.mark.parametrize("suffix", [".xz", ".zst"])
    def test_candump(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, suffix: str, chunk: int) -> None:
        """Blocks that end inside a line (completed by a readline through the decompressor) too."""
        monkeypatch.setattr(candump, "CHUNK_CHARS", chunk)
        text = "".join(f"({T0 + i:.6f}) can0 {i:03X}#{i:02X}\n" for i in range(50))
        plain = _read(tmp_path, text)
        packed = tmp_path / f"x.log{suffix}"
        packed.write_bytes(self._compress(text.encode(), suffix))
        assert list(read_log(packed)) == plain
        chunks = list(read_log(packed).chunks())
        assert chunks and all(type(c) is not list for c in chunks), "a compressed plain block left the block path"

    @pytest.mark.parametrize("suffix", [".xz", ".zst"])
    def test_asc(self, tmp_path: Path, suffix: str) -> None:
        msgs = _messages()
        asc = _log_with(can.ASCWriter, tmp_path / "x.asc", msgs)
        packed = tmp_path / f"x.asc{suffix}"
        packed.write_bytes(self._compress(asc.read_bytes(), suffix))
        _same_frames(list(read_log(packed)), msgs, relative=True)

    @pytest.mark.parametrize(("suffix", "kind"), [(".xz", "xz"), (".zst", "zstd")])
    def test_not_compressed(self, tmp_path: Path, suffix: str, kind: str) -> None:
        path = tmp_path / f"x.log{suffix}"
        path.write_bytes(b"(1.0) can0 123#11\n")
        with pytest.raises(LogFormatError, match=rf"x\.log\{suffix}: cannot read {kind} log"):
            list(read_log(path))

    def test_zst_without_zstandard_says_how(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        import importlib.util

        path = tmp_path / "x.log.zst"
        path.write_bytes(b"")
        real = importlib.util.find_spec
        monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "zstandard" else real(name))
        with pytest.raises(LogFormatError, match=r"reading \.zst logs needs zstandard: pip install zstandard"):
            read_log(path)


class TestBadInput:
    """Malformed lines, empty logs, unknown extensions and missing files: clear errors, never tracebacks."""

    BAD = "(1.0) can0 123#11\n(2.0) can0 12G#11\n(3.0) can0 124#22\n(4.0) can0 125#1\n(5.0) can0 126#33\n"

    def test_malformed_line_names_file_line_and_text(self, tmp_path: Path) -> None:
        """The error names file:line, the reason and the line's text."""
        with pytest.raises(LogFormatError) as err:
            _read(tmp_path, self.BAD)
        msg = str(err.value)
        assert msg.startswith(f"{tmp_path / 'x.log'}:2: bad CAN id '12G'")
        assert "'(2.0) can0 12G#11'" in msg

    def test_frames_before_the_bad_line_are_delivered(self, tmp_path: Path) -> None:
        """Frames before a malformed line arrive before the error stops the stream."""
        got: list[Frame] = []
        with pytest.raises(LogFormatError):
            for fr in read_log(_write(tmp_path / "x.log", self.BAD)):
                got.append(fr)
        assert [f.arbitration_id for f in got] == [0x123]

    def test_skip_bad_counts(self, tmp_path: Path) -> None:
        """With skip_bad the bad lines are skipped and counted."""
        stats = ReadStats()
        frames = _read(tmp_path, self.BAD, skip_bad=True, stats=stats)
        assert [f.arbitration_id for f in frames] == [0x123, 0x124, 0x126]
        assert stats.bad_lines == 2 and stats.frames == 3

    @pytest.mark.parametrize(
        ("line", "reason"),
        [
            ("(1.0) can0 123#112233445566778899", "9 data bytes in a classic CAN frame"),
            ("(1.0) can0 800#11", "standard CAN id '800' is above 7FF"),
            ("(1.0) can0 1234#11", "bad CAN id '1234'"),
            ("(1.0) can0 0x1#11", "bad CAN id '0x1'"),
            ("(1.0) can0 123#R9", "bad remote frame DLC"),
            ("(1.0) can0 123##G11", "flags digit"),
            ("(1.0) can0 123##0" + "11" * 9, "not a CAN FD length"),
            ("(1.0) can0 123#11 X", "unexpected text after the frame"),
            ("(1.0 can0 123#11", "no closing ')'"),
            ("(nan) can0 123#11", "bad timestamp 'nan'"),
            ("can0 123#11", "missing '(seconds.microseconds)' timestamp"),
            ("(1.0) can0", "expected '(secs) channel ID#DATA'"),
            ("(1.0) can0 80000123#11", "above 1FFFFFFF"),
        ],
    )
    def test_reasons(self, tmp_path: Path, line: str, reason: str) -> None:
        """Each kind of malformed line says what is wrong with it."""
        with pytest.raises(LogFormatError) as err:
            _read(tmp_path, line + "\n")
        msg = str(err.value)
        assert msg.startswith(f"{tmp_path / 'x.log'}:1: ") and reason in msg and repr(line) in msg

    @pytest.mark.parametrize(
        ("bad", "reason"),
        [
            ("({t}) can0 800#11", "standard CAN id '800' is above 7FF"),
            ("({t}) can0 80000123#11", "above 1FFFFFFF"),
            ("({t}) can0 12G#11", "bad CAN id '12G'"),
            ("({t}) can0 123#1", "odd number of hex digits"),
            ("({t}) can0 123#1G", "is not hex"),
            ("({t}) can0 123#112233445566778899", "9 data bytes in a classic CAN frame"),
            ("({t} can0 123#11", "no closing ')'"),
            ("{t}) can0 123#11", "expected '(secs) channel ID#DATA'"),
            ("(1547073727.6707.4) can0 123#11", "bad timestamp"),
            ("(1547073727.) can0 123#11", "bad timestamp"),
            ("(1547073727.67070x) can0 123#11", "bad timestamp"),
        ],
    )
    def test_one_bad_line_in_a_plain_block(self, tmp_path: Path, bad: str, reason: str) -> None:
        """A block of plain lines with one bad line in the middle is not taken whole: the bad line is named."""
        lines = [f"({T0 + i / 1000:.6f}) can0 {0x100 + i % 16:03X}#{i % 256:02X}11" for i in range(100)]
        lines[49] = bad.format(t=f"{T0 + 0.049:.6f}")
        with pytest.raises(LogFormatError) as err:
            _read(tmp_path, "\n".join(lines) + "\n")
        msg = str(err.value)
        assert msg.startswith(f"{tmp_path / 'x.log'}:50: ") and reason in msg

    def test_timestamps_of_several_widths_read_right(self, tmp_path: Path) -> None:
        """Timestamps that gain a digit or have fewer decimals mid-block give the frames python-can reads."""
        lines = [f"({9999.990 + i / 1000:.6f}) can0 123#{i:02X}" for i in range(20)]
        lines[5] = "(9999.9955) can0 123#05"
        text = "\n".join(lines) + "\n"
        assert _read(tmp_path, text) == [frame_from_message(m) for m in can.CanutilsLogReader(tmp_path / "x.log")]

    def test_bad_line_in_a_later_chunk(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """Line numbers stay right across chunk boundaries."""
        monkeypatch.setattr(candump, "CHUNK_CHARS", 64)
        text = "".join(f"({i}.000000) can0 123#11\n" for i in range(40)) + "(41.0) can0 123#1\n"
        with pytest.raises(LogFormatError, match=r"x\.log:41: odd number"):
            _read(tmp_path, text)

    def test_empty_log(self, tmp_path: Path) -> None:
        """An empty log (or only comments) is a LogFormatError saying it has no frames."""
        with pytest.raises(LogFormatError, match=r"x\.log: empty log: no frames"):
            _read(tmp_path, "")
        with pytest.raises(LogFormatError, match=r"empty log"):
            _read(tmp_path, "# nothing\n\n", name="y.log")

    def test_all_lines_bad_with_skip_bad(self, tmp_path: Path) -> None:
        """A log whose every line is bad is empty even with skip_bad, and says how many were skipped."""
        with pytest.raises(LogFormatError, match=r"no frames \(2 bad lines skipped\)"):
            _read(tmp_path, "junk\nmore junk\n", skip_bad=True)

    def test_empty_blf(self, tmp_path: Path) -> None:
        """A python-can log without messages is reported as empty too."""
        path = _log_with(can.BLFWriter, tmp_path / "x.blf", [])
        with pytest.raises(LogFormatError, match="empty log"):
            list(read_log(path))

    def test_unknown_extension(self, tmp_path: Path) -> None:
        """An unknown extension is refused at once, listing the known ones."""
        path = _write(tmp_path / "x.pcap", "")
        with pytest.raises(LogFormatError, match=r"x\.pcap: unknown log format '\.pcap'.*\.log.*\.blf"):
            read_log(path)
        with pytest.raises(LogFormatError, match=r"unknown log format '\.zip'"):
            log_format("x.zip.gz")

    def test_missing_file(self, tmp_path: Path) -> None:
        """A missing file is refused at once with a LogFormatError naming the path."""
        with pytest.raises(LogFormatError, match=r"nope\.log: no such file"):
            read_log(tmp_path / "nope.log")

    def test_directory(self, tmp_path: Path) -> None:
        """A directory named like a log is refused at once."""
        (tmp_path / "d.log").mkdir()
        with pytest.raises(LogFormatError, match="not a regular file"):
            read_log(tmp_path / "d.log")

    def test_binary_junk(self, tmp_path: Path) -> None:
        """Binary junk in a .log file is a malformed line, not a UnicodeDecodeError."""
        path = tmp_path / "x.log"
        path.write_bytes(b"(1.0) can0 123#11\n\xff\xfe\x00junk\n")
        with pytest.raises(LogFormatError, match=r"x\.log:2:"):
            list(read_log(path))


    def test_no_line_break(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """A line longer than four blocks (a binary blob named .log, say) is refused with its line number,
        after the frames before it; it is not read whole into memory first."""
        monkeypatch.setattr(candump, "CHUNK_CHARS", 64)
        path = tmp_path / "blob.log"
        good = "".join(f"({t:.6f}) can0 123#11\n" for t in (1.0, 2.0, 3.0))
        path.write_text(good + "A" * 10_000 + "\n(4.000000) can0 123#11\n", encoding="ascii")
        got: list[float] = []
        with pytest.raises(LogFormatError, match=r"blob\.log:4: no line break in 320 characters"):
            for chunk in read_log(path):
                got.append(chunk.t)
        assert got == [1.0, 2.0, 3.0]

class TestTimestampStats:
    """Backwards and repeated timestamps are counted, never fatal."""

    def test_counts(self, tmp_path: Path) -> None:
        """One step back and two repeats are counted and every frame is still delivered in file order."""
        text = "".join(f"({t:.6f}) can0 123#11\n" for t in (1.0, 2.0, 2.0, 1.5, 3.0, 3.0))
        stats = ReadStats()
        frames = _read(tmp_path, text, stats=stats)
        assert [f.t for f in frames] == [1.0, 2.0, 2.0, 1.5, 3.0, 3.0]
        assert (stats.backwards_timestamps, stats.repeated_timestamps) == (1, 2)

    def test_counts_across_chunks(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """A step back at a chunk boundary is counted too."""
        monkeypatch.setattr(candump, "CHUNK_CHARS", 40)
        ts = [float(i) for i in range(30)]
        ts[15] = 3.0
        stats = ReadStats()
        _read(tmp_path, "".join(f"({t:.6f}) can0 123#11\n" for t in ts), stats=stats)
        assert (stats.backwards_timestamps, stats.repeated_timestamps) == (1, 0)

    def test_python_can_format_counts(self, tmp_path: Path) -> None:
        """Repeated timestamps in a BLF log are counted as well."""
        msgs = [can.Message(timestamp=T0, arbitration_id=1, is_extended_id=False, channel=0)] * 3
        stats = ReadStats()
        list(read_log(_log_with(can.BLFWriter, tmp_path / "x.blf", msgs), stats=stats))
        assert (stats.frames, stats.repeated_timestamps) == (3, 2)


def _ts(ms: int) -> float:
    """T0 plus ``ms`` milliseconds, as candump's 6 decimals would give it."""
    return float(f"{T0 + ms / 1000:.6f}")


SPECIAL = [
    Frame(T0, "can0", 0x081, bytes.fromhex("0000000008000000")),
    Frame(_ts(1), "can0", 0x123, b"\x11", is_extended_id=True),
    Frame(_ts(2), "can1", 0x123, bytes(range(12)), is_fd=True, bitrate_switch=True),
    Frame(_ts(3), "can1", 0x124, b"", is_fd=True, error_state_indicator=True),
    Frame(_ts(4), "can0", 0x125, b"", is_remote_frame=True),
    Frame(_ts(5), "can0", 0x126, b"", is_remote_frame=True, dlc=8),
    Frame(_ts(6), "can0", 0x80, bytes(8), is_extended_id=True, is_error_frame=True),
    Frame(_ts(7), "vcan0", 0x1FFFFFFF, b"", is_extended_id=True),
]


class TestWriteCandump:
    """write_candump / format_candump_line: candump -L that both python-can and read_log read back."""

    def test_line_format(self) -> None:
        """Lines follow candump -L: 6-decimal time, 3/8-digit ids, ``##F`` for FD, ``R<dlc>`` for remote."""
        lines = [format_candump_line(f) for f in SPECIAL]
        assert lines[0] == "(1547073727.670704) can0 081#0000000008000000"
        assert lines[1].endswith(" 00000123#11")
        assert lines[2].endswith(" 123##1000102030405060708090A0B")
        assert lines[3].endswith(" 124##2")
        assert lines[4].endswith(" 125#R") and lines[5].endswith(" 126#R8")
        assert lines[6].endswith(" 20000080#0000000000000000")

    def test_read_log_round_trip(self, tmp_path: Path) -> None:
        """read_log reads written frames back exactly, every special case included."""
        path = tmp_path / "out.log"
        with path.open("w") as f:
            assert write_candump(SPECIAL, f) == len(SPECIAL)
        assert list(read_log(path)) == SPECIAL

    def test_python_can_reads_it(self, tmp_path: Path) -> None:
        """python-can's CanutilsLogReader reads the written log to the same frames."""
        path = tmp_path / "out.log"
        with path.open("w") as f:
            write_candump(SPECIAL, f)
        msgs = list(can.CanutilsLogReader(str(path)))
        assert len(msgs) == len(SPECIAL)
        for fr, msg in zip(SPECIAL, msgs, strict=True):
            assert msg.timestamp == pytest.approx(fr.t, abs=1e-6)
            assert msg.is_error_frame == fr.is_error_frame
            if fr.is_error_frame:
                continue
            assert frame_from_message(msg) == fr._replace(t=msg.timestamp)

    def test_default_channel_and_bad_channel(self) -> None:
        """An empty channel is written as the default one; a channel with a space is refused."""
        assert format_candump_line(Frame(1.0, "", 1, b"")).startswith("(1.000000) can0 001#")
        with pytest.raises(ValueError, match="whitespace"):
            format_candump_line(Frame(1.0, "can 0", 1, b""))

    def test_id_out_of_range(self) -> None:
        """A standard id above 0x7FF cannot be written (it would read back as another frame)."""
        with pytest.raises(ValueError, match="standard id"):
            format_candump_line(Frame(1.0, "can0", 0x800, b""))

    @settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(
        st.lists(
            st.tuples(
                st.integers(0, 10**12),
                st.sampled_from(["can0", "can1", "vcan0"]),
                st.booleans(),
                st.integers(0, 0x1FFFFFFF),
                st.binary(max_size=8),
            ),
            min_size=1,
            max_size=40,
        )
    )
    def test_property_round_trip(
        self, tmp_path: Path, rows: list[tuple[int, str, bool, int, bytes]]
    ) -> None:
        """Any classic frames written with write_candump read back identical (bulk path included)."""
        frames = [
            Frame(us / 1e6, ch, arb if ext else arb & 0x7FF, data, is_extended_id=ext)
            for us, ch, ext, arb, data in rows
        ]
        buf = io.StringIO()
        write_candump(frames, buf)
        path = tmp_path / "prop.log"
        path.write_text(buf.getvalue())
        assert list(read_log(path)) == frames


class TestProgressBar:
    """ProgressBar: drawn only on a terminal, fed by the reader's file position."""

    class _Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    def test_silent_when_not_a_tty(self) -> None:
        """On a non-terminal stream nothing is written."""
        out = io.StringIO()
        bar = ProgressBar(1000, stream=out)
        bar.update(500)
        bar.close()
        assert not bar.enabled and out.getvalue() == ""

    def test_draws_on_a_tty(self) -> None:
        """On a terminal the bar shows the percentage and ends its line on close."""
        out = self._Tty()
        bar = ProgressBar(1_000_000, stream=out, label="x.log")
        bar.update(500_000)
        bar.close()
        text = out.getvalue()
        assert "\r[###############...............]  50%  0.5/1.0 MB  x.log" in text
        assert text.endswith("\n")

    def test_reader_reports_the_file_position(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """read_log moves the bar to the end of the file by the time the log is read."""
        monkeypatch.setattr(candump, "CHUNK_CHARS", 256)
        path = _write(tmp_path / "x.log", "".join(f"({i}.000000) can0 123#11\n" for i in range(200)))
        bar = ProgressBar(path.stat().st_size, stream=self._Tty())
        frames = read_log(path)
        frames.progress = bar
        list(frames)
        assert bar.position == path.stat().st_size

    def test_wrap_progress_attaches_to_the_reader(self, tmp_path: Path) -> None:
        """wrap_progress on a terminal attaches a bar that ends at 100 % once the log is read."""
        path = _write(tmp_path / "x.log", "".join(f"({i}.000000) can0 123#11\n" for i in range(50)))
        out = self._Tty()
        frames = wrap_progress(read_log(path), path, stream=out)
        assert len(list(frames)) == 50
        assert "100%" in out.getvalue() and out.getvalue().endswith("x.log\n")

    def test_wrap_progress_off_a_terminal(self, tmp_path: Path) -> None:
        """Off a terminal wrap_progress returns the reader unchanged and writes nothing."""
        path = _write(tmp_path / "x.log", "(1.000000) can0 123#11\n")
        reader = read_log(path)
        out = io.StringIO()
        assert wrap_progress(reader, path, stream=out) is reader
        assert list(reader) and out.getvalue() == ""
