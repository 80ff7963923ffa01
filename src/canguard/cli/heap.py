"""A replay on a Dask worker keeps the memory it frees until the replay ends, then gives it back.

Dask's nanny sets ``MALLOC_TRIM_THRESHOLD_``, which turns glibc's adaptive thresholds off: every
large buffer a replay makes and frees block after block is then a fresh ``mmap`` and a trim (12-30 %
more CPU). :func:`keep_freed_memory` raises the trim and mmap thresholds while replays run and puts
the environment's back (and trims once) when the last ends; it does nothing without that variable
or without glibc's ``mallopt``.
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
