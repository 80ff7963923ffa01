"""Submodules of our dependencies that ``canguard`` commands never use, loaded on first use instead of at import.

``import cantools`` imports ``cantools.tester`` and with it python-can whole; ``py_trees`` imports pydot.
Only the process entry point defers, never a library import. (The stdlib's ``LazyLoader`` is not thread-safe
before Python 3.12.)
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
import threading

UNUSED = ("cantools.tester", "cantools.logreader", "py_trees.display", "py_trees.demos", "py_trees.programs")
"""The submodules :func:`defer_unused` defers: none is read on a replay, check or daemon run."""


def defer(name: str) -> bool:
    """Load the submodule ``name`` only when one of its attributes is first read; False: it cannot be deferred."""
    package = name.rpartition(".")[0]
    if not package or package in sys.modules or name in sys.modules:
        return False
    try:
        parent = importlib.util.find_spec(package)  # finds the package without importing it
    except (ImportError, ValueError):
        return False
    if parent is None or not parent.submodule_search_locations:
        return False
    # as the import system finds it (a package: its submodules import as usual once it runs)
    spec = importlib.machinery.PathFinder.find_spec(name, parent.submodule_search_locations)
    if spec is None or spec.loader is None:
        return False
    module = importlib.util.module_from_spec(spec)
    loader = spec.loader
    lock = threading.RLock()  # another thread's first use waits for the module's code to have run
    running: list[bool] = []

    def __getattr__(attr: str) -> object:
        space = module.__dict__
        with lock:
            if space.get("__getattr__") is __getattr__ and not running:  # else: loaded, or loading in this thread
                running.append(True)
                try:
                    loader.exec_module(module)  # a failure propagates; the next use tries again
                finally:
                    running.clear()
                if space.get("__getattr__") is __getattr__:  # a module's own __getattr__, if it has one, stays
                    del space["__getattr__"]
        if attr in space:
            return space[attr]
        own = space.get("__getattr__")
        if own is not None and own is not __getattr__:
            return own(attr)
        raise AttributeError(f"module {name!r} has no attribute {attr!r}")

    module.__dict__["__getattr__"] = __getattr__
    sys.modules[name] = module
    return True


def defer_unused() -> None:
    """:func:`defer` every module of :data:`UNUSED`."""
    for name in UNUSED:
        defer(name)
