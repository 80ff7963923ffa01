"""The loader's state and its generic checks (mapping, string, number, seconds, path, bus name)."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from canguard.config import yamlsrc
from canguard.config.dbc import DbcChecks
from canguard.config.schema import FrameSpec, SignalRef, SourceConfig
from canguard.config.yamlsrc import _SECONDS_KEYS, _closest, _found, _line_of, _path, _shown
from canguard.errors import ConfigError

if TYPE_CHECKING:
    from canguard.config.canopen import CanopenDrive


class CanopenDrives(Protocol):
    """What the loader asks of its ``canopen:`` section (:class:`canguard.config.canopen_section.CanopenSection`)."""

    drives: dict[str, CanopenDrive]

    def load(self, value: Any) -> None: ...

    def source_refs(self, source: str, role: str, value: Mapping[str, Any], key: str
                    ) -> tuple[str, float, list[SignalRef]]: ...

    def messages(self) -> list[Any]: ...

    def frame(self, value: Mapping[str, Any], key: str) -> FrameSpec | None: ...


class _Checks:
    """One pass over one config file: the problems found so far and the generic checks of a value."""

    def __init__(self, path: Path, display: str, text: str = "") -> None:
        self.path = path
        self.base = path.parent
        self.display = display
        self.problems: list[str] = []
        self.located: list[str] = []
        """``problems`` with the line of their key: ``file:line: key: found X, expected Y``."""
        self.text = text
        self.database: Any = None
        self.dbc_checks = DbcChecks()
        """What the DBC files get wrong: errors where the config reads it, notes elsewhere."""
        self.messages_ok = False
        self._by_name: dict[str, Any] = {}
        self._by_id: dict[int, list[Any]] = {}
        self.bus_names: tuple[str, ...] = ()
        self.sources: dict[str, SourceConfig] = {}
        self._broken_sources: set[str] = set()
        self._sources_ok = True
        self.canopen: CanopenDrives | None = None
        """The ``canopen:`` drives, when the config has any."""

    @cached_property
    def lines(self) -> dict[str, int]:
        """Each key path's line in :attr:`text`, worked out when a problem first asks (a valid config never does)."""
        return yamlsrc.key_lines(self.text)

    # -- problems ----------------------------------------------------------
    def problem(self, key: str, found: str, expected: str) -> None:
        """Record ``file: key: found X, expected Y`` (and its located form ``file:line: key: ...``)."""
        self.problems.append(f"{self.display}: {key}: found {found}, expected {expected}")
        line = _line_of(self.lines, key)
        where = self.display if line is None else f"{self.display}:{line}"
        self.located.append(f"{where}: {key}: found {found}, expected {expected}")

    def fail(self) -> ConfigError:
        """The ConfigError listing every problem recorded so far."""
        return ConfigError(self.problems, self.located)

    # -- generic checks ----------------------------------------------------
    def mapping(self, value: Any, key: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> bool:
        """Check ``value`` is a mapping with only ``allowed`` keys and every ``required`` one."""
        if not isinstance(value, Mapping):
            self.problem(key or "(top level)", _found(value), f"a mapping with keys {', '.join(allowed)}")
            return False
        for k in value:
            if k not in allowed:
                self.problem(_path(key, k), f"unknown key {_shown(k)}",
                             f"one of {', '.join(allowed)}" + _closest(k, allowed))
        for k in required:
            if k not in value:
                self.problem(_path(key, k), "nothing", "a value (required key)")
        return True

    def section(self, value: Any, key: str, allowed: tuple[str, ...], required: tuple[str, ...] = ()) -> Any:
        """An optional section: ``value`` when it is a mapping (its keys checked by :meth:`mapping`), else None."""
        return value if value is not None and self.mapping(value, key, allowed, required) else None

    def choice(self, mapping: Mapping[str, Any], name: str, key: str, options: tuple[Any, ...], default: Any) -> Any:
        """``mapping[name]`` (``default`` when left out) if it is one of ``options``, else a problem and ``default``."""
        value = mapping.get(name, default)
        if type(value) is type(options[0]) and value in options:
            return value
        shown = [str(o).lower() if isinstance(o, bool) else str(o) for o in options]
        self.problem(_path(key, name), _found(value), ", ".join(shown[:-1]) + " or " + shown[-1])
        return default

    def string(self, value: Any, key: str, expected: str = "a string") -> str | None:
        if isinstance(value, str) and value:
            return value
        self.problem(key, _found(value), expected)
        return None

    def number(self, value: Any, key: str, *, positive: bool = False) -> float | None:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        if ok and (not positive or value > 0):
            return float(value)
        if positive:
            unit = " in seconds" if key.rsplit(".", 1)[-1] in _SECONDS_KEYS else ""
            self.problem(key, _found(value), f"a number > 0{unit}")
        else:
            self.problem(key, _found(value), "a finite number")
        return None

    def seconds(self, mapping: Mapping[str, Any], name: str, key: str, default: float) -> float:
        if name not in mapping:
            return default
        value = self.number(mapping[name], _path(key, name), positive=True)
        return default if value is None else value

    def file_path(self, value: Any, key: str) -> Path | None:
        text = self.string(value, key, "a file path (relative to the config file or absolute)")
        if text is None:
            return None
        try:
            p = Path(text).expanduser()
        except RuntimeError:  # ~user of a user that does not exist, or no home directory
            self.problem(key, _found(text), "a file path whose ~ names an existing user's home directory")
            return None
        return Path(os.path.normpath(p if p.is_absolute() else self.base / p))

    def bus(self, value: Any, key: str) -> str:
        """Resolve a ``bus:`` key (``value`` None = left out)."""
        if value is None:
            if len(self.bus_names) == 1:
                return self.bus_names[0]
            if self.bus_names:
                buses = ", ".join(self.bus_names)
                self.problem(key, "nothing", f"one of the buses {buses} (several buses are configured)")
            return ""
        if not isinstance(value, str) or value not in self.bus_names:
            if self.bus_names:
                self.problem(key, _found(value), "a configured bus" + _closest(value, self.bus_names))
            return ""
        return value

    # -- DBC ---------------------------------------------------------------
