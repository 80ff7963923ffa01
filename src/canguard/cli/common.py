"""What every ``canguard`` subcommand shares: the config default, global options, exit codes."""

from __future__ import annotations

import argparse
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from canguard.errors import ConfigError

if TYPE_CHECKING:
    from canguard.config.schema import Config


def bundled_config() -> Path:
    """The config shipped in the package (``canguard/data/config/canguard.yaml``), looked up when needed."""
    from canguard.data import data_path

    return data_path("config", "canguard.yaml")


EXIT_OK = 0
EXIT_TRIPPED = 1
EXIT_REGRESSED = 1
"""replay --fail-on-regression: worse than --baseline (the same code as a trip: a CI gate failed)."""
EXIT_BAD_INPUT = 2
EXIT_UNGUARDED = 3
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141

EXIT_CODES: tuple[tuple[int, str], ...] = (
    (EXIT_OK, "fine"),
    (EXIT_TRIPPED, "replay --fail-on-trip: a guard tripped; --fail-on-regression: a trip gained or lost, "
                   "or a margin shrank, against --baseline"),
    (EXIT_BAD_INPUT, "bad input (config, DBC, tree, log, option, state file): every problem on stderr"),
    (EXIT_UNGUARDED, "replay --fail-on-trip: a source the config guards got no sample from a log"),
    (EXIT_INTERRUPTED, "interrupted (Ctrl-C)"),
    (EXIT_BROKEN_PIPE, "stdout was closed (e.g. | head): output ended early, quietly"),
)


COMMANDS: dict[str, str] = {
    "run": "run the daemon on the config's buses (systemd service)",
    "check": "validate a config, its DBC files and its tree; print what they resolve to",
    "tree": "print the config's behaviour tree; render it; write a Groot2 nodes model",
    "replay": "run the daemon's engine over recorded logs (candump, ASC, BLF, TRC, CSV, MF4; .gz .xz .zst)",
    "tune": "propose thresholds from healthy logs and known faults, proven by replay",
    "simulate": "a simulated robot (ODrive axes + BMS) on a bus or into a candump -L log",
    "demo": "the simulated robot and the daemon on a virtual bus, with a live view (no hardware)",
    "init": "write a starter config, tree and DBC into a directory (e.g. /etc/canguard)",
    "unit": "print the systemd unit for this install (right ExecStart path)",
    "completion": "print a shell completion script (bash or zsh)",
}
"""Every subcommand and its one-line help, in the order ``canguard -h`` lists them (no module imported)."""


EXIT_CODES_EPILOG = "exit codes:\n" + "\n".join(f"  {code:<4} {text}" for code, text in EXIT_CODES)
"""The exit-code table printed at the end of every ``-h``."""


def default_config() -> Path:
    """``$CANGUARD_CONFIG``, else /etc/canguard/canguard.yaml when it exists, else the bundled config."""
    env = os.environ.get("CANGUARD_CONFIG")
    if env:
        return Path(env)
    etc = Path("/etc/canguard/canguard.yaml")
    return etc if etc.exists() else bundled_config()


def add_config(p: argparse.ArgumentParser) -> None:
    """``-c/--config``: the YAML config (default: :func:`default_config`)."""
    p.add_argument("-c", "--config", type=Path, default=None,
                   help="YAML config (default: $CANGUARD_CONFIG, /etc/canguard/canguard.yaml, "
                        "or the bundled config/canguard.yaml)")


def config_path(args: argparse.Namespace) -> Path:
    """The config a subcommand uses: ``-c`` or the default."""
    return args.config if args.config is not None else default_config()


def add_state_dir(p: argparse.ArgumentParser) -> None:
    """``--state-dir DIR``: the daemon's events and I²t state in DIR instead of where the config says."""
    p.add_argument("--state-dir", type=Path, default=None, metavar="DIR",
                   help="write the event journal and the I²t state file into DIR (the config's file names "
                        "kept), e.g. a trial run beside a service's own files; the bundled config's go to "
                        "$XDG_STATE_HOME/canguard (~/.local/state/canguard) unless this says otherwise")


