"""canguard: a CAN-bus motor-driver monitoring daemon."""

from __future__ import annotations

__all__ = ["__version__"]


def __getattr__(name: str) -> str:
    """``canguard.__version__``, looked up in the installed metadata when first asked for (lazy: the lookup costs
    every command's start-up, for a value only ``--version`` prints)."""
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        value = version("canguard")
    except PackageNotFoundError:  # running from a source tree that was not installed
        value = "0.0.0+unknown"
    globals()["__version__"] = value
    return value
