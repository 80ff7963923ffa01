"""What tells a ROS bag and what a replay asks of one (apart from :mod:`canguard.io.rosbag`: nothing heavy)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

BAG_SUFFIXES = (".bag", ".db3", ".mcap")
"""Files read as bags (a rosbag2 directory is one too: it holds ``metadata.yaml``)."""
STAMPS = ("header", "record")
"""``--stamp``: each frame's ``header.stamp`` (the record time where it is zero), or the record time."""
NEEDS = ("rosbags", "pip install 'canguard[rosbags]'")
"""The optional dependency bags need, and how to install it."""


@dataclass(frozen=True)
class BagOptions:
    """What a replay asks of a bag: the ``--topic`` s (empty: every CAN frame topic) and the ``--stamp``."""

    topics: tuple[str, ...] = ()
    stamp: str = "header"


def is_bag(path: Path) -> bool:
    """True for a rosbag2 directory (it holds ``metadata.yaml``) or a file of a bag's suffix."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.suffix.lower() in BAG_SUFFIXES


def emits_bag(path: Path) -> bool:
    """``--emit`` writes a bag to ``path`` (``.mcap``, or a directory: no suffix), not candump text."""
    return path.suffix.lower() == ".mcap" or not path.suffix
