"""The installed product, not the checkout: scripts/wheel_smoke.sh.

On the wheel built and installed into a fresh venv outside the checkout (the ``installed_canguard``
fixture: scripts/install_wheel.sh, as the smoke script does on its own), runs
from there, ``--version``, ``check``, ``tree``, ``demo --duration 6`` without a terminal (to its summary:
the spike at 4 s trips PackCurrent and the stop frames go out),
``simulate --scenario overload --duration 5 --out x.log``, ``replay x.log`` (exit 0
and, with ``--fail-on-trip``, 1), ``init`` + ``check -c`` and ``unit``, from a temporary directory.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from checkout import REPO


@pytest.mark.slow
def test_installed_wheel_from_another_directory(tmp_path: Path, installed_canguard: Path) -> None:
    """Every step of the smoke script exits as documented."""
    proc = subprocess.run(["bash", str(REPO / "scripts" / "wheel_smoke.sh")], capture_output=True, text=True,
                          timeout=240, cwd=tmp_path, env={"PATH": "/usr/bin:/bin", "PYTHON": sys.executable,
                                                         "HOME": str(Path.home()),
                                                         "CANGUARD_VENV": str(installed_canguard.parents[1])})
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("wheel smoke: ok")
