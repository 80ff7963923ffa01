"""Heat that survives restarts: the I²t state file (docs/protection.md, "Heat across restarts").

``{"format": "canguard-heat", "version": 1, "t": <save time, s>, "models": {"<key>": <model.export()>}}``;
a clock that stamps saves (:class:`canguard.io.clock.BootClock`) keeps a wall-clock step out of the downtime.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from canguard.errors import StateFileError

if TYPE_CHECKING:
    from canguard.io.clock import BootClock

KIND_LEAKY = "leaky"
KIND_THERMAL = "thermal"


def _param(params: Mapping[str, Any], name: str) -> float:
    v = params.get(name)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"i2t state: parameter {name!r} missing or not a finite number: {v!r}")
    return float(v)


def cooled_level(state: Mapping[str, Any], downtime_s: float) -> float:
    """The trip-level fraction of an exported state after ``downtime_s`` at zero current, by the saved model's own
    parameters and law; ValueError when the state is malformed."""
    if not isinstance(state, Mapping):
        raise ValueError(f"i2t state: expected a mapping, got {type(state).__name__}")
    kind = state.get("kind")
    params = state.get("params")
    if not isinstance(params, Mapping):
        raise ValueError("i2t state: 'params' missing or not a mapping")
    acc = state.get("accumulator")
    if isinstance(acc, bool) or not isinstance(acc, (int, float)) or not math.isfinite(acc) or acc < 0:
        raise ValueError(f"i2t state: 'accumulator' must be a finite number >= 0, got {acc!r}")
    d = float(downtime_s)
    d = d if d > 0 else 0.0  # negative or NaN (the clock went back across the restart): none
    if kind == KIND_LEAKY:
        c = _param(params, "continuous_a")
        s = (_param(params, "peak_a") ** 2 - c**2) * _param(params, "peak_time_s")
        if c <= 0 or s <= 0:
            raise ValueError("i2t state: leaky parameters do not give a positive trip level")
        return max(0.0, float(acc) - c * c * d) / s
    if kind == KIND_THERMAL:
        tau_cool = _param(params, "tau_cool_s")
        if tau_cool <= 0:
            raise ValueError("i2t state: tau_cool_s must be > 0")
        return float(acc) * math.exp(-d / tau_cool)
    raise ValueError(f"i2t state: unknown kind {kind!r} (expected {KIND_LEAKY!r} or {KIND_THERMAL!r})")


log = logging.getLogger(__name__)

FORMAT = "canguard-heat"
VERSION = 1
ON_CORRUPT = ("hot", "cold")


@runtime_checkable
class HeatModel(Protocol):
    """What the state file needs of a model (LeakyI2t and ThermalI2t): ``export``, ``restore``, ``set_hot``."""

    def export(self) -> dict[str, Any]: ...

    def restore(self, state: Mapping[str, Any], downtime_s: float) -> None: ...

    def set_hot(self, t: float | None = None) -> None: ...


class HeatStore:
    """Saves and restores I²t state to/from one JSON file; ``on_corrupt``: ``"hot"`` or ``"cold"`` (ValueError else)."""

    def __init__(self, path: Path | str | None, on_corrupt: str = "hot", clock: BootClock | None = None) -> None:
        if on_corrupt not in ON_CORRUPT:
            raise ValueError(f"on_corrupt must be 'hot' or 'cold', got {on_corrupt!r}")
        self.path = None if path is None else Path(path)
        self.on_corrupt = on_corrupt
        self._loaded = False
        self.corrupt: str | None = None
        """Why the file could not be used (None when it loaded, was missing or was never read)."""
        self._saved_t: float | None = None
        self._states: dict[str, Any] = {}
        self._saved_stamp: object = None
        self.clock = clock
        self._last_save_t: float | None = None

    def load(self, now: float) -> None:
        """Read the state file once (later calls do nothing); ``now`` is the start time, for the log."""
        if self._loaded:
            return
        self._loaded = True
        if self.path is None:
            return
        try:
            doc = json.loads(self.path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            log.info("no I²t state file %s: starting cold", self.path)
            return
        except (OSError, UnicodeDecodeError) as exc:
            problem = f"cannot read it: {exc}"
        except ValueError as exc:
            problem = f"not valid JSON: {exc}"
        else:
            problem = _check_doc(doc)
        if problem:
            self.corrupt = problem
            log.warning("I²t state file %s is unusable (%s): models start %s", self.path, problem, self.on_corrupt)
            return
        self._saved_t = float(doc["t"])
        self._states = dict(doc["models"])
        self._saved_stamp = doc.get("stamp")
        log.debug("loaded I²t state of %d models from %s (saved %.3f s before %.3f)",
                  len(self._states), self.path, now - self._saved_t, now)

    def restore(self, key: str, model: Any, now: float) -> None:
        """Restore ``model`` under ``key``, cooled for the downtime; TypeError when the model cannot hold heat."""
        if not isinstance(model, HeatModel):
            raise TypeError(f"model {key!r} ({type(model).__name__}) has no heat state to restore")
        self.load(now)
        if self.path is None:
            return
        if self.corrupt is not None:
            if self.on_corrupt == "hot":
                model.set_hot(now)
            return
        state = self._states.get(key)
        if state is None or self._saved_t is None:
            return
        downtime = now - self._saved_t
        if self.clock is not None:
            downtime = self.clock.downtime(self._saved_stamp, downtime)
        try:
            model.restore(state, downtime)
        except (ValueError, TypeError, KeyError) as exc:
            log.warning("I²t state of %r in %s is unusable (%s): it starts %s", key, self.path, exc, self.on_corrupt)
            if self.on_corrupt == "hot":
                model.set_hot(now)

    def save(self, models: Mapping[str, Any], now: float) -> None:
        """Write every model's state atomically, stamped ``now``: StateFileError when it cannot be written,
        TypeError (before anything is written) when a model cannot hold heat."""
        if self.path is None:
            return
        for key, model in models.items():
            if not isinstance(model, HeatModel):
                raise TypeError(f"model {key!r} ({type(model).__name__}) has no heat state to save")
        doc = {"format": FORMAT, "version": VERSION, "t": now, "models": {k: m.export() for k, m in models.items()}}
        if self.clock is not None:
            doc["stamp"] = self.clock.stamp()
        try:
            data = json.dumps(doc, allow_nan=False, sort_keys=True, indent=1).encode("utf-8")
        except ValueError as exc:
            raise StateFileError(f"cannot encode I²t state for {self.path}: {exc}") from exc
        _atomic_write(self.path, data)
        self._last_save_t = now

    def next_save_t(self, period_s: float) -> float:
        """From when :meth:`maybe_save` saves again (-inf: at its next call; inf: never, no file)."""
        if self.path is None:
            return math.inf
        last = self._last_save_t
        return -math.inf if last is None else last + period_s

    def maybe_save(self, models: Mapping[str, Any], now: float, period_s: float) -> bool:
        """Save when ``period_s`` has passed since the last save (or none yet, or time went back); True if it saved."""
        if self.path is None:
            return False
        last = self._last_save_t
        if last is not None and 0 <= now - last < period_s:
            return False
        self.save(models, now)
        return True


def readable_problem(path: Path) -> str:
    """Why the state file ``path`` cannot be read ("" when it can)."""
    if not path.exists():
        return "no such file"
    if not path.is_file():
        return "not a regular file"
    try:
        with open(path, "rb"):
            pass
    except OSError as exc:
        return exc.strerror or str(exc)
    return ""


def _check_doc(doc: Any) -> str:
    """What is wrong with a loaded document, "" when nothing."""
    if not isinstance(doc, dict):
        return f"expected a JSON object, got {type(doc).__name__}"
    if doc.get("format") != FORMAT:
        return f"'format' is {doc.get('format')!r}, expected {FORMAT!r}"
    if doc.get("version") != VERSION:
        return f"unsupported version {doc.get('version')!r} (expected {VERSION})"
    t = doc.get("t")
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
        return f"'t' must be a finite number, got {t!r}"
    if not isinstance(doc.get("models"), dict):
        return "'models' missing or not an object"
    return ""


def _atomic_write(path: Path, data: bytes) -> None:
    """Temp file in the same directory + fsync + os.replace + directory fsync."""
    fd = -1
    tmp = ""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        with os.fdopen(fd, "wb") as f:
            fd = -1  # owned by f now
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        tmp = ""
        with contextlib.suppress(OSError):  # not every filesystem lets a directory be fsynced
            dfd = os.open(path.parent, os.O_RDONLY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)
    except OSError as exc:
        raise StateFileError(f"cannot write I²t state file {path}: {exc}") from exc
    finally:
        if fd >= 0:
            os.close(fd)
        if tmp:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
