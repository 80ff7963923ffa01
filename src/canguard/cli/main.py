"""The ``canguard`` command: one subcommand = ``add_parser(sub)`` + a function returning an exit code."""

from __future__ import annotations

import argparse
import gc
import importlib
import logging
import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from canguard.cli.common import (
    COMMANDS,
    EXIT_BAD_INPUT,
    EXIT_BROKEN_PIPE,
    EXIT_CODES_EPILOG,
    EXIT_INTERRUPTED,
    add_global_options,
    add_monitor_options,
    add_state_dir,
    default_config,
    one_blas_thread,
    run_config,
    subcommand,
)
from canguard.cli.common import add_config as _add_config
from canguard.cli.common import config_path as _config_path
from canguard.errors import CanguardError, ConfigError

Handler = Callable[[argparse.Namespace], int]

__all__ = ["build_parser", "default_config", "main", "parse_args"]


# -- check -----------------------------------------------------------------------------------
def _add_check(sub: argparse._SubParsersAction) -> None:
    p = subcommand(sub, "check", _cmd_check,
                       description="Load the config, its DBC files and its tree; print buses, sources "
                                   "(message, id, signals, units) and frames; exit 0, or 2 with every error. -v lists "
                                   "what the DBC files get wrong where the config does not read it.")
    _add_config(p)
    add_state_dir(p)
    _add_nodes(p)


def _add_nodes(p: argparse.ArgumentParser) -> None:
    p.add_argument("--nodes", action="append", default=[], type=Path, metavar="FILE",
                   help="a Groot2 / BT.CPP palette (<TreeNodesModel>) declaring node types the tree uses; "
                        "repeatable")


def _palette(args: argparse.Namespace) -> Any:
    from canguard.bt.loader import read_palettes

    return read_palettes(args.nodes) if args.nodes else None


def _cmd_check(args: argparse.Namespace) -> int:
    from canguard.bt.checks import check_tree
    from canguard.bt.loader import partial_tree_problems
    from canguard.cli.check import describe
    from canguard.io.outputs import check_config_outputs

    try:
        cfg, _ = run_config(args)
    except ConfigError as exc:
        # The tree's own mistakes belong in the same report: check it against what did load.
        tree_problems = partial_tree_problems(exc.partial)
        if not tree_problems:
            raise
        raise ConfigError([*exc.problems, *tree_problems], [*exc.located, *tree_problems]) from None
    check_config_outputs(cfg)  # what `canguard run` refuses at start, refused here
    print(describe(cfg, verbose=args.verbose > 0))
    if cfg.tree is not None:
        report = check_tree(cfg, _palette(args))
        print(report.text, end="" if report.text.endswith("\n") else "\n")
        for warning in report.warnings:
            print(f"warning: {warning}", file=sys.stderr)
    return 0


# -- tree ------------------------------------------------------------------------------------
def _add_tree(sub: argparse._SubParsersAction) -> None:
    p = subcommand(sub, "tree", _cmd_tree,
                       description="Print the tree of the config (py_trees' unicode display).")
    _add_config(p)
    p.add_argument("--dot", type=Path, metavar="FILE", help="render the tree (.dot, or .png/.svg with graphviz)")
    p.add_argument("--nodes-model", type=Path, metavar="FILE",
                   help="write a Groot2 <TreeNodesModel> of every canguard node and its ports")
    p.add_argument("file", type=Path, nargs="?", metavar="TREE.xml",
                   help="a tree file on its own (no config): check it, and with --tick run it dry")
    p.add_argument("--tick", type=int, default=None, metavar="N",
                   help="with TREE.xml: tick it N times, each as BT.CPP's tickOnce() (the root is ticked "
                        "again while a node has emitted its wake-up signal)")
    p.add_argument("--exactly-once", action="store_true",
                   help="with --tick: each tick as BT.CPP's tickExactlyOnce() (no re-tick on a wake-up)")
    p.add_argument("--dt", type=float, default=0.1, metavar="S", help="seconds between ticks (default 0.1)")
    p.add_argument("--main", default=None, metavar="ID", help="with TREE.xml: the BehaviorTree to run")
    p.add_argument("--json", action="store_true",
                   help='print {"ticks": [root status per tick], "blackboard": {root entries}}')
    _add_nodes(p)


def _cmd_tree(args: argparse.Namespace) -> int:
    from canguard.bt.checks import nodes_model_xml, show_tree

    if args.file is not None:
        return _dry_run(args)
    if args.tick is not None or args.json or args.exactly_once:
        raise ConfigError("tree: --tick, --exactly-once and --json run a tree file on its own: "
                          "canguard tree TREE.xml --tick N")

    if args.nodes_model is not None:
        from canguard.bt.checks import context_for
        from canguard.config.loader import load_config

        ctx = context_for(load_config(_config_path(args)))
        args.nodes_model.write_text(nodes_model_xml(ctx), encoding="utf-8")
        print(f"wrote {args.nodes_model}")
    print(show_tree(_config_path(args), dot=args.dot), end="")
    return 0


