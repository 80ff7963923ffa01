"""Fleet replay: which logs a ``canguard replay`` names, and running them on a Dask cluster."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from canguard.errors import ConfigError
from canguard.io.bagopts import is_bag
from canguard.io.logs import LOG_SUFFIXES
from canguard.io.logtypes import COMPRESSIONS


def expand_logs(given: Sequence[Path]) -> list[Path]:
    """The log files ``given`` names, in order: directories, globs and ``@LIST`` files expanded; ConfigError naming
    what matched nothing (a missing plain file is left for the reader to name)."""
    out: list[Path] = []
    for item in given:
        text = str(item)
        if text == "-":
            out.append(item)
        elif text.startswith("@"):
            out.extend(_read_list(Path(text[1:])))
        elif item.is_dir() and is_bag(item):
            out.append(item)  # a rosbag2 directory: one log
        elif item.is_dir():
            files = [p for p in item.rglob("*") if p.is_file()]
            bags = {p.parent for p in files if p.name == "metadata.yaml"}
            endings = tuple(s + comp for comp in ("", *COMPRESSIONS) for s in LOG_SUFFIXES)  # of a log file name
            found = sorted([*bags, *(p for p in files if p.name.lower().endswith(endings)
                                     and not bags.intersection(p.parents))])
            if not found:
                raise ConfigError(f"replay: {item}: no log files in the directory (expected {', '.join(LOG_SUFFIXES)}, "
                                  f"optionally + {' / '.join(COMPRESSIONS)})")
            out.extend(found)
        elif any(ch in text for ch in "*?[") and not item.exists():
            import glob

            found = sorted(Path(p) for p in glob.glob(text, recursive=True) if Path(p).is_file())
            if not found:
                raise ConfigError(f"replay: {text}: the pattern matches no file")
            out.extend(found)
        else:
            out.append(item)
    return out


def _read_list(path: Path) -> list[Path]:
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"replay: @{path}: cannot read the list of logs: {exc}") from None
    out = []
    for line in lines:
        entry = line.split("#", 1)[0].strip()
        if entry:
            out.append(path.parent / entry)  # an absolute entry as it is
    if not out:
        raise ConfigError(f"replay: @{path}: the list names no log")
    return out


def _collect(futures: Iterable[Any], index: Callable[[Any], int], total: int) -> list[Any]:
    """The futures' results in input order (``index``: a future's place); ``N of M logs`` on a terminal's stderr."""
    results: list[Any] = [None] * total
    for done, future in enumerate(futures, 1):
        results[index(future)] = future.result()
        if sys.stderr.isatty() and total > 1:
            print(f"\rcanguard replay: {done} of {total} logs", end="\n" if done == total else "", file=sys.stderr,
                  flush=True)
    return results


def run_dask(address: str, job: Callable[[Any], Any], jobs: list[Any]) -> list[Any]:
    """Run ``job`` over ``jobs`` on the Dask scheduler at ``address``; results in the order of ``jobs``. ConfigError
    when the ``fleet`` extra is missing or the scheduler cannot be reached."""
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise ConfigError("--dask: running on a Dask cluster needs the fleet extra: "
                          "pip install 'canguard[fleet]'") from None
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT)
    except (OSError, TimeoutError) as exc:
        raise ConfigError(f"--dask {address}: cannot reach the scheduler: {exc}") from None
    try:
        futures = client.map(job, jobs, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        return _collect(as_completed(futures), lambda f: index[f.key], len(jobs))
    finally:
        client.close()


def _pool_context() -> Any:
    """How ``--jobs`` starts its workers: 'fork' on Linux while this process runs one thread (they inherit the
    loaded config), else 'spawn' (a forked child of a threaded process can hang on a lock copied while held).
    Threads as the kernel counts them: C libraries' included."""
    import multiprocessing
    import os

    try:
        threads = len(os.listdir("/proc/self/task"))
    except OSError:
        threads = 0  # no /proc: spawn, always safe
    return multiprocessing.get_context("fork" if sys.platform == "linux" and threads == 1 else "spawn")


CONNECT_TIMEOUT = "10s"
"""How long ``--dask ADDRESS`` tries to reach the scheduler before the run is refused (exit 2)."""


def _worker_start() -> None:
    """A --jobs worker: no BLAS thread pool, and (spawned) the same deferred imports as the command."""
    from canguard.cli.common import one_blas_thread
    from canguard.cli.deferred import defer_unused

    one_blas_thread()
    defer_unused()


def run_processes(workers: int, job: Callable[[Any], Any], jobs: list[Any],
                  warm: Sequence[str] = ()) -> list[Any]:
    """Run ``job`` over ``jobs`` in ``workers`` local processes; results in the order of ``jobs``. ``warm``: modules
    every job imports, imported here first when the workers are forked (once, not per worker)."""
    import gc
    import importlib
    from concurrent.futures import ProcessPoolExecutor, as_completed

    context = _pool_context()
    if context.get_start_method() == "fork":
        for name in warm:
            importlib.import_module(name)
        gc.freeze()  # the collector would otherwise write to (and so copy) every inherited page
    try:
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=context,
                                 initializer=_worker_start) as executor:
            futures = {executor.submit(job, j): i for i, j in enumerate(jobs)}
            return _collect(as_completed(futures), futures.__getitem__, len(jobs))
    finally:
        gc.unfreeze()
