"""A replay keeps the memory it frees until it ends, then gives it back.

glibc gives freed memory back to the kernel past a trim threshold (fixed where Dask's nanny sets
``MALLOC_TRIM_THRESHOLD_``), so each block of a replay would fault its pages in again.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
"""glibc's ``mallopt`` parameters (malloc.h)."""
KEEP_BYTES = 32 << 20
"""The thresholds while a replay runs (glibc's own adaptive ceiling on 64-bit)."""
DEFAULT_THRESHOLD = 128 * 1024
"""glibc's default trim and mmap thresholds."""

_lock = threading.Lock()
_running = 0


@functools.cache
def _glibc() -> Any:
    """glibc through ctypes, or None (another libc, or no ``mallopt``)."""
    import ctypes

    try:
        lib = ctypes.CDLL("libc.so.6")
    except OSError:
        return None
    return lib if hasattr(lib, "mallopt") and hasattr(lib, "malloc_trim") else None


def _env_bytes(name: str, default: int) -> int:
    try:
        return int(os.environ.get(name, default))
    except ValueError:
        return default


@contextmanager
def keep_freed_memory() -> Iterator[None]:
    """Within: freed memory stays in the heap."""
    global _running
    libc = _glibc()
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
                libc.mallopt(M_MMAP_THRESHOLD, _env_bytes("MALLOC_MMAP_THRESHOLD_", DEFAULT_THRESHOLD))
                libc.mallopt(M_TRIM_THRESHOLD, _env_bytes("MALLOC_TRIM_THRESHOLD_", DEFAULT_THRESHOLD))
                libc.malloc_trim(0)
