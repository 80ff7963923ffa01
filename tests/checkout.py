"""Where the checkout is, for every test: the tests never depend on the current directory."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
"""The repository root."""

SRC = REPO / "src"
"""The package's source root (``PYTHONPATH`` of the canguard processes the tests start)."""
