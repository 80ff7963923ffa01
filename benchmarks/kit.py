"""What every suite shares: the table and its header, timing a command, the canguard tree timed, child processes.

A suite is a function ``run(opts) -> Table``. Every figure of canguard sits in a row beside its peer
measured in the same run; :func:`render` prints the table as markdown under one header line (date,
commit, machine, command), :func:`as_json` the same as a document.
"""

from __future__ import annotations

import compileall
import contextlib
import datetime
import io
import os
import platform
import random
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"
CONFIG = REPO / "config" / "canguard.yaml"
DBC = REPO / "dbc" / "robot.dbc"

Cell = str | int | float | None


@dataclass
class Options:
    """How a suite runs: ``quick`` (tiny sizes, one round, in-process where a whole process adds nothing to
    check), the canguard source tree it times, and rounds (best of N)."""

    quick: bool = False
    src: Path = SRC
    rounds: int = 3

    @property
    def inprocess(self) -> bool:
        """Quick runs call canguard's entry point in this process: the same command, without a new interpreter."""
        return self.quick


@dataclass
class Table:
    """One suite's table: ``columns``, rows worst case first, notes under it.

    ``costs`` names the columns that measure canguard (seconds, µs, ms: lower is better): ``--ab`` compares those
    between two revisions, the other columns are the peers and ratios of one run."""

    suite: str
    title: str
    columns: list[str]
    rows: list[list[Cell]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    costs: list[str] = field(default_factory=list)
    failed: str = ""  # what failed (a check of the suite's own), shown under the table; the runner exits 1

    def row_dicts(self) -> list[dict[str, Cell]]:
        """The rows as {column: cell}."""
        return [dict(zip(self.columns, row, strict=True)) for row in self.rows]


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return ""


def commit() -> str:
    """The checkout's short commit, ``+changes`` when src/ or benchmarks/ differ from it."""
    head = _git("rev-parse", "--short", "HEAD") or "unknown"
    return head + ("+changes" if _git("status", "--porcelain", "--", "src", "benchmarks") else "")


def machine() -> dict[str, Any]:
    """Cores, load average (1, 5, 15 min) now, CPU model, Python and the platform."""
    model = ""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    return {"cores": os.cpu_count(), "load_avg": [round(x, 2) for x in os.getloadavg()], "cpu": model,
            "python": platform.python_version(), "platform": platform.platform(terse=True)}


def meta(command: Sequence[str]) -> dict[str, Any]:
    """The header every table carries; taken when the suite starts."""
    return {"date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "commit": commit(), "machine": machine(), "command": " ".join(command)}


def fmt(cell: Cell) -> str:
    """A cell as the table shows it."""
    if cell is None:
        return "—"
    if isinstance(cell, float):
        if cell != cell:  # NaN
            return "—"
        return f"{cell:,.0f}" if abs(cell) >= 1000 else f"{cell:.3g}" if abs(cell) < 10 else f"{cell:.1f}"
    if isinstance(cell, int):
        return f"{cell:,}"
    return cell


def render(head: dict[str, Any], table: Table) -> str:
    """The table as markdown, under its header line."""
    m = head["machine"]
    load = " / ".join(f"{x:.2f}" for x in m["load_avg"])
    lines = [f"**{table.suite}**: {table.title}", "",
             f"{head['date']}, commit {head['commit']}, {m['cores']} cores ({m['cpu'] or 'cpu unknown'}), load average "
             f"{load} at start, Python {m['python']}; `{head['command']}`", "",
             "| " + " | ".join(table.columns) + " |",
             "| " + " | ".join("---" if i == 0 else "---:" for i in range(len(table.columns))) + " |"]
    lines += ["| " + " | ".join(fmt(c) for c in row) + " |" for row in table.rows]
    lines += [""] + [f"- {note}" for note in table.notes]
    if table.failed:
        lines.append(f"- **FAILED**: {table.failed}")
    return "\n".join(lines).rstrip() + "\n"


def as_json(head: dict[str, Any], table: Table) -> dict[str, Any]:
    """The table as a JSON document: the header, the columns, the rows as objects, the notes."""
    return {**head, "suite": table.suite, "title": table.title, "columns": table.columns, "costs": table.costs,
            "rows": table.row_dicts(), "notes": table.notes, "failed": table.failed}


def ratio(num: float | None, den: float | None) -> float | None:
    """``num / den``, None where either is missing or ``den`` is 0."""
    return None if num is None or den is None or den == 0 else num / den


def percentile(samples: Sequence[float], q: float) -> float:
    """The ``q`` quantile (0..1) of ``samples``, nearest rank."""
    s = sorted(samples)
    return s[min(len(s) - 1, round(q * (len(s) - 1)))]


def median(samples: Sequence[float]) -> float:
    """The median."""
    return statistics.median(samples)


# -- the canguard tree timed ---------------------------------------------------------------------------------
def compiled(src: Path) -> Path:
    """``src`` with its bytecode written, as ``pip install`` writes it for a wheel; returns ``src``.

    Without it each timed process would compile canguard from source where the environment sets
    PYTHONDONTWRITEBYTECODE=1 (up to 90 ms a process, counted against canguard only)."""
    if not compileall.compile_dir(str(src), quiet=1, workers=1):
        raise SystemExit(f"{src}: compileall failed")
    return src


def export(rev: str, into: Path) -> Path:
    """``src/`` of git revision ``rev`` (``git archive``) under ``into``, compiled; returns that src."""
    proc = subprocess.run(["git", "archive", "--format=tar", rev, "src"], cwd=REPO, capture_output=True)
    if proc.returncode != 0:
        raise SystemExit(f"--ab {rev}: git archive failed: {proc.stderr.decode().strip()}")
    with tarfile.open(fileobj=io.BytesIO(proc.stdout)) as tar:
        tar.extractall(into, filter="data") if hasattr(tarfile, "data_filter") else tar.extractall(into)
    return compiled(into / "src")


def child_env(src: Path, **extra: str) -> dict[str, str]:
    """The environment of a child process: ``src`` first on PYTHONPATH, no systemd variables but ``extra``."""
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(src), env.get("PYTHONPATH", "")) if p)
    env.update(extra)
    return env


