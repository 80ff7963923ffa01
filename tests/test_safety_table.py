"""docs/safety.md's failure-mode table is tied to tests that exist.

Every row names test ids (``tests/file.py::Class::test`` or ``tests/file.py::test``,
parametrized ones without their ``[...]``) that exist in the suite, or says
``no test:`` and why. The suite itself makes every named test pass.
"""

from __future__ import annotations

import ast
import re

from checkout import REPO

DOC = REPO / "docs" / "safety.md"
TEST_ID = re.compile(r"`(tests/[\w/]+\.py(?:::\w+)+)`")


def rows() -> list[list[str]]:
    """The table rows (cells) of every failure-mode table."""
    out = []
    for line in DOC.read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| ") and re.fullmatch(r"[FBHT]\d+", cells[0]):
            out.append(cells)
    return out


def defined(test_id: str) -> bool:
    """Whether ``path::Class::name`` (or ``path::name``) is defined in that file."""
    path, *names = test_id.split("::")
    file = REPO / path
    if not file.exists():
        return False
    scope: list[ast.stmt] = ast.parse(file.read_text(encoding="utf-8")).body
    for name in names:
        node = next((n for n in scope if isinstance(n, (ast.ClassDef, ast.FunctionDef)) and n.name == name), None)
        if node is None:
            return False
        scope = node.body if isinstance(node, ast.ClassDef) else []
    return True


def test_every_row_is_tied_to_tests_or_says_why_not() -> None:
    """Each row has test ids or an explicit 'no test:' with a reason; the ids all exist."""
    table = rows()
    assert len(table) >= 20, "the failure-mode table lost rows"
    missing = []
    for cells in table:
        ids = TEST_ID.findall(cells[-1])
        if not ids:
            assert re.search(r"no test: \w+", cells[-1]), f"row {cells[0]} names no test and says not why"
        missing += [f"{cells[0]}: {i}" for i in ids if not defined(i)]
    assert missing == []


def test_the_checker_sees_a_missing_test() -> None:
    """The check is not vacuous: a made-up id is not 'defined'."""
    assert defined("tests/test_faults.py::TestBusOff::test_bus_off_stops_and_recovery_releases")
    assert not defined("tests/test_faults.py::TestBusOff::test_that_does_not_exist")
    assert not defined("tests/no_such_file.py::test_x")


def test_gaps_are_counted_in_the_open() -> None:
    """Rows without a test are the gaps the document names: each is marked **gap** or explains itself."""
    untested = [c[0] for c in rows() if not TEST_ID.findall(c[-1])]
    gaps = [c[0] for c in rows() if "**gap**" in " ".join(c)]
    assert set(untested) <= set(gaps), f"untested rows not marked as gaps: {set(untested) - set(gaps)}"
