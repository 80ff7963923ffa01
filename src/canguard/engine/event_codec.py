"""One event -> one deterministic JSON line (the journal's format)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

FIRST_KEYS = ("t", "event", "node", "source", "value", "threshold", "reason")
"""Keys every line carries, in this order; the event's other keys follow, sorted."""


def _normalize(value: Any, key: str = "") -> Any:
    """Make ``value`` JSON-safe and deterministic (rounded floats, sorted nested keys)."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, int):
        return int(value)  # IntEnum and friends: their plain number
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        if key == "t":
            # Epoch seconds: microseconds are what candump writes.
            return round(value, 6)
        rounded = float(f"{value:.10g}")
        # Rounding near float max can overflow to inf: keep the exact value then.
        return rounded if math.isfinite(rounded) else value
    if isinstance(value, Mapping):
        return {str(k): _normalize(v, str(k)) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    if isinstance(value, (list, tuple)):
        return [_normalize(v) for v in value]
    if isinstance(value, (set, frozenset)):
        return sorted((_normalize(v) for v in value), key=repr)
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).hex()
    if hasattr(value, "__float__") and not isinstance(value, (str, bytes)):
        try:
            return _normalize(float(value), key)  # numpy scalars, Decimal
        except (TypeError, ValueError):
            pass
    return str(value)  # Path, enums, anything else: its text


def _top(value: Any, key: str) -> Any:
    """A top-level field: like :func:`_normalize`, but a non-finite float is null (its text is beside it)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return _normalize(value, key)


def encode_event(event: Mapping[str, Any]) -> bytes:
    """Encode one event as one JSON line (UTF-8, ending in ``\\n``); ValueError without an ``event`` key."""
    if "event" not in event:
        raise ValueError(f"an event needs an 'event' key (trip, recover, ...); got keys {sorted(event)}")
    # A number field stays a number or null: a non-finite value is written as null, and its text
    # ("nan", "inf", "-inf") goes to "<key>_text", so consumers never meet a string in "value".
    texts = {
        f"{k}_text": ("nan" if math.isnan(v) else "inf" if v > 0 else "-inf")
        for k, v in event.items()
        if isinstance(v, float) and not math.isfinite(v)
    }
    rest = {str(k): v for k, v in event.items() if k not in FIRST_KEYS}
    rest.update(texts)
    out: dict[str, Any] = {k: _top(event.get(k), k) for k in FIRST_KEYS}
    for k, v in sorted(rest.items(), key=lambda kv: kv[0]):
        out[k] = _top(v, k)
    text = json.dumps(out, ensure_ascii=False, separators=(",", ":"), allow_nan=False)
    return text.encode("utf-8") + b"\n"
