"""A replay on a Dask worker keeps the memory it frees until the replay ends, then gives it back.

Dask's nanny starts each worker with ``MALLOC_TRIM_THRESHOLD_=65536`` (its
``distributed.nanny.pre-spawn-environ``) so that a worker hands freed memory back to the
kernel at once. Setting that variable also turns off glibc's adaptive thresholds: every
allocation of 128 KiB or more is then a fresh ``mmap`` and every free of the heap's top
64 KiB a trim, so a replay, which makes and frees such buffers block after block, faults the
same pages in again and again. Measured on 16 logs of 600 k frames on a LocalCluster of two
workers (``python -m benchmarks fleet``'s set-up): about 15,000 page faults per log, and 12-30 % more CPU
than the same replays in a plain process.

:func:`keep_freed_memory` raises glibc's trim and mmap thresholds for as long as a replay runs
and, when the last replay of the process ends, puts back the thresholds the environment set
and trims the heap once: the worker ends each task as lean as Dask wants it. It does nothing
where glibc's adaptive thresholds are still on (no ``MALLOC_TRIM_THRESHOLD_`` in the
environment: nothing to undo, nothing to gain) or where ``mallopt`` is not glibc's.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
"""glibc's ``mallopt`` parameters (malloc.h)."""
KEEP_BYTES = 32 << 20
"""The thresholds while a replay runs: freed blocks of up to 32 MiB stay in the heap (glibc's own adaptive
ceiling on 64-bit)."""
DEFAULT_MMAP_THRESHOLD = 128 * 1024

_lock = threading.Lock()
_running = 0
_libc: Any = None
_T = TypeVar("_T")


def _glibc() -> Any:
    """glibc through ctypes, or None (another libc, or no ``mallopt``)."""
    global _libc
    if _libc is None:
        try:
            import ctypes

            lib = ctypes.CDLL("libc.so.6")
            _libc = lib if hasattr(lib, "mallopt") and hasattr(lib, "malloc_trim") else False
        except (OSError, AttributeError):
            _libc = False
    return _libc or None


def _env_bytes(name: str, default: int) -> int:
    try:
        return int(os.environ.get(name, default))
    except ValueError:
        return default


@contextmanager
def keep_freed_memory() -> Iterator[None]:
    """Within: freed memory stays in the heap (when the environment had turned glibc's adaptive thresholds off)."""
    global _running
    libc = _glibc() if "MALLOC_TRIM_THRESHOLD_" in os.environ else None
    if libc is None:
        yield
        return
    with _lock:
        _running += 1
        if _running == 1:
            libc.mallopt(M_TRIM_THRESHOLD, KEEP_BYTES)
            libc.mallopt(M_MMAP_THRESHOLD, KEEP_BYTES)
    try:
        yield
    finally:
        with _lock:
            _running -= 1
            if _running == 0:
                libc.mallopt(M_MMAP_THRESHOLD, _env_bytes("MALLOC_MMAP_THRESHOLD_", DEFAULT_MMAP_THRESHOLD))
                libc.mallopt(M_TRIM_THRESHOLD, _env_bytes("MALLOC_TRIM_THRESHOLD_", 0))
                libc.malloc_trim(0)


def lean_after(job: Callable[[_T], Any], arg: _T) -> Any:
    """``job(arg)`` within :func:`keep_freed_memory`: what a Dask worker runs for one log."""
    with keep_freed_memory():
        return job(arg)
