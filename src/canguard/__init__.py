"""canguard: a CAN-bus motor-driver monitoring daemon.

Frames in (python-can), samples out (cantools and the robot's DBC files),
protection models per sample, a BehaviorTree.CPP-format tree on py_trees to gate
the robot's task, and stop frames back onto the bus when the tree fails.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("canguard")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
