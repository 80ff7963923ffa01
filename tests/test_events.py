"""The event journal: one deterministic JSON line per event, appended, rotated, crash-safe."""

from __future__ import annotations

import errno
import json
import math
import os
import signal
import subprocess
import sys
import textwrap
from contextlib import closing
from pathlib import Path
from typing import Any

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from canguard.engine import events as events_mod
from canguard.engine.event_codec import FIRST_KEYS, encode_event
from canguard.engine.events import EventJournal
from checkout import SRC
from test_daemon import read_events

CHARS = st.characters(exclude_categories=["Cs"])
"""``st.text()``'s own alphabet (every code point but the surrogates), named by its Unicode category: found by
encoding each code point as UTF-8, it costs ~3 CPU-s in each process that draws from it first."""


def journal_files(path: Path) -> list[Path]:
    """The journal's files oldest first: ``path.N`` ... ``path.1``, then ``path`` (as a reader must take them)."""
    numbered = sorted((int(p.suffix[1:]), p) for p in path.parent.glob(f"{path.name}.*") if p.suffix[1:].isdigit())
    return [p for _n, p in reversed(numbered)] + ([path] if path.exists() else [])


def rotated_events(path: Path) -> list[dict[str, Any]]:
    """Every event of the journal and of its rotated files, oldest first."""
    return [event for file in journal_files(path) for event in read_events(file)]


def _trip(i: int) -> dict[str, Any]:
    return {
        "t": 1_700_000_000.0 + i * 0.001,
        "event": "trip",
        "node": "MotorCurrent",
        "source": "left_drive",
        "value": 30.0 + i,
        "threshold": 30.0,
        "reason": "overcurrent",
    }


class TestEncodeEvent:
    """encode_event: the exact bytes of one journal line."""

    def test_first_keys_in_fixed_order_then_rest_sorted(self) -> None:
        """The seven standard keys come first in a fixed order, missing ones as null, extras sorted after."""
        line = encode_event({"zeta": 1, "event": "start", "alpha": "x", "t": 1.5})
        assert line == (
            b'{"t":1.5,"event":"start","node":null,"source":null,"value":null,'
            b'"threshold":null,"reason":null,"alpha":"x","zeta":1}\n'
        )

    def test_nan_and_inf_stay_valid_json(self) -> None:
        """NaN and infinities are null in number fields, their text beside them; the line is strict JSON."""
        line = encode_event({"event": "trip", "value": math.nan, "threshold": math.inf, "x": -math.inf})
        obj = json.loads(line, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))
        assert (obj["value"], obj["threshold"], obj["x"]) == (None, None, None)
        assert (obj["value_text"], obj["threshold_text"], obj["x_text"]) == ("nan", "inf", "-inf")

    def test_floats_are_rounded(self) -> None:
        """Time is kept to the microsecond and values to 10 significant digits."""
        obj = json.loads(encode_event({"event": "trip", "t": 1700000000.1234567891, "value": 0.1 + 0.2}))
        assert obj["t"] == 1700000000.123457
        assert obj["value"] == 0.3

    def test_nested_and_odd_values_are_deterministic(self) -> None:
        """Nested dicts get sorted keys, bytes become hex and paths their text."""
        line = encode_event(
            {"event": "reload", "detail": {"b": 2, "a": 1}, "data": b"\x01\xff", "p": Path("/x")}
        )
        assert b'"data":"01ff","detail":{"a":1,"b":2},"p":"/x"' in line

    def test_event_key_is_required(self) -> None:
        """An event without its 'event' name is refused with a message naming the key."""
        with pytest.raises(ValueError, match="'event'"):
            encode_event({"t": 1.0})

    # The corners first, every run (non-finite numbers in a first key and in another, a float whose
    # rounding overflows, the time key, line breaks in keys and text), then random events around them.
    @example({"value": math.nan, "threshold": math.inf, "peak": -math.inf, "big": 1.7976931348623157e308,
              "t": 0.1 + 0.2, "a\nb": "x\ny\u2028z", "event": None, "n": 2**70, "ok": True, "none": None})
    @example({})
    @settings(max_examples=40, deadline=None)
    @given(
        st.dictionaries(
            st.text(CHARS, max_size=8),
            st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(CHARS, max_size=20)),
            max_size=8,
        )
    )
    def test_any_event_is_one_strict_json_line(self, extra: dict[str, Any]) -> None:
        """Whatever the fields hold, the event is exactly one line of strict JSON."""
        line = encode_event({**extra, "event": "stale"})
        assert line.endswith(b"\n") and line.count(b"\n") == 1
        obj = json.loads(line, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))
        assert obj["event"] == "stale"
        assert list(obj)[:7] == list(FIRST_KEYS)


