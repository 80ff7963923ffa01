"""Files shipped inside the package: bundled config, trees, DBC, systemd units.

Resolved through importlib.resources so they are found from any working
directory after a non-editable install.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path


def data_path(*parts: str) -> Path:
    """Filesystem path of a bundled data file, e.g. data_path("dbc", "robot.dbc")."""
    return Path(str(files("canguard.data").joinpath(*parts)))