# -- timing a command ----------------------------------------------------------------------------------------
@dataclass
class Timing:
    """Wall and CPU seconds (user + system, the process and its reaped children) of one run, and its stdout."""

    wall_s: float
    cpu_s: float
    out: bytes = b""


def _cpu_now() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def process(cmd: Sequence[str], src: Path, stdin: Path | None = None, ok: tuple[int, ...] = (0, 1)) -> Timing:
    """``cmd`` as a whole process (interpreter start-up included) with ``src`` on PYTHONPATH; its own CPU
    (``wait4``: this child's alone)."""
    with open(stdin or os.devnull, "rb") as inp, tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(list(cmd), stdin=inp, stdout=out, stderr=err, env=child_env(src))
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = code = os.waitstatus_to_exitcode(status)
        err.seek(0)
        if code not in ok:
            raise RuntimeError(f"{' '.join(cmd)}: exit {code}: {err.read().decode()[-2000:]}")
        out.seek(0)
        return Timing(wall, usage.ru_utime + usage.ru_stime, out.read())


@contextlib.contextmanager
def _captured() -> Iterator[io.BytesIO]:
    buf = io.BytesIO()
    text = io.TextIOWrapper(buf, encoding="utf-8", write_through=True)
    old_out, old_err = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = text, io.StringIO()
    try:
        yield buf
    finally:
        text.flush()
        sys.stdout, sys.stderr = old_out, old_err
        text.detach()


def in_process(call: Callable[[], int | None], ok: tuple[int, ...] = (0, 1)) -> Timing:
    """``call`` in this process, its stdout captured; CPU of this process and the children it reaped meanwhile."""
    cpu0, t0 = _cpu_now(), time.perf_counter()
    with _captured() as buf:
        try:
            code = call() or 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
    wall, cpu = time.perf_counter() - t0, _cpu_now() - cpu0
    if code not in ok:
        raise RuntimeError(f"in-process call exited {code}")
    return Timing(wall, cpu, buf.getvalue())


