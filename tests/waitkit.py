"""Waiting in tests: on a condition, with a generous bound, never for a fixed time.

A test that sleeps for "long enough" is slow where the machine is fast and flaky
where it is busy (the suite runs on several workers at once); a test that waits
for what it needs goes on the moment it holds and fails, naming it, only when it
never comes.
"""

from __future__ import annotations

import sys
import threading
import time
import traceback
from collections.abc import Callable
from typing import TypeVar

import can
import pytest

T = TypeVar("T")

WAIT_S = 20.0
"""Upper bound for anything a test waits for (a loaded CI machine is slow, never this slow)."""

POLL_S = 0.01
"""How often a condition is looked at again."""


def wait_until(predicate: Callable[[], T], timeout: float = WAIT_S, *, what: str = "") -> T:
    """Poll ``predicate`` until it returns something truthy, and return that; fail naming ``what`` after ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout} s waiting for {what or getattr(predicate, '__qualname__', '?')}")
        time.sleep(POLL_S)


def receive_until(bus: can.BusABC, pred: Callable[[can.Message], bool], what: str,
                  timeout: float = WAIT_S) -> can.Message:
    """Receive on ``bus`` until a frame matches ``pred`` and return it; fail naming ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = bus.recv(0.1)
        if msg is not None and pred(msg):
            return msg
    pytest.fail(f"no {what} received within {timeout} s")



def join_or_stacks(thread: threading.Thread, timeout: float = WAIT_S) -> str:
    """Join ``thread``: "" once it ended, else (still alive after ``timeout``) every thread's stack, for the failure
    to tell where it hangs, not only that it did. The caller cleans up first, then asserts on it."""
    thread.join(timeout)
    if not thread.is_alive():
        return ""
    names = {t.ident: t.name for t in threading.enumerate()}
    return f"still running after {timeout} s; every thread's stack:\n" + "".join(
        f"--- {names.get(ident, ident)}\n" + "".join(traceback.format_stack(frame))
        for ident, frame in sys._current_frames().items())
