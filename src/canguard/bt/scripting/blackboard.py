"""What a script needs from a blackboard, and a plain dict-backed one."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol


class ScriptBlackboard(Protocol):
    """The blackboard a script reads and writes.

    An entry can exist without a value (a port declared with a type, not written
    yet): ``has`` is then true and ``get`` raises KeyError.
    """

    def has(self, key: str) -> bool:
        """Whether the entry exists (with or without a value)."""
        ...

    def get(self, key: str) -> object:
        """The entry's value; KeyError when the entry does not exist or holds no value."""
        ...

    def set(self, key: str, value: object) -> None:
        """Create or overwrite the entry's value."""
        ...

    def declared_type(self, key: str) -> type | None:
        """The type the entry was declared with (a typed port), or None: any type."""
        ...


class DictBlackboard:
    """A blackboard over a dict of values and a dict of declared types.

    ``DictBlackboard({"x": 3}, types={"speed": float})``: ``x`` holds 3; ``speed``
    exists, is declared as a real and holds nothing yet.
    """

    def __init__(self, values: Mapping[str, object] | None = None, types: Mapping[str, type] | None = None) -> None:
        self.values: dict[str, object] = dict(values or {})
        self.types: dict[str, type] = dict(types or {})

    def has(self, key: str) -> bool:
        return key in self.values or key in self.types

    def get(self, key: str) -> object:
        return self.values[key]

    def set(self, key: str, value: object) -> None:
        self.values[key] = value

    def declared_type(self, key: str) -> type | None:
        return self.types.get(key)
