"""``canguard simulate``: the simulated robot on a configured bus, or into a candump -L file."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from canguard.cli.common import config_path, subcommand
from canguard.errors import ConfigError


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``canguard simulate``."""
    from canguard.sim import SCENARIOS

    scen = "; ".join(f"{k}: {v.splitlines()[0] if v else ''}" for k, v in SCENARIOS.items())
    p = subcommand(sub, "simulate", cmd_simulate,
                   description="Send the bundled DBC's frames as a robot would, on a configured bus (--bus, "
                               "answering canguard's Estop / Clear_Errors / Set_Axis_State) or into a candump -L "
                               f"file (--out). Scenarios (combine them; NAME@S shifts one by S seconds): {scen}")
    p.add_argument("-c", "--config", type=Path, default=None, help="YAML config (its DBC and buses)")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--bus", metavar="NAME", help="a bus of the config to run on, in real time")
    where.add_argument("--out", type=Path, metavar="FILE",
                       help="write a candump -L log: FILE.log, or FILE.log.gz compressed (replay reads a log by its "
                            "suffix)")
    p.add_argument("--scenario", action="append", default=[], metavar="NAME[@S]",
                   help=f"one of {', '.join(SCENARIOS)} (repeatable; default: normal)")
    p.add_argument("--duration", type=float, default=10.0, metavar="S", help="simulated seconds (default 10)")
    p.add_argument("--seed", type=int, default=0, help="random seed: same seed, same log (default 0)")
    p.add_argument("--axes", type=int, default=4, help="number of motor drivers (default 4)")


def cmd_simulate(args: argparse.Namespace) -> int:
    """Run the simulator; exit 0, or 2 on bad arguments."""
    from canguard.config.loader import load_config
    from canguard.sim import run_on_bus, write_log

    cfg = load_config(config_path(args))
    if args.duration <= 0:
        raise ConfigError(f"--duration {args.duration}: expected seconds > 0")
    from canguard.io.outputs import check_output

    check_output(args.out, "--out")
    if args.out is not None:
        from canguard.io.logs import log_format

        fmt, compression = log_format(args.out)  # an unknown suffix: a LogFormatError naming the known ones
        if fmt != "candump" or compression not in ("", "gz"):
            as_read = fmt + (f" + {compression}" if compression else "")
            raise ConfigError(f"--out {args.out}: simulate writes candump -L logs, plain or gzip'd: name it .log or "
                              f".log.gz (replay would read this name as {as_read})")
    scenarios = tuple(args.scenario) or ("normal",)
    kwargs = {"db": cfg.database, "scenarios": scenarios, "seed": args.seed, "axes": args.axes}
    try:
        if args.out is not None:
            chan = next((b.channel for b in cfg.buses.values() if b.channel), "can0")
            n = write_log(args.out, args.duration, channel=chan, **kwargs)
            print(f"wrote {n} frames ({args.duration:g} s, scenarios {', '.join(scenarios)}) to {args.out}")
            return 0
        if args.bus not in cfg.buses:
            raise ConfigError(f"--bus {args.bus!r}: expected one of the configured buses: {', '.join(cfg.buses)}")
        from canguard.io.bus import open_bus

        bus = open_bus(cfg.buses[args.bus])
        try:
            n = run_on_bus(bus, args.duration, **kwargs)
        finally:
            bus.shutdown()
    except ValueError as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"simulate: {exc}") from exc
    print(f"sent {n} frames on bus {args.bus}", file=sys.stderr)
    return 0
