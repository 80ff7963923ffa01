"""The ``canguard`` command: one subcommand = ``add_parser(sub)`` + a function returning an exit code.

Exit codes: one table, :data:`canguard.cli.common.EXIT_CODES`, printed by every ``-h``.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from canguard import __version__
from canguard.cli.common import (
    BUNDLED_CONFIG,
    EXIT_BAD_INPUT,
    EXIT_BROKEN_PIPE,
    EXIT_INTERRUPTED,
    Formatter,
    add_global_options,
    default_config,
    exit_codes_epilog,
    subcommand,
)
from canguard.cli.common import add_config as _add_config
from canguard.cli.common import config_path as _config_path
from canguard.errors import CanguardError, ConfigError

Handler = Callable[[argparse.Namespace], int]

__all__ = ["BUNDLED_CONFIG", "build_parser", "default_config", "main", "parse_args"]


# -- check -----------------------------------------------------------------------------------
def _add_check(sub: argparse._SubParsersAction) -> None:
    p = subcommand(sub, "check", help="validate a config, its DBC files and its tree; print what they resolve to",
                       description="Load the config, its DBC files and its tree; print buses, sources "
                                   "(message, id, signals, units) and frames; exit 0, or 2 with every error.")
    _add_config(p)
    _add_nodes(p)
    p.set_defaults(func=_cmd_check)


def _add_nodes(p: argparse.ArgumentParser) -> None:
    p.add_argument("--nodes", action="append", default=[], type=Path, metavar="FILE",
                   help="a Groot2 / BT.CPP palette (<TreeNodesModel>) declaring node types the tree uses; "
                        "repeatable")


def _palette(args: argparse.Namespace) -> Any:
    from canguard.bt.palette import read_palettes

    return read_palettes(args.nodes) if args.nodes else None


def _cmd_check(args: argparse.Namespace) -> int:
    from canguard.bt.loader import check_tree, partial_tree_problems
    from canguard.cli.check import describe
    from canguard.config.loader import load_config
    from canguard.errors import ConfigError

    try:
        cfg = load_config(_config_path(args))
    except ConfigError as exc:
        # The tree's own mistakes belong in the same report: check it against what did load.
        tree_problems = partial_tree_problems(exc.partial)
        if not tree_problems:
            raise
        raise ConfigError([*exc.problems, *tree_problems], [*exc.located, *tree_problems]) from None
    print(describe(cfg))
    if cfg.tree is not None:
        report = check_tree(cfg, _palette(args))
        print(report.text, end="" if report.text.endswith("\n") else "\n")
        for warning in report.warnings:
            print(f"warning: {warning}", file=sys.stderr)
    return 0


# -- tree ------------------------------------------------------------------------------------
def _add_tree(sub: argparse._SubParsersAction) -> None:
    p = subcommand(sub, "tree", help="print the config's behaviour tree; render it; write a Groot2 nodes model",
                       description="Print the tree of the config (py_trees' unicode display).")
    _add_config(p)
    p.add_argument("--dot", type=Path, metavar="FILE", help="render the tree (.dot, or .png/.svg with graphviz)")
    p.add_argument("--nodes-model", type=Path, metavar="FILE",
                   help="write a Groot2 <TreeNodesModel> of every canguard node and its ports")
    p.add_argument("file", type=Path, nargs="?", metavar="TREE.xml",
                   help="a tree file on its own (no config): check it, and with --tick run it dry")
    p.add_argument("--tick", type=int, default=None, metavar="N", help="with TREE.xml: tick it N times")
    p.add_argument("--dt", type=float, default=0.1, metavar="S", help="seconds between ticks (default 0.1)")
    p.add_argument("--main", default=None, metavar="ID", help="with TREE.xml: the BehaviorTree to run")
    p.add_argument("--json", action="store_true",
                   help='print {"ticks": [root status per tick], "blackboard": {root entries}}')
    _add_nodes(p)
    p.set_defaults(func=_cmd_tree)


def _cmd_tree(args: argparse.Namespace) -> int:
    from canguard.bt.loader import nodes_model_xml, show_tree

    if args.file is not None:
        return _dry_run(args)
    if args.tick is not None or args.json:
        raise ConfigError("tree: --tick and --json run a tree file on its own: canguard tree TREE.xml --tick N")

    if args.nodes_model is not None:
        from canguard.bt.loader import context_for
        from canguard.config.loader import load_config

        ctx = context_for(load_config(_config_path(args)))
        args.nodes_model.write_text(nodes_model_xml(ctx), encoding="utf-8")
        print(f"wrote {args.nodes_model}")
    print(show_tree(_config_path(args), dot=args.dot), end="")
    return 0


def _dry_run(args: argparse.Namespace) -> int:
    """``canguard tree TREE.xml [--tick N --dt S] [--json]``: the tree alone, on a manual clock."""
    import json

    from canguard.bt.dryrun import dry_run
    from canguard.bt.loader import render_text

    if args.config is not None:
        raise ConfigError("tree TREE.xml runs the file on its own: leave out -c (or drop TREE.xml to show the "
                          "config's tree)")
    if args.tick is not None and args.tick < 0:
        raise ConfigError(f"--tick {args.tick}: expected a number of ticks >= 0")
    if not math.isfinite(args.dt) or args.dt <= 0:
        raise ConfigError(f"--dt {args.dt}: expected seconds > 0")
    from canguard.bt.build import validate_tree
    from canguard.bt.context import Context, NullTaskGate
    from canguard.io.clock import ManualClock

    palette = _palette(args)
    if not args.tick:
        main_id, unbound = validate_tree(args.file, Context(ManualClock(), {}, task=NullTaskGate()), args.main,
                                         palette)
        if unbound:  # valid against its palettes; it cannot run until those nodes are bound
            print(f"{args.file}: BehaviorTree {main_id} is valid; to run it, bind these nodes:")
            print("\n".join(f"  {why}" for why in unbound))
            return 0
    result = dry_run(args.file, args.tick or 0, args.dt, args.main, palette)
    if args.json:
        print(json.dumps(result))
        return 0
    from canguard.bt.build import load_tree

    loaded = load_tree(args.file, Context(ManualClock(), {}, task=NullTaskGate()), args.main, palette)
    print(render_text(loaded.root), end="")
    if args.tick:
        print("ticks: " + " ".join(result["ticks"]))
        print("blackboard: " + ", ".join(f"{k}={v!r}" for k, v in result["blackboard"].items()))
    return 0


# -- run -------------------------------------------------------------------------------------
def _add_run(sub: argparse._SubParsersAction) -> None:
    p = subcommand(sub, "run", help="run the daemon on the config's buses (systemd service)",
                       description="Run the live engine: read the buses, tick the tree, send task / stop "
                                   "frames. SIGTERM stops cleanly (stop frames out, exit 0); SIGHUP reloads.")
    _add_config(p)
    p.add_argument("--metrics", metavar="HOST:PORT", help="serve Prometheus metrics (e.g. 127.0.0.1:9108)")
    p.add_argument("--duration", type=float, metavar="S", help="stop by itself after S seconds")
    p.set_defaults(func=_cmd_run)


def _cmd_run(args: argparse.Namespace) -> int:
    from canguard.service.daemon import Daemon

    daemon = Daemon(_config_path(args), metrics_addr=args.metrics)
    daemon.install_signals()
    return daemon.run(duration_s=args.duration)


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser (every subcommand has -h)."""
    parser = argparse.ArgumentParser(
        prog="canguard",
        description="CAN-bus motor-driver monitoring: DBC decoding, protection models, behaviour trees.",
        epilog=exit_codes_epilog(), formatter_class=Formatter,
    )
    parser.add_argument("--version", action="version", version=f"canguard {__version__}")
    add_global_options(parser, in_subcommand=False)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for add in (_add_run, _add_check, _add_tree):
        add(sub)
    for extra in _extra_commands():
        extra(sub)
    return parser