class TestEventJournal:
    """EventJournal: appending, durability, rotation, errors."""

    def test_lines_read_back_in_order(self, tmp_path: Path) -> None:
        """Events written come back from read_events in the same order with the same fields."""
        path = tmp_path / "events.jsonl"
        with closing(EventJournal(path)) as j:
            for i in range(3):
                j.write(_trip(i))
        got = read_events(path)
        assert [e["value"] for e in got] == [30.0, 31.0, 32.0]
        assert got[0]["reason"] == "overcurrent"

    def test_opening_appends_never_truncates(self, tmp_path: Path) -> None:
        """A daemon restart keeps the previous run's events and appends after them."""
        path = tmp_path / "events.jsonl"
        with closing(EventJournal(path)) as j:
            j.write({"event": "start", "t": 1.0})
        with closing(EventJournal(path)) as j:
            j.write({"event": "start", "t": 2.0})
        assert [e["t"] for e in read_events(path)] == [1.0, 2.0]

    def test_same_events_give_byte_identical_files(self, tmp_path: Path) -> None:
        """Two runs writing the same events produce byte-identical files."""
        evs = [_trip(i) for i in range(50)] + [{"event": "stop", "t": 5.0, "node": "Guard", "frames": 2}]
        for name in ("a", "b"):
            with closing(EventJournal(tmp_path / name)) as j:
                for e in evs:
                    j.write(dict(reversed(list(e.items()))))  # insertion order must not matter
        assert (tmp_path / "a").read_bytes() == (tmp_path / "b").read_bytes()

    def test_write_reaches_the_file_before_flush(self, tmp_path: Path) -> None:
        """A written line is visible in the file at once, without flush or close."""
        path = tmp_path / "events.jsonl"
        j = EventJournal(path)
        j.write({"event": "start", "t": 1.0})
        assert path.read_bytes().count(b"\n") == 1
        j.close()

    def test_flush_fsyncs_only_when_something_is_new(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        """flush() fsyncs the file after writes and does nothing when there is nothing new."""
        j = EventJournal(tmp_path / "events.jsonl")
        calls: list[int] = []
        real_fsync = os.fsync
        monkeypatch.setattr(events_mod.os, "fsync", lambda fd: (calls.append(fd), real_fsync(fd))[1])
        j.write({"event": "start", "t": 1.0})
        j.flush()
        j.flush()
        assert len(calls) == 1
        j.close()

    def test_kill_9_leaves_whole_lines_and_every_flushed_one(self, tmp_path: Path) -> None:
        """A daemon's journal killed by SIGKILL while it writes holds only whole lines, every line flushed before
        the kill among them, in order."""
        path = tmp_path / "events.jsonl"
        code = textwrap.dedent(
            f"""
            import itertools
            from canguard.engine.events import EventJournal
            from canguard.engine.stats import Journal
            sink = EventJournal({str(path)!r}, max_bytes=64 * 1024, sync_in_background=True)
            journal = Journal(lambda: 0.0, sink)
            for i in itertools.count():  # until the SIGKILL
                journal.write({{"event": "trip", "node": "N", "value": i, "reason": "x" * (i % 300)}})
                if i % 3 == 2:
                    journal.flush()
                    print(i, flush=True)
            """
        )
        env = {**os.environ, "PYTHONPATH": str(SRC)}
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, env=env, text=True)
        try:
            assert proc.stdout is not None
            while int(proc.stdout.readline() or -1) < 600:  # rotated at least once; still writing
                assert proc.poll() is None, "the writer ended before the kill"
            proc.send_signal(signal.SIGKILL)
            said = proc.stdout.read().split()
            assert proc.wait(timeout=10) == -signal.SIGKILL
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        flushed = int(said[-1]) if said else 600
        files = journal_files(path)
        assert len(files) > 1
        for file in files:
            data = file.read_bytes()
            assert not data or data.endswith(b"\n"), f"{file}: a torn last line"
        values = [e["value"] for e in rotated_events(path)]
        assert values == list(range(len(values)))
        assert len(values) > flushed

    def test_rotation_keeps_every_line(self, tmp_path: Path) -> None:
        """Rotating by size splits the journal into numbered files that together hold every line in order."""
        path = tmp_path / "events.jsonl"
        with closing(EventJournal(path, max_bytes=1000)) as j:
            for i in range(100):
                j.write(_trip(i))
        files = journal_files(path)
        assert len(files) >= 6
        assert files[-1] == path and files[-2].name == "events.jsonl.1"
        assert all(f.stat().st_size <= 1000 for f in files)
        assert [e["value"] for e in rotated_events(path)] == [30.0 + i for i in range(100)]

    def test_rotation_continues_numbering_after_restart(self, tmp_path: Path) -> None:
        """A restarted daemon rotates on top of existing backups without overwriting any of them."""
        path = tmp_path / "events.jsonl"
        for run in range(3):
            with closing(EventJournal(path, max_bytes=500)) as j:
                for i in range(20):
                    j.write(_trip(run * 20 + i))
        assert len(rotated_events(path)) == 60

    def test_line_larger_than_max_bytes_is_still_written(self, tmp_path: Path) -> None:
        """An event bigger than max_bytes gets a file of its own instead of being cut or lost."""
        path = tmp_path / "events.jsonl"
        with closing(EventJournal(path, max_bytes=50)) as j:
            j.write({"event": "start", "t": 0.0})
            j.write({"event": "error", "t": 1.0, "reason": "x" * 200})
        assert [e["event"] for e in rotated_events(path)] == ["start", "error"]

    def test_no_path_writes_nothing_and_still_checks_events(self, tmp_path: Path) -> None:
        """A journal without a path takes events and writes nothing; an event without ``event`` is still refused."""
        j = EventJournal(None)
        j.write({"event": "start"})
        with pytest.raises(ValueError, match="'event' key"):
            j.write({"reason": "no event name"})
        j.flush()
        j.close()

    def test_write_after_close_raises(self, tmp_path: Path) -> None:
        """Writing to a closed journal is a programming error and says so."""
        j = EventJournal(tmp_path / "e.jsonl")
        j.close()
        j.close()
        with pytest.raises(ValueError, match="closed"):
            j.write({"event": "exit"})

    def test_bad_arguments_are_refused(self, tmp_path: Path) -> None:
        """A non-positive max_bytes is refused at construction."""
        with pytest.raises(ValueError, match="max_bytes"):
            EventJournal(tmp_path / "e", max_bytes=0)

    def test_disk_error_is_survived_and_lines_written_later(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
    ) -> None:
        """A full disk neither raises nor tears a line: lines are written, in order, once space returns."""
        path = tmp_path / "events.jsonl"
        j = EventJournal(path)
        j.write({"event": "start", "t": 0.0})
        real_write = os.write
        state = {"calls": 0}

        def full_disk(fd: int, data: Any) -> int:
            state["calls"] += 1
            if state["calls"] == 1:
                return real_write(fd, bytes(data)[:5])  # a partial write, then the disk is full
            raise OSError(errno.ENOSPC, "No space left on device")

        monkeypatch.setattr(events_mod.os, "write", full_disk)
        j.write({"event": "trip", "t": 1.0})
        j.write({"event": "stop", "t": 2.0})
        j.flush()
        assert "No space left" in caplog.text
        monkeypatch.setattr(events_mod.os, "write", real_write)
        j.write({"event": "recover", "t": 3.0})
        j.close()
        assert [e["event"] for e in read_events(path)] == ["start", "trip", "stop", "recover"]

