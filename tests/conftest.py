"""Fixtures shared by every test: py_trees' blackboard is global, so it is cleared around each test."""

from __future__ import annotations

import os
import signal
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

# A shell without job control starts `cmd &` with SIGINT ignored, and every child inherits that: a
# Python child then never installs its KeyboardInterrupt handler, so can.logger, stopped with SIGINT to
# write out its file, would never stop. Children of the tests get the default disposition back.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

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


@pytest.fixture(scope="session")
def installed_canguard(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The ``canguard`` of this checkout's wheel, installed into a fresh venv outside the checkout.

    Built once per test run (``scripts/install_wheel.sh``): pytest-xdist workers share the
    session's base directory and take turns under a lock, so the first one builds and the
    others use it. Needs the package index (or pip's cache) for the dependencies, as
    ``scripts/test.sh`` does.
    """
    import fcntl
    import subprocess
    import sys

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the run's directory, shared by its workers (each has its own basetemp below it)
    work = root / "installed-wheel"
    exe = work / "venv" / "bin" / "canguard"
    with open(root / "installed-wheel.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not exe.exists():
            argv = ["bash", str(REPO / "scripts" / "install_wheel.sh"), str(work)]
            proc = subprocess.run(argv, capture_output=True, text=True, timeout=600, cwd=root,
                                  env={**os.environ, "PYTHON": sys.executable})
            if proc.returncode != 0:
                pytest.fail(f"{' '.join(argv)}: exit {proc.returncode}\n{proc.stdout[-2000:]}{proc.stderr[-3000:]}")
    return exe


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Under pytest-xdist (scripts/test.sh), the slow tests come first: they mostly wait on subprocesses and
    the clock (the soak, the installed wheel, the live daemon), so one worker waits on them while the others
    run the rest, rather than all waiting at the end. Every worker sorts alike (a stable sort)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        items.sort(key=lambda item: item.get_closest_marker("slow") is None)