def canguard(argv: Sequence[str], opts: Options) -> Timing:
    """``canguard ARGV``: a whole ``python -m canguard`` process, or (quick) its entry point in this process."""
    if opts.inprocess:
        from canguard.cli.main import main

        return in_process(lambda: main(list(argv)))
    return process([sys.executable, "-m", "canguard", *argv], opts.src)


def python(code: str, args: Sequence[str], opts: Options) -> Timing:
    """``python -c CODE ARGS``: a whole process, or (quick) the code run in this process with ``sys.argv`` set."""
    if opts.inprocess:
        def call() -> None:
            old = sys.argv
            sys.argv = ["-c", *args]
            try:
                exec(compile(code, "<peer>", "exec"), {"__name__": "__main__"})
            finally:
                sys.argv = old
        return in_process(call)
    return process([sys.executable, "-c", code, *args], opts.src)


def best_of(runs: Sequence[Callable[[], Timing]], rounds: int) -> list[Timing]:
    """Each of ``runs`` ``rounds`` times, taking turns in every round (so all meet the same machine); the best
    wall and the best CPU of each, and the output of its last run."""
    best = [Timing(float("inf"), float("inf"))] * len(runs)
    for _ in range(rounds):
        for k, run in enumerate(runs):
            t = run()
            best[k] = Timing(min(best[k].wall_s, t.wall_s), min(best[k].cpu_s, t.cpu_s), t.out)
    return best


# -- child processes --------------------------------------------------------------------------------------
def multicast_bus(rnd: random.Random | None = None) -> dict[str, Any]:
    """A udp_multicast bus of this run's own (group and port drawn at random)."""
    r = rnd or random.Random()
    return {"interface": "udp_multicast", "channel": f"239.{r.randint(1, 254)}.{r.randint(1, 254)}.{r.randint(1, 254)}",
            "port": r.randint(20000, 60000)}


def write_config(tmp: Path, bus: dict[str, Any], monitor: dict[str, Any] | None = None) -> Path:
    """The bundled config on ``bus``, with absolute paths and events / state in ``tmp`` (and ``monitor:``)."""
    import yaml

    doc = yaml.safe_load(CONFIG.read_text(encoding="utf-8"))
    doc["dbc"] = [str(DBC)]
    doc["tree"]["file"] = str((CONFIG.parent / doc["tree"]["file"]).resolve())
    doc["buses"] = {"main": bus}
    doc["events"] = str(tmp / "events.jsonl")
    doc["state"]["file"] = str(tmp / "i2t_state.json")
    if monitor:
        doc["monitor"] = monitor
    path = tmp / "canguard.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def stop_process(proc: subprocess.Popen[Any], timeout_s: float = 10.0) -> int:
    """SIGTERM, as systemd stops a service; killed when it has not ended within ``timeout_s``; its exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout_s)
    return proc.returncode


def clean_up_on_sigterm() -> None:
    """A SIGTERM (a CI timeout, ``kill``) ends the runner as an exception would: its ``finally`` blocks stop the
    daemons and load generators it started, which would otherwise load every later measurement."""
    signal.signal(signal.SIGTERM, lambda signum, _frame: sys.exit(128 + signum))


def cpu_of(pid: int) -> float:
    """CPU seconds (user + system) of process ``pid`` so far (``/proc/PID/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def vmrss_mb(pid: int) -> float:
    """VmRSS of ``pid`` in MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def which(tool: str) -> str | None:
    """The path of ``tool``, None when it is not installed."""
    return shutil.which(tool)


def scratch(prefix: str) -> tempfile.TemporaryDirectory[str]:
    """A temporary directory of this run's own."""
    return tempfile.TemporaryDirectory(prefix=f"canguard-bench-{prefix}-")


def from_json(doc: dict[str, Any]) -> tuple[dict[str, Any], Table]:
    """The header and table :func:`as_json` wrote."""
    head = {k: doc[k] for k in ("date", "commit", "machine", "command")}
    columns = list(doc["columns"])
    table = Table(doc["suite"], doc["title"], columns, [[row.get(c) for c in columns] for row in doc["rows"]],
                  list(doc["notes"]), list(doc["costs"]), doc.get("failed", ""))
    return head, table
