"""ColumnRows answers from numpy columns what the per-row tuples would answer (canguard.decode.rows).

A block taken whole asks a message's decoded rows whether every row passed, which rows
have their values and how many rows are EMPTY. These tests build random columns and masks
and require every answer to equal the one computed from the materialised rows.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from canguard.decode.rows import EMPTY, ColumnRows, valued_table

FLOATS = st.floats(allow_nan=False, allow_infinity=False, width=64) | st.sampled_from([0.0, -0.0, 1e308, -5e-324])


@st.composite
def blocks(draw: Any) -> tuple[ColumnRows, list[Any]]:
    """A ColumnRows and the rows the row decoders built for the same values and masks."""
    n = draw(st.integers(1, 30))
    width = draw(st.integers(1, 4))
    columns = [np.array(draw(st.lists(FLOATS, min_size=n, max_size=n)), dtype=np.float64) for _ in range(width)]
    fed = np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)))
    empty = np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n))) if draw(st.booleans()) else None
    rows: list[Any] = [tuple(float(c[k]) for c in columns) for k in range(n)]
    for k in np.flatnonzero(fed).tolist():
        rows[k] = None
    if empty is not None:
        for k in np.flatnonzero(empty).tolist():
            rows[k] = EMPTY  # EMPTY wins over fed, as in the column decoder
    return ColumnRows(n, columns, fed, empty), rows


def _block(columns: list[list[float]], fed: list[bool], empty: list[bool] | None) -> tuple[ColumnRows, list[Any]]:
    """An explicit example of :func:`blocks`."""
    n = len(fed)
    rows: list[Any] = [tuple(c[k] for c in columns) for k in range(n)]
    rows = [EMPTY if empty is not None and empty[k] else None if fed[k] else rows[k] for k in range(n)]
    cols = [np.array(c, dtype=np.float64) for c in columns]
    return ColumnRows(n, cols, np.array(fed), None if empty is None else np.array(empty)), rows


# 100 random blocks, and the corners as explicit examples every run: every row valued (-0.0 and the smallest
# subnormal), one row both fed and EMPTY, no row valued.
@settings(max_examples=100, deadline=None)
@given(blocks())
@example(_block([[-0.0, 1e308, -5e-324], [2.0, -3.0, 0.0]], [False] * 3, None))
@example(_block([[1.0, 2.0, 3.0, 4.0]], [True, False, True, False], [True, False, False, True]))
@example(_block([[1.0, 2.0]], [True, False], [False, True]))
def test_answers_equal_the_rows(block: tuple[ColumnRows, list[Any]]) -> None:
    """Every answer of a ColumnRows equals the one computed from the rows it stands for."""
    found, rows = block
    assert found.rows() == rows
    assert list(found) == rows and len(found) == len(rows) and found[-1] == rows[-1]
    assert found.count(EMPTY) == rows.count(EMPTY) == found.count_empty()
    assert found.clean() == all(rows)
    assert found.valued().tolist() == [bool(row) for row in rows]  # the rows an export writes
    for kind in (found, rows):
        keep, table = valued_table(kind, len(found.columns))
        assert keep.tolist() == [bool(row) for row in rows]
        assert [tuple(r) for r in table[keep].tolist()] == [row for row in rows if row]


def test_empty_is_the_one_empty_tuple() -> None:
    """The replay tells EMPTY rows by identity (``values is EMPTY``): the materialised rows must hold it."""
    found = ColumnRows(2, [np.array([1.0, 2.0])], None, np.array([False, True]))
    assert found.rows()[1] is EMPTY
    assert found.rows()[0] == (1.0,)
