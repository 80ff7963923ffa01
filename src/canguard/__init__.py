"""canguard: a CAN-bus motor-driver monitoring daemon.

Frames in (python-can), samples out (cantools and the robot's DBC files),
protection models per sample, a BehaviorTree.CPP-format tree on py_trees to gate
the robot's task, and stop frames back onto the bus when the tree fails.
"""

from __future__ import annotations

__all__ = ["__version__"]


def __getattr__(name: str) -> str:
    """``canguard.__version__``, looked up in the installed metadata when first asked for.

    Lazy: importing ``importlib.metadata`` and scanning ``sys.path`` for the distribution
    cost every ``canguard`` command ~30 ms at start-up, for a value only ``--version`` prints.
    """
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        value = version("canguard")
    except PackageNotFoundError:  # running from a source tree that was not installed
        value = "0.0.0+unknown"
    globals()["__version__"] = value
    return value
