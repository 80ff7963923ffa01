"""Read recorded CAN logs as streams of :class:`~canguard.io.block.Block` s (or frames).

The reader is chosen by file suffix (:data:`LOG_READERS`); memory stays flat in the log's length."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from canguard.errors import LogFormatError
from canguard.io.bagopts import BAG_SUFFIXES, NEEDS, BagOptions, is_bag
from canguard.io.candump import candump_blocks
from canguard.io.logtypes import COMPRESSIONS, Blocks, LogFrames, ReadStats
from canguard.io.pycan import python_can_blocks

LOG_READERS: dict[str, str] = {
    **dict.fromkeys((".log", ".candump", ".txt"), "candump"),
    **{f".{name}": name for name in ("asc", "blf", "trc", "csv", "mf4")},
    **dict.fromkeys(BAG_SUFFIXES, "rosbag"),
}
"""The log formats keyed by file suffix (as python-can's ``MESSAGE_READERS``): a format is one entry."""

LOG_SUFFIXES = tuple(LOG_READERS)
"""Every suffix :func:`read_log` reads (each may carry a compression on top: :data:`COMPRESSIONS`)."""

_NEEDS = {"mf4": ("asammdf", "pip install 'python-can[mf4]'"), "rosbag": NEEDS,
          "zst": ("zstandard", "pip install zstandard")}
"""Formats and compressions that need an optional dependency: (module, how to install it)."""


def log_format(path: str | Path) -> tuple[str, str]:
    """``(format, compression)`` of a log path by its suffix; :class:`LogFormatError` for an unknown one."""
    path = Path(path)
    if path.is_dir() and is_bag(path):
        return "rosbag", ""
    suffix = path.suffix.lower()
    compression = ""
    if suffix in COMPRESSIONS:
        compression = suffix[1:]
        suffix = Path(path.stem).suffix.lower()
    found = LOG_READERS.get(suffix)
    if found is None:
        known = ", ".join(LOG_SUFFIXES)
        raise LogFormatError(f"{path}: unknown log format {(suffix or path.name)!r}: expected one of {known} "
                             f"(optionally + {' / '.join(COMPRESSIONS)})")
    return found, compression


def read_log(path: str | Path, *, skip_bad: bool = False, stats: ReadStats | None = None,
             bag: BagOptions | None = None) -> LogFrames:
    """Stream a log's frames a block at a time; path, format and dependencies checked now, every problem a
    :class:`LogFormatError` naming the file (bad lines counted in ``stats`` with ``skip_bad``; ``bag``: ROS bags)."""
    p = Path(path)
    fmt, gz = log_format(p)  # gz: the compression ("" none)
    if not p.exists():
        raise LogFormatError(f"{p}: no such file")
    if not p.is_file() and fmt != "rosbag":
        raise LogFormatError(f"{p}: not a regular file")
    if fmt == "rosbag" and gz:
        raise LogFormatError(f"{p}: a bag compressed as a whole (.{gz}) is not read: decompress it first (rosbag2 and "
                             "ROS 1 compress inside the bag)")
    for what, needs in (("ROS bags" if fmt == "rosbag" else f".{fmt} logs", _NEEDS.get(fmt)),
                        (f".{gz} logs", _NEEDS.get(gz))):
        if needs is not None and importlib.util.find_spec(needs[0]) is None:
            raise LogFormatError(f"{p}: reading {what} needs {needs[0]}: {needs[1]}")
    st = stats if stats is not None else ReadStats()
    try:
        size = sum(f.stat().st_size for f in p.iterdir()) if p.is_dir() else p.stat().st_size
    except OSError as exc:
        raise LogFormatError(f"{p}: cannot read: {exc.strerror or exc}") from None
    st.bytes_total += size

    def read() -> Blocks:
        if fmt == "candump":
            return candump_blocks(p, gz, skip_bad, st)
        if fmt == "rosbag":
            from canguard.io.rosbag import bag_blocks  # numpy and rosbags: imported for bags only

            return bag_blocks(p, bag or BagOptions(), st, skip_bad)
        return python_can_blocks(p, fmt, gz, size)

    return LogFrames(p, st, read)