def run_config(args: argparse.Namespace) -> tuple[Config, Path | None]:
    """The config ``canguard run`` (and ``check``, which judges it the same way) runs, and where it keeps its events
    and heat when not where the config says: ``--state-dir``, or, for the bundled config (inside the installed
    package: read-only material), the user's state directory."""
    from canguard.io.outputs import load_run_config, user_state_dir

    path = config_path(args)
    where = args.state_dir
    if where is None and args.config is None and path == bundled_config():
        where = user_state_dir()
    return load_run_config(path, where), where


def add_global_options(p: argparse.ArgumentParser, *, in_subcommand: bool) -> None:
    """``-v`` anywhere: a subcommand's count is ``sub_verbose``, added up by :func:`canguard.cli.main.parse_args`."""
    dest = "sub_verbose" if in_subcommand else "verbose"
    p.add_argument("-v", "--verbose", action="count", default=0, dest=dest, help="more log output (-vv: debug)")


def subcommand(sub: argparse._SubParsersAction, name: str, func: Callable[[argparse.Namespace], int],
               **kwargs: Any) -> argparse.ArgumentParser:
    """``sub.add_parser`` running ``func``, with the global options and the exit-code epilog every subcommand shares."""
    kwargs.setdefault("help", COMMANDS[name])
    p: argparse.ArgumentParser = sub.add_parser(name, epilog=EXIT_CODES_EPILOG,
                                                formatter_class=argparse.RawDescriptionHelpFormatter, **kwargs)
    add_global_options(p, in_subcommand=True)
    p.set_defaults(func=func)
    return p


def replace_once(text: str, pattern: str, repl: str, what: str) -> str:
    """``text`` of the packaged file ``what`` with its one line matching ``pattern`` replaced (else ConfigError)."""
    out, n = re.subn(pattern, repl, text, flags=re.M)
    if n != 1:
        raise ConfigError(f"the packaged {what} has {n} lines matching {pattern!r}, expected one: cannot fit it")
    return out


def per_log_path(base: Path | None, log: Path, many: bool) -> Path | None:
    """``--events out.jsonl`` for one log of several: ``out.<log name>.jsonl`` (as given for one log)."""
    if base is None or not many:
        return base
    return base.with_name(f"{base.stem}.{log.name}{base.suffix}")


BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""numpy's BLAS thread pools (OpenBLAS, OpenMP, MKL)."""


def one_blas_thread() -> None:
    """One thread per BLAS pool unless the user set one (block-sized work is never worth a pool); before numpy."""
    for name in BLAS_THREADS:
        os.environ.setdefault(name, "1")


class TappedSink:
    """A daemon's frame sink whose sends are shown to ``tap`` first (``--emit``'s recorder, the demo's stopwatch)."""

    def __init__(self, inner: Any, tap: Callable[[Any, str], None]) -> None:
        self.inner = inner
        self.tap = tap

    @property
    def sent(self) -> int:
        """Frames the inner sink put on the bus."""
        return int(self.inner.sent)

    def send(self, frames: Any, origin: str) -> None:
        """Show the frames to the tap, then send them."""
        self.tap(frames, origin)
        self.inner.send(frames, origin)


def add_monitor_options(p: argparse.ArgumentParser) -> None:
    """``--http HOST:PORT`` and ``--groot2 PORT``: the live monitors (``monitor:`` in the config)."""
    p.add_argument("--http", metavar="HOST:PORT",
                   help="serve the status page and its JSON API (e.g. 127.0.0.1:8470; config monitor.http); "
                        "a non-loopback address needs monitor.token")
    p.add_argument("--groot2", metavar="PORT",
                   help="serve Groot2's monitor (BehaviorTree.CPP's publisher protocol: ZeroMQ REP on PORT, PUB on "
                        "PORT+1; config monitor.groot2; needs the 'monitor' extra)")
