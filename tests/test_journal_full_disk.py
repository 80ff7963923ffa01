"""The event journal on a disk that fills up.

A journal line reaches the file whole or not at all; lines the file refuses stay in
memory and are written, in order and once, when the disk takes them again; lines that
cannot reach the file at exit (or overflow the in-memory backlog) go to stderr, which
systemd keeps in its journal, and are counted. Nothing is lost without a word.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

import canguard.engine.events as events_mod
from canguard.engine.events import EventJournal


class Disk:
    """Stands in for os.write in the journal: a byte budget; a write larger than what is left is cut short."""

    def __init__(self) -> None:
        self.free: int | None = None  # None: unlimited
        self.real_write = os.write

    def write(self, fd: int, data: bytes | memoryview) -> int:
        data = bytes(data)
        if self.free is None:
            return self.real_write(fd, data)
        if self.free == 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        n = self.real_write(fd, data[: self.free])
        self.free -= n
        return n


@pytest.fixture
def disk(monkeypatch: pytest.MonkeyPatch) -> Disk:
    d = Disk()
    monkeypatch.setattr(events_mod.os, "write", d.write)
    return d


def ev(i: int) -> dict[str, object]:
    return {"t": 1700000000.0 + i, "event": "trip", "node": f"Node{i}", "source": "axis0",
            "value": 30.0 + i, "threshold": 30.0, "reason": "overcurrent " + "x" * (i % 7)}


def file_lines(path: Path) -> list[dict[str, object]]:
    """Every line of the file parsed as JSON: a torn line fails the test here."""
    text = path.read_text(encoding="utf-8")
    assert text == "" or text.endswith("\n"), f"the file ends in the middle of a line: {text[-80:]!r}"
    return [json.loads(line) for line in text.splitlines()]


def stderr_events(err: str) -> list[dict[str, object]]:
    return [json.loads(line.removeprefix("canguard-event ")) for line in err.splitlines()
            if line.startswith("canguard-event ")]


class TestShortWrite:
    """The disk fills up in the middle of a line."""

    def test_a_cut_line_is_taken_back_and_written_whole_later(self, tmp_path: Path, disk: Disk) -> None:
        """Budget for 2.5 lines: the file holds 2 whole lines; freed, all 6 follow in order, once."""
        path = tmp_path / "events.jsonl"
        journal = EventJournal(path)
        one = len(events_mod.encode_event(ev(0)))
        disk.free = int(one * 2.5)
        for i in range(4):
            journal.write(ev(i))
        assert [e["node"] for e in file_lines(path)] == ["Node0", "Node1"]
        disk.free = None
        journal.write(ev(4))
        journal.write(ev(5))
        journal.close()
        assert [e["node"] for e in file_lines(path)] == [f"Node{i}" for i in range(6)]

    def test_write_error_after_some_bytes_is_cut_back(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """A write that puts bytes out and then raises (EIO) leaves no fragment either."""
        path = tmp_path / "events.jsonl"
        journal = EventJournal(path)
        journal.write(ev(0))
        real = os.write

        def half_then_fail(fd: int, data: bytes | memoryview) -> int:
            real(fd, bytes(data)[:10])
            raise OSError(errno.EIO, "I/O error")

        monkeypatch.setattr(events_mod.os, "write", half_then_fail)
        journal.write(ev(1))
        assert [e["node"] for e in file_lines(path)] == ["Node0"]
        monkeypatch.setattr(events_mod.os, "write", real)
        journal.write(ev(2))
        assert [e["node"] for e in file_lines(path)] == ["Node0", "Node1", "Node2"]
        journal.close()


class TestNothingLostWithoutAWord:
    """Lines the file never takes go to stderr, whole, and are counted."""

    def test_close_on_a_full_disk_sends_the_rest_to_stderr(self, tmp_path: Path, disk: Disk,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
        """10 events, room for 3: 3 in the file, 7 on stderr with the count; each event exactly once."""
        path = tmp_path / "events.jsonl"
        journal = EventJournal(path)
        disk.free = sum(len(events_mod.encode_event(ev(i))) for i in range(3)) + 5
        for i in range(10):
            journal.write(ev(i))
        journal.close()
        err = capsys.readouterr().err
        on_disk = [e["node"] for e in file_lines(path)]
        on_stderr = [e["node"] for e in stderr_events(err)]
        assert on_disk == ["Node0", "Node1", "Node2"]
        assert on_stderr == [f"Node{i}" for i in range(3, 10)]
        assert "7 line(s) not written to the file" in err

    def test_backlog_overflow_goes_to_stderr_oldest_first(self, tmp_path: Path, disk: Disk,
                                                          monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
        """A backlog of 5 on a full disk: the 3 oldest of 8 go to stderr at once, the 5 newest at close."""
        monkeypatch.setattr(events_mod, "_PENDING_MAX", 5)
        path = tmp_path / "events.jsonl"
        journal = EventJournal(path)
        disk.free = 0
        for i in range(8):
            journal.write(ev(i))
        early = stderr_events(capsys.readouterr().err)
        assert [e["node"] for e in early] == ["Node0", "Node1", "Node2"]
        journal.close()
        late = stderr_events(capsys.readouterr().err)
        assert [e["node"] for e in late] == [f"Node{i}" for i in range(3, 8)]
        assert file_lines(path) == []


@pytest.fixture
def tiny_fs(tmp_path: Path) -> Iterator[Path]:
    """A real 64 KiB tmpfs (root only; skipped where mount is not allowed)."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    mnt = tmp_path / f"tiny-{uuid.uuid4().hex[:8]}"
    mnt.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.decode().strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_real_full_tmpfs_keeps_every_line_whole(tiny_fs: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The reproduction of the report: a 64 KiB tmpfs fills up; every line on disk parses, none is missing."""
    path = tiny_fs / "events.jsonl"
    journal = EventJournal(path)
    n = 600  # ~ 150 bytes each: about 90 KB, more than the file system holds
    for i in range(n):
        journal.write(ev(i))
    journal.close()
    on_disk = [e["node"] for e in file_lines(path)]
    on_stderr = [e["node"] for e in stderr_events(capsys.readouterr().err)]
    assert 0 < len(on_disk) < n
    assert on_disk + on_stderr == [f"Node{i}" for i in range(n)]
