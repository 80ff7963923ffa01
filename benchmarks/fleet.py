"""Suite ``fleet``: replaying many logs at once, ``--jobs 2`` and a Dask cluster, beside one process.

``LOGS`` copies of the simulator's log (scenarios normal + load), replayed by ``canguard replay DIR -c
config/canguard.yaml --json`` in one process (the peer), with ``--jobs 2`` (a process pool) and with
``--dask`` on a LocalCluster of 2 worker processes (started before the timing, shared by its rounds;
distributed's own CPU meanwhile counted). The three must print the same summaries. Best of N rounds.
"""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path
from typing import Any

from benchmarks import kit, shapes
from benchmarks.kit import Options, Table, Timing


def cluster_cpu(cluster: Any) -> float:
    """CPU seconds so far of a LocalCluster's worker and nanny processes (``/proc``)."""
    total = 0.0
    for worker in getattr(cluster, "workers", {}).values():
        pid = getattr(getattr(worker, "process", None), "pid", None)
        if pid:
            for p in (pid, *(int(c) for c in _children(pid))):
                with contextlib.suppress(OSError):  # ended meanwhile
                    total += kit.cpu_of(p)
    return total


def _children(pid: int) -> list[str]:
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return path.read_text().split() if path.exists() else []


def with_dask(argv: list[str], opts: Options, rounds: int) -> Timing | None:
    """``argv --dask ADDRESS`` on a 2-worker LocalCluster, best of ``rounds``; None when distributed is missing."""
    try:
        from distributed import LocalCluster
    except ImportError:
        return None
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      host="127.0.0.1") as cluster:
        def once() -> Timing:
            before = cluster_cpu(cluster)
            t = kit.canguard([*argv, "--dask", cluster.scheduler_address], opts)
            return Timing(t.wall_s, t.cpu_s + cluster_cpu(cluster) - before, t.out)
        return kit.best_of([once], rounds)[0]


def run(opts: Options) -> Table:
    """The fleet table: each way beside one process, worst (lowest × one process) first."""
    logs, frames = (2, 500) if opts.quick else (4, 600_000)
    rounds = 1 if opts.quick else opts.rounds
    table = Table("fleet", f"{logs} logs of the simulator ({frames:,} frames each) replayed at once, beside one "
                  f"process replaying them in turn; best of {rounds}",
                  ["run", "logs", "frames", "canguard s", "CPU s", "one process s", "× one process"],
                  costs=["canguard s"])
    with kit.scratch("fleet") as d:
        work = Path(d)
        src = shapes.own_shape(frames)
        for i in range(logs):
            shutil.copy(src.log, work / f"log{i}.log")
        argv = ["replay", str(work), "-c", str(kit.CONFIG), "--json"]
        serial, jobs = kit.best_of([lambda: kit.canguard(argv, opts),
                                    lambda: kit.canguard([*argv, "--jobs", "2"], opts)], rounds)
        if jobs.out != serial.out:
            raise RuntimeError("--jobs 2 printed other summaries than one process")
        total = logs * src.frames
        rows: list[list[kit.Cell]] = [
            ["--jobs 2 (process pool)", logs, total, jobs.wall_s, jobs.cpu_s, serial.wall_s,
             kit.ratio(serial.wall_s, jobs.wall_s)]]
        dask = None if opts.quick else with_dask(argv, opts, rounds)
        if dask is not None:
            if dask.out != serial.out:
                raise RuntimeError("--dask printed other summaries than one process")
            rows.append(["--dask (LocalCluster, 2 workers)", logs, total, dask.wall_s, dask.cpu_s, serial.wall_s,
                         kit.ratio(serial.wall_s, dask.wall_s)])
        rows.sort(key=lambda r: r[-1] if isinstance(r[-1], float) else 0.0)
        rows.append(["one process (the peer)", logs, total, serial.wall_s, serial.cpu_s, serial.wall_s, 1.0])
    table.rows = rows
    table.notes.append("× one process: one process's wall time over this run's (2 workers at best: 2)")
    if opts.quick:
        table.notes.append("--quick: tiny logs in this process, no Dask cluster (starting one costs ~3 CPU-s): checks "
                           "that the suite runs")
    elif dask is None:
        table.notes.append("Dask: distributed not installed (pip install -e '.[fleet]'): not measured")
    table.notes.append("CPU s: the replay, its pool and (Dask) the cluster's workers meanwhile")
    return table
