"""The event journal: guard transitions, stops, stale sources... as JSON lines.

A line is whole and survives a crash of the daemon once :meth:`EventJournal.write` returns (one ``os.write``
on an ``O_APPEND`` descriptor). A power cut loses at most the last ``SYNC_INTERVAL_S``: with
``sync_in_background`` (the daemon) a thread of its own ``fsync``s, ``SYNC_INTERVAL_S`` after the first flush
since its last one, so the loop never waits for a disk (on a VM or an SD card one ``fsync`` can stall the
machine for milliseconds) and no ``fsync`` starts while a stop's frames travel. Rotation never deletes a
file (the highest number is the oldest).
"""

from __future__ import annotations

import errno
import logging
import os
import sys
import threading
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from canguard.engine.event_codec import encode_event

log = logging.getLogger(__name__)

DEFAULT_MAX_BYTES = 16 * 1024 * 1024

SYNC_INTERVAL_S = 0.2
"""A background-syncing journal's time from a flush to its ``fsync``: how long a flushed line may lag on disk."""

_PENDING_MAX = 10_000
"""Lines kept in memory while the disk refuses them (full, read-only); older ones are dropped then."""


class EventJournal:
    """Appends events to a JSON-lines file, rotated at ``max_bytes`` (every rotated file is kept).

    ``path`` None writes nothing. Thread-safe (receive threads report ``bus_error``). Disk errors never raise out
    of :meth:`write` or :meth:`flush`, so a full disk cannot stop the guard: the lines wait in memory for the
    next call that succeeds (whole or not at all); the backlog's overflow and lines left at :meth:`close` go
    to stderr (the systemd journal).
    """

    def __init__(
        self,
        path: Path | str | None,
        max_bytes: int = DEFAULT_MAX_BYTES,
        *,
        sync_in_background: bool = False,
    ) -> None:
        if max_bytes <= 0:
            raise ValueError(f"max_bytes must be > 0, got {max_bytes}")
        self.path: Path | None = None if path is None else Path(path)
        self.max_bytes = int(max_bytes)
        self._fd: int | None = None
        self._size = 0
        self._dirty = False
        self._closed = False
        self._pending: deque[bytes] = deque()
        self._torn = False
        self._torn_at = 0
        self._failing = False
        self._lock = threading.Lock()
        if self.path is not None:
            self._open()
        self._sync_due = threading.Event()
        self._sync_stop = threading.Event()
        self._syncer: threading.Thread | None = None
        if sync_in_background and self.path is not None:
            self._syncer = threading.Thread(target=self._sync_loop, name="canguard-journal-fsync", daemon=True)
            self._syncer.start()

    # -- file handling -------------------------------------------------------------

    def _open(self) -> None:
        """Open (create) the file for appending; never truncates."""
        assert self.path is not None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        existed = self.path.exists()
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC, 0o640)
        self._fd = fd
        self._size = os.fstat(fd).st_size
        if not existed:
            self._fsync_dir()

    def _fsync_dir(self) -> None:
        """Make a created or renamed file's directory entry durable."""
        assert self.path is not None
        try:
            dfd = os.open(self.path.parent, os.O_RDONLY | os.O_DIRECTORY)
        except OSError:
            return
        try:
            os.fsync(dfd)
        except OSError:
            pass  # some file systems refuse fsync on directories; the data itself is synced
        finally:
            os.close(dfd)

    def _backup(self, n: int) -> Path:
        assert self.path is not None
        return self.path.with_name(f"{self.path.name}.{n}")

    def _rotate(self) -> None:
        """Rename the full file to ``.1`` after shifting older backups up; open a fresh one."""
        assert self.path is not None and self._fd is not None
        os.fsync(self._fd)
        os.close(self._fd)
        self._fd = None
        self._dirty = False
        n = 1
        while self._backup(n).exists():
            n += 1
        # n is the first free number: shift n-1 -> n, ..., 1 -> 2, from the top down, so a
        # crash half-way leaves a gap in the numbers but never overwrites a file.
        for i in range(n - 1, 0, -1):
            os.replace(self._backup(i), self._backup(i + 1))
        os.replace(self.path, self._backup(1))
        self._fsync_dir()
        self._open()

    def _drain(self) -> None:
        """Write every pending line; raises OSError if the disk fails. A line written in part (a full disk) is cut
        back with ``ftruncate`` and stays first in the queue: a later retry writes it whole."""
        while self._pending:
            line = self._pending[0]
            if self._fd is None:
                self._open()
            if self._torn:
                self._cut_torn()
            if self._size > 0 and self._size + len(line) > self.max_bytes:
                self._rotate()
            assert self._fd is not None
            start = self._size
            try:
                n = os.write(self._fd, line)
            except OSError:
                self._size = os.fstat(self._fd).st_size if self._fd_ok() else start
                if self._size != start:  # some bytes went out before the error
                    self._cut_torn(start)
                raise
            if n != len(line):
                self._cut_torn(start)
                raise OSError(errno.ENOSPC, f"{os.strerror(errno.ENOSPC)} (a short write: {n} of {len(line)} "
                                            "bytes; the partial line was cut back)")
            self._size += n
            self._dirty = True
            self._pending.popleft()

    def _cut_torn(self, at: int | None = None) -> None:
        """Remove the part of a line a short write left at the end of the file (``ftruncate`` to ``at``, the line's
        start; None: where a cut that failed was to go)."""
        if at is not None:
            self._torn_at, self._torn = at, True
        assert self._fd is not None
        os.ftruncate(self._fd, self._torn_at)
        self._size = self._torn_at
        self._torn = False

    def _failed(self, exc: OSError, what: str) -> None:
        """A disk error: logged (only the first of a run at WARNING); the lines wait in memory."""
        level = logging.DEBUG if self._failing else logging.WARNING
        log.log(level, "event journal %s: %s failed: %s (lines kept in memory)", self.path, what, exc)
        self._failing = True
        # A failed write may have left a half-open descriptor (e.g. during rotation); reopen later.
        if self._fd is not None and not self._fd_ok():
            self._fd = None

    def _fd_ok(self) -> bool:
        try:
            os.fstat(self._fd)  # type: ignore[arg-type]
        except OSError:
            return False
        return True

    # -- public API ------------------------------------------------------------------

    def write(self, event: Mapping[str, Any]) -> None:
        """Append one event as a JSON line, handed to the OS before returning; ValueError for an event without an
        ``event`` key or a closed journal (disk errors are logged and retried, not raised)."""
        line = encode_event(event)
        with self._lock:
            if self._closed:
                raise ValueError("write to a closed EventJournal")
            if self.path is None:
                return
            self._pending.append(line)
            if len(self._pending) > _PENDING_MAX:
                # The backlog is full: the oldest line leaves memory for stderr (the systemd journal).
                self._spill([self._pending.popleft()], "the in-memory backlog is full")
            try:
                self._drain()
            except OSError as exc:
                self._failed(exc, "write")
                return
            if self._failing:
                log.warning("event journal %s: writing again", self.path)
                self._failing = False

    def flush(self) -> None:
        """Make every line written so far durable (``os.fsync``); cheap when nothing is new."""
        with self._lock:
            if self.path is None or self._closed:
                return
            try:
                self._drain()
                if self._dirty and self._fd is not None:
                    if self._syncer is not None:
                        self._sync_due.set()  # the sync thread waits for the disk, the caller does not
                        return
                    os.fsync(self._fd)
                    self._dirty = False
            except OSError as exc:
                self._failed(exc, "fsync")

    def _sync_loop(self) -> None:
        """The sync thread: ``fsync`` a duplicate descriptor outside the lock ``SYNC_INTERVAL_S`` after the first flush
        since the last one; never at once, so a stop's tick does not stall the disk while its frames travel. Ends
        once :meth:`close` asked, at the latest after the ``fsync`` under way: a close between the interval's end and
        the ``clear`` below sets the flag that ``clear`` then drops, so the wait must not be the only way out."""
        while not self._sync_stop.is_set():
            self._sync_due.wait()
            if self._sync_stop.wait(SYNC_INTERVAL_S):
                return  # close() syncs what is left itself
            self._sync_due.clear()  # a flush from here on asks for the next fsync
            with self._lock:
                if not self._dirty or self._fd is None:
                    continue
                try:
                    fd = os.dup(self._fd)  # rotation may close the journal's own descriptor meanwhile
                except OSError as exc:
                    self._failed(exc, "fsync")
                    continue
                self._dirty = False
            try:
                os.fsync(fd)
            except OSError as exc:
                with self._lock:
                    self._dirty = True
                    self._failed(exc, "fsync")
            finally:
                os.close(fd)

    def close(self) -> None:
        """Flush, fsync and close the file; later writes raise ValueError. Idempotent."""
        if self._syncer is not None:  # from here on flush() syncs itself, before close returns
            self._sync_stop.set()
            self._sync_due.set()
            self._syncer.join()
            self._syncer = None
        self.flush()
        with self._lock:
            self._closed = True
            if self._fd is not None:
                try:
                    os.close(self._fd)
                finally:
                    self._fd = None
            if self._pending:
                lines = list(self._pending)
                self._pending.clear()
                self._spill(lines, "closing while the file refuses them")

    def _spill(self, lines: list[bytes], why: str) -> None:
        """Lines that cannot reach the file go to stderr (the systemd journal), whole, with their count."""
        try:
            sys.stderr.write(f"canguard: event journal {self.path}: {len(lines)} line(s) not written to the file "
                             f"({why}); here they are:\n")
            for line in lines:
                sys.stderr.write("canguard-event " + line.decode("utf-8"))
            sys.stderr.flush()
        except (OSError, ValueError):
            log.error("event journal %s: %d line(s) lost (%s; stderr refused them too)", self.path, len(lines), why)
