"""Which configured bus takes the frames of each channel of a recorded log."""

from __future__ import annotations

from collections.abc import Sequence

from canguard.config.schema import Config
from canguard.errors import ConfigError


def parse_map(items: Sequence[str], cfg: Config) -> dict[str, str]:
    """``--map can0=main`` items -> {channel: bus}; errors name the item and the configured buses."""
    out: dict[str, str] = {}
    for item in items:
        chan, sep, bus = item.partition("=")
        if not sep or not chan or not bus:
            raise ConfigError(f"--map {item!r}: expected CHANNEL=BUS, e.g. can0=main")
        if bus not in cfg.buses:
            raise ConfigError(f"--map {item!r}: unknown bus {bus!r}; configured buses: {', '.join(cfg.buses)}")
        out[chan] = bus
    return out


class ChannelRouter:
    """Maps a log's channel names to the config's buses: --map, then bus names and channels, then the only bus
    (one bus, no --map: any channel; :meth:`merged` says when that merged several)."""

    def __init__(self, cfg: Config, overrides: dict[str, str]) -> None:
        self.table: dict[str, str] = {b.channel: name for name, b in cfg.buses.items() if b.channel}
        self.table.update({name: name for name in cfg.buses})
        self.table.update(overrides)
        self.only = next(iter(cfg.buses)) if len(cfg.buses) == 1 and not overrides else None
        self.unmapped: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        """Frames per channel while the only-bus fallback is on (counted by the engine's run_log)."""

    def merged(self) -> dict[str, int]:
        """Frames per channel when the fallback merged several channels into the only bus, else {}."""
        if len(self.channels) < 2 or all(c in self.table for c in self.channels):
            return {}
        return dict(sorted(self.channels.items()))
