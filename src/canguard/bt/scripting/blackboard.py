"""What a script needs from a blackboard."""

from __future__ import annotations

from typing import Protocol


class ScriptBlackboard(Protocol):
    """The blackboard a script reads and writes; an entry may exist without a value (a typed port's)."""

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