def _extra_commands() -> list[Callable[[argparse._SubParsersAction], None]]:
    """Subcommands that live in their own modules (replay, simulate, demo)."""
    adders: list[Callable[[argparse._SubParsersAction], None]] = []
    for module in ("cli.replay", "cli.simulate", "cli.demo", "cli.init", "cli.unit", "cli.completion"):
        try:
            mod = __import__(f"canguard.{module}", fromlist=["add_parser"])
        except ModuleNotFoundError as exc:
            if exc.name != f"canguard.{module}":
                raise
            continue
        adders.append(mod.add_parser)
    return adders


def parse_args(parser: argparse.ArgumentParser, argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Parse ``argv``; global options count wherever they stand (``-v check -v`` is ``-vv``)."""
    args = parser.parse_args(argv)
    args.verbose += getattr(args, "sub_verbose", 0)
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``canguard`` console script; returns the exit code."""
    parser = build_parser()
    args = parse_args(parser, argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(name)s %(levelname)s: %(message)s")
    if args.command is None:
        parser.print_help()
        return EXIT_BAD_INPUT
    func: Handler = args.func
    args.root_parser = parser
    try:
        code = func(args)
        sys.stdout.flush()  # a closed pipe shows here, inside the try, not at interpreter exit
        return code
    except BrokenPipeError:
        return _quiet_broken_pipe()
    except CanguardError as exc:
        # ConfigError / TreeError carry every problem of one load: all are printed, one per line.
        problems = getattr(exc, "problems", None)
        count = len(problems) if isinstance(problems, list) else 1
        head = "error" if count <= 1 else f"{count} errors"
        print(f"canguard {args.command}: {head}:\n{exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except FileNotFoundError as exc:
        print(f"canguard {args.command}: error: {exc.filename or exc}: no such file", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED


def _quiet_broken_pipe() -> int:
    """The reader of stdout went away (``| head``): end quietly, as a SIGPIPE'd Unix tool does.

    Python's docs' recipe: point stdout at devnull so the interpreter's final flush
    does not raise again and print a traceback.
    """
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return EXIT_BROKEN_PIPE


if __name__ == "__main__":
    sys.exit(main())
