"""Fixtures shared by every test: py_trees' blackboard is global, so it is cleared around each test."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import py_trees
import pytest

REPO = Path(__file__).resolve().parents[1]


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