def _dry_run(args: argparse.Namespace) -> int:
    """``canguard tree TREE.xml [--tick N --dt S] [--json]``: the tree alone, on a manual clock."""
    import json

    from canguard.bt.checks import render_text
    from canguard.bt.dryrun import dry_run

    if args.config is not None:
        raise ConfigError("tree TREE.xml runs the file on its own: leave out -c (or drop TREE.xml to show the "
                          "config's tree)")
    if args.tick is not None and args.tick < 0:
        raise ConfigError(f"--tick {args.tick}: expected a number of ticks >= 0")
    if not math.isfinite(args.dt) or args.dt <= 0:
        raise ConfigError(f"--dt {args.dt}: expected seconds > 0")
    from canguard.bt.context import Context, NullTaskGate
    from canguard.bt.loader import load_tree, validate_tree
    from canguard.io.clock import ManualClock

    palette = _palette(args)
    if not args.tick:
        main_id, unbound = validate_tree(args.file, Context(ManualClock(), {}, task=NullTaskGate()), args.main,
                                         palette)
        if unbound:  # valid against its palettes; it cannot run until those nodes are bound
            print(f"{args.file}: BehaviorTree {main_id} is valid; to run it, bind these nodes:")
            print("\n".join(f"  {why}" for why in unbound))
            return 0
    result = dry_run(args.file, args.tick or 0, args.dt, args.main, palette, exactly_once=args.exactly_once)
    if args.json:
        print(json.dumps(result))
        return 0
    loaded = load_tree(args.file, Context(ManualClock(), {}, task=NullTaskGate()), args.main, palette)
    print(render_text(loaded.root), end="")
    if args.tick:
        print("ticks: " + " ".join(result["ticks"]))
        print("blackboard: " + ", ".join(f"{k}={v!r}" for k, v in result["blackboard"].items()))
    return 0


# -- run -------------------------------------------------------------------------------------
def _add_run(sub: argparse._SubParsersAction) -> None:
    p = subcommand(sub, "run", _cmd_run,
                       description="Run the live engine: read the buses, tick the tree, send task / stop "
                                   "frames. SIGTERM stops cleanly (stop frames out, exit 0); SIGHUP reloads.")
    _add_config(p)
    p.add_argument("--metrics", metavar="HOST:PORT", help="serve Prometheus metrics (e.g. 127.0.0.1:9108)")
    p.add_argument("--duration", type=float, metavar="S", help="stop by itself after S seconds")
    add_state_dir(p)
    add_monitor_options(p)


def _cmd_run(args: argparse.Namespace) -> int:
    from canguard.service.daemon import Daemon

    cfg, where = run_config(args)
    if where is not None:  # not where the config says: say where, before anything is written
        why = ("--state-dir" if args.state_dir is not None
               else "the bundled config is read-only; choose with -c CONFIG or --state-dir DIR")
        print(f"canguard run: events {cfg.events or '(none)'}, I²t state {cfg.state.file or '(not kept)'} ({why})",
              file=sys.stderr, flush=True)
    daemon = Daemon(_config_path(args), cfg=cfg, state_dir=where, metrics_addr=args.metrics, http=args.http,
                    groot2=args.groot2)
    daemon.install_signals()
    return daemon.run(duration_s=args.duration)


class _VersionAction(argparse._VersionAction):
    """``--version``: the version is looked up when asked for, not at every start (see canguard.__init__)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        import canguard

        self.version = f"canguard {canguard.__version__}"
        super().__call__(parser, namespace, values, option_string)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The full argument parser; with ``command``, only that subcommand in full (the others listed, not imported)."""
    parser = argparse.ArgumentParser(
        prog="canguard",
        description="CAN-bus motor-driver monitoring: DBC decoding, protection models, behaviour trees.",
        epilog=EXIT_CODES_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action=_VersionAction)
    add_global_options(parser, in_subcommand=False)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    builtin = {"run": _add_run, "check": _add_check, "tree": _add_tree}  # the others: canguard.cli.<name>
    for name in COMMANDS:
        if command is not None and name != command:
            sub.add_parser(name, help=COMMANDS[name])  # named and listed; never parsed
        elif name in builtin:
            builtin[name](sub)
        else:
            importlib.import_module(f"canguard.cli.{name}").add_parser(sub)
    return parser


def _command_in(argv: Sequence[str]) -> str | None:
    """The subcommand ``argv`` runs ("" for none); None: build them all (``completion`` needs every option)."""
    for word in argv:
        if word == "--":
            return None
        if not word.startswith("-"):
            return word if word in COMMANDS and word != "completion" else None
    return ""  # no subcommand: -h, --version or the usage need only the names


def parse_args(parser: argparse.ArgumentParser, argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Parse ``argv``; global options count wherever they stand (``-v check -v`` is ``-vv``)."""
    args = parser.parse_args(argv)
    args.verbose += getattr(args, "sub_verbose", 0)
    return args


def main(argv: Sequence[str] | None = None, parser: argparse.ArgumentParser | None = None) -> int:
    """Entry point of the ``canguard`` console script; returns the exit code (``parser``: built already)."""
    if parser is None:
        one_blas_thread()  # before anything imports numpy
        parser = build_parser(_command_in(sys.argv[1:] if argv is None else argv))
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
    except BrokenPipeError:  # the reader of stdout went away (``| head``): stdout to devnull, a quiet final flush
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return EXIT_BROKEN_PIPE
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
    except OSError as exc:  # a file the checks before the run could not foresee (a race, a disk gone)
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"canguard {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED


def console() -> int:
    """The process's entry point (console script, ``python -m canguard``): :func:`main`, then exit. The imports'
    objects live until exit: made with the collector off, then frozen out of its walks (not in :func:`main`)."""
    from canguard.cli.deferred import defer_unused

    defer_unused()
    one_blas_thread()  # before anything imports numpy
    gc.disable()
    parser = build_parser(_command_in(sys.argv[1:]))
    gc.freeze()
    gc.enable()
    code = main(parser=parser)
    gc.freeze()
    return code
