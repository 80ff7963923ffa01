"""Fixtures shared by every test: py_trees' blackboard is global, so it is cleared around each test."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import py_trees
import pytest
from hypothesis import HealthCheck
from hypothesis import settings as _hypothesis_settings

from canguard.cli.common import one_blas_thread
from checkout import REPO

# As every canguard command does before numpy is imported: no BLAS thread pool, so this process is
# single-threaded where a test forks (--jobs forks only then: canguard.cli.fleet._pool_context).
one_blas_thread()

# mutmut (scripts/mutation.sh) runs test methods through its own trampoline, which hypothesis
# reports as "differing executors"; the tests themselves are unchanged by it.
_hypothesis_settings.register_profile("canguard", suppress_health_check=[HealthCheck.differing_executors])
_hypothesis_settings.load_profile("canguard")


@pytest.fixture(autouse=True)
def _clean_blackboard() -> Iterator[None]:
    """Start and end every test with an empty py_trees blackboard."""
    py_trees.blackboard.Blackboard.clear()
    yield
    py_trees.blackboard.Blackboard.clear()


@pytest.fixture
def repo() -> Path:
    """The repository root (tests never depend on the current directory)."""
    return REPO


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Under pytest-xdist (scripts/test.sh), the slow tests come first: they mostly wait on subprocesses and
    the clock (the soak, the installed wheel, the live daemon), so one worker waits on them while the others
    run the rest, rather than all waiting at the end. Every worker sorts alike (a stable sort)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        items.sort(key=lambda item: item.get_closest_marker("slow") is None)
