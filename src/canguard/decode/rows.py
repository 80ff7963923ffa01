"""A message's decoded rows in a block, kept as numpy columns until a row is asked for."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    import numpy as np

Row = tuple[float, ...] | None
"""A row's values in output order, :data:`EMPTY` or None (the row goes to ``feed``)."""

EMPTY: tuple[float, ...] = ()
"""A decoded row with no configured signal in it (a multiplexer page nobody reads): counted, nothing else."""


class Verdict(NamedTuple):
    """Why one row is not a tuple of values ("": valid), and per signal on its page (output index, value, reason)."""

    reason: str
    cells: list[tuple[int, float, str]]


Why = Callable[[int], Verdict]
"""The verdict on row ``k`` of a block (computed when asked: most rows never are)."""


class OneRow(list[Row]):
    """The row of a block of one payload that is not a tuple of values (EMPTY or None), with :meth:`verdict`."""

    __slots__ = ("_why",)

    def __init__(self, row: Row, why: Why) -> None:
        super().__init__((row,))
        self._why = why

    def verdict(self, k: int) -> Verdict:
        """Why row ``k`` (0) is not a tuple of values."""
        return self._why(k)


class ColumnRows(Sequence[Row]):
    """The rows of one message in a block: ``columns[j][k]`` is output ``j`` of row ``k``; ``fed`` marks the rows
    that go to ``feed`` (None), ``empty`` the EMPTY ones (it wins over ``fed``)."""

    __slots__ = ("_rows", "_why", "columns", "empty", "fed", "n")

    def __init__(self, n: int, columns: list[np.ndarray], fed: np.ndarray | None, empty: np.ndarray | None,
                 why: Why | None = None) -> None:
        self.n = n
        self.columns = columns
        self.fed = fed if fed is not None and fed.any() else None
        self.empty = empty if empty is not None and empty.any() else None
        self._rows: list[Row] | None = None
        self._why = why

    def verdict(self, k: int) -> Verdict:
        """Why row ``k`` is what it is (reason "" for a valid row), with each value as a sample carries it."""
        assert self._why is not None, "rows built without verdicts"
        return self._why(k)

    def rows(self) -> list[Row]:
        """The rows as tuples (built once)."""
        if self._rows is None:
            import numpy as np

            found: list[Row] = list(zip(*[c.tolist() for c in self.columns], strict=True))
            if self.fed is not None:
                for k in np.flatnonzero(self.fed).tolist():
                    found[k] = None
            if self.empty is not None:
                for k in np.flatnonzero(self.empty).tolist():
                    found[k] = EMPTY
            self._rows = found
        return self._rows

    def valued(self) -> np.ndarray:
        """Which rows have their values (neither fed nor EMPTY), as a mask."""
        import numpy as np

        keep = np.ones(self.n, dtype=bool)
        for mask in (self.fed, self.empty):
            if mask is not None:
                keep &= ~mask
        return keep

    def clean(self) -> bool:
        """Every row has all its values (none to feed, none EMPTY): ``all(rows)``."""
        return self.fed is None and self.empty is None

    def count_empty(self) -> int:
        """How many rows are EMPTY."""
        return 0 if self.empty is None else int(self.empty.sum())

    def __len__(self) -> int:
        return self.n

    def __iter__(self) -> Iterator[Row]:
        return iter(self.rows())

    def __getitem__(self, k: Any) -> Any:
        return self.rows()[k]


def valued_table(rows: Sequence[Row], width: int) -> tuple[np.ndarray, np.ndarray]:
    """(which rows have their values, a ``len(rows) x width`` float64 table of them; other rows hold zeros)."""
    import numpy as np

    if type(rows) is ColumnRows:
        return rows.valued(), np.column_stack(rows.columns)
    keep = np.array([bool(row) for row in rows], dtype=bool)
    table = np.zeros((len(rows), width), dtype=np.float64)
    if keep.any():
        table[keep] = [row for row in rows if row]
    return keep, table
