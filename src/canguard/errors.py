"""The one exception tree of canguard.

::

    CanguardError
     +-- ConfigError (ValueError)      YAML config: file, key path, what was found and expected
     +-- DbcError (ValueError)         a DBC file that does not load
     +-- TreeError (ValueError)        BehaviorTree.CPP XML: file, line, node, port
     +-- LogFormatError (ValueError)   a recorded log line that does not parse: file:line and text
     +-- BusError (OSError)            a bus that does not open or went away
     +-- StateFileError (OSError)      an I²t state file that cannot be read or written

Every error also inherits the matching built-in, so callers that only know
Python's own exceptions still catch them.
"""

from __future__ import annotations

from collections.abc import Iterable


class CanguardError(Exception):
    """Base class of every error canguard raises on purpose."""


class ConfigError(CanguardError, ValueError):
    """One or more problems in a YAML config file.

    ``problems`` holds every problem found (several errors in one file are all
    reported, not only the first); ``str()`` joins them one per line.
    """

    def __init__(self, problems: str | Iterable[str]) -> None:
        self.problems: list[str] = [problems] if isinstance(problems, str) else list(problems)
        super().__init__("\n".join(self.problems))


class DbcError(CanguardError, ValueError):
    """A DBC file that is missing or does not parse."""


class TreeError(CanguardError, ValueError):
    """A behaviour tree that does not load: names the file, line, node and port at fault."""


class LogFormatError(CanguardError, ValueError):
    """A line of a recorded CAN log that does not parse (names file:line and the text)."""


class BusError(CanguardError, OSError):
    """A CAN bus that cannot be opened or that went away."""


class StateFileError(CanguardError, OSError):
    """An I²t state file that cannot be read or written."""
