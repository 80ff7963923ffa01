"""Fleet replay workers: a worker keeps the run's config; the logs go largest first; same results.

``--jobs N`` forks its workers (Linux, from a process running one thread) after the parent loaded
the config, so no worker reads it again (spawned workers read it once); a Dask worker reads it
once per run (:class:`~canguard.cli.replay.ConfigRef`). The results stay those of a serial run,
in the order the logs were given, whatever order the workers took them in.
"""

from __future__ import annotations

import contextlib
import io
import json
import operator
import os
import shutil
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import pytest

import canguard.cli.fleet as fleet
import canguard.cli.replay as replay_cmd
from canguard.cli.common import BLAS_THREADS
from canguard.cli.fleet import _worker_start, run_processes
from canguard.cli.main import main
from canguard.config.schema import Config
from checkout import REPO

CONFIG = REPO / "config" / "examples" / "robot_guard.yaml"
EXAMPLES = sorted((REPO / "examples").glob("*.log.gz"))


@pytest.fixture(scope="module")
def mixed(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Example logs of different sizes, smallest first (the workers take them largest first); read only."""
    tmp_path = tmp_path_factory.mktemp("mixed")
    by_size = sorted(EXAMPLES, key=lambda p: p.stat().st_size)
    out = []
    for i, src in enumerate(by_size[:4]):
        dst = tmp_path / f"{i}-{src.name}"
        shutil.copy(src, dst)
        out.append(dst)
    assert len({p.stat().st_size for p in out}) > 1
    return out


def _run(argv: list[str], capsys: pytest.CaptureFixture[str] | None = None) -> str:
    """``canguard ARGV`` in-process; its stdout (``capsys``: this test's capture; None: captured here)."""
    if capsys is None:
        with contextlib.redirect_stdout(io.StringIO()) as out:
            code = main(argv)
        assert code in (0, 1)
        return out.getvalue()
    code = main(argv)
    captured = capsys.readouterr()
    assert code in (0, 1), captured.err
    return captured.out


@pytest.fixture(scope="module")
def serial(mixed: list[Path]) -> str:
    """The serial run's ``--json`` of the mixed logs: what every way of running them in workers must print."""
    return _run(["replay", *map(str, mixed), "-c", str(CONFIG), "--json"])


@dataclass(frozen=True)
class ForkedRun:
    """``replay MIXED... --jobs 2 --json`` in a fresh interpreter, as the ``canguard`` command runs it."""

    stdout: str
    record: list[str]
    """Each config load's path, then ``pool: <start method>`` and whether numpy was loaded when it was chosen."""


@pytest.fixture(scope="module")
def forked_run(mixed: list[Path], tmp_path_factory: pytest.TempPathFactory) -> ForkedRun:
    """One fresh, single-threaded interpreter runs the jobs (this test process may hold an earlier test's
    threads, and then its workers are spawned: :func:`canguard.cli.fleet._pool_context`).

    numpy is loaded before the pool is chosen (after one_blas_thread, as the command does): its BLAS
    pool must not make the process multi-threaded, or the workers would be spawned instead of forked.
    """
    record = tmp_path_factory.mktemp("forked") / "loads.txt"
    probe = (
        "import sys\n"
        "from canguard.cli.common import one_blas_thread\n"
        "one_blas_thread()\n"
        "import numpy\n"
        "import canguard.cli.replay as replay_cmd\n"
        "from canguard.cli.main import main\n"
        "real = replay_cmd.load_config\n"
        "def recording(path):\n"
        f"    with open({str(record)!r}, 'a', encoding='utf-8') as f:\n"
        "        f.write(f'{path}\\n')\n"
        "    return real(path)\n"
        "replay_cmd.load_config = recording\n"
        "import canguard.cli.fleet as fleet\n"
        "chosen = fleet._pool_context\n"
        "def telling():\n"
        "    context = chosen()\n"
        f"    with open({str(record)!r}, 'a', encoding='utf-8') as f:\n"
        "        f.write(f'pool: {context.get_start_method()}, numpy loaded: {\"numpy\" in sys.modules}\\n')\n"
        "    return context\n"
        "fleet._pool_context = telling\n"
        f"code = main(['replay', *{[str(p) for p in mixed]!r}, '-c', {str(CONFIG)!r}, '--json', '--jobs', '2'])\n"
        "assert replay_cmd._CONFIGS == {}, 'the parent kept the run config after it'\n"
        "sys.exit(code)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREADS}
    done = subprocess.run([sys.executable, "-W", "error::DeprecationWarning", "-c", probe], capture_output=True,
                          text=True, env=env, timeout=120)
    assert done.returncode in (0, 1), done.stderr[-2000:]
    return ForkedRun(done.stdout, record.read_text(encoding="utf-8").splitlines())


@pytest.mark.skipif(sys.platform != "linux", reason="workers are forked on Linux only")
def test_jobs_give_the_serial_results_in_input_order(mixed: list[Path], forked_run: ForkedRun, serial: str) -> None:
    """--jobs 2 prints the serial run's summaries byte for byte, in the order the logs were given."""
    assert forked_run.stdout == serial
    assert [s["log"] for s in json.loads(serial)] == [str(p) for p in mixed]


@pytest.mark.skipif(sys.platform != "linux", reason="workers are forked on Linux only")
def test_forked_workers_do_not_read_the_config_again(forked_run: ForkedRun) -> None:
    """Only the parent loads the config: a forked worker that loaded it would write a line to the record.

    The command forks them: one thread, numpy loaded included (no BLAS pool after one_blas_thread).
    """
    assert forked_run.record == [str(CONFIG), "pool: fork, numpy loaded: True"]


def test_a_worker_reads_the_config_once_per_run(monkeypatch: pytest.MonkeyPatch) -> None:
    loads: list[Path] = []
    real = replay_cmd.load_config

    def counting(path: str | Path) -> Config:
        loads.append(Path(path))
        return real(path)

    monkeypatch.setattr(replay_cmd, "load_config", counting)
    monkeypatch.setattr(replay_cmd, "_CONFIGS", {})
    first, second = replay_cmd.ConfigRef(CONFIG, "run-1"), replay_cmd.ConfigRef(CONFIG, "run-2")
    cfg = replay_cmd._config_of(first)
    assert replay_cmd._config_of(first) is cfg
    assert loads == [CONFIG]
    assert replay_cmd._config_of(second) is not cfg  # the next run reads the file again (it may have changed)
    assert loads == [CONFIG, CONFIG]
    assert list(replay_cmd._CONFIGS) == [second]  # one run's config kept, not every run's


def test_worker_start_keeps_blas_to_one_thread_unless_set(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in BLAS_THREADS:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    _worker_start()
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1" and os.environ["MKL_NUM_THREADS"] == "1"
    assert os.environ["OMP_NUM_THREADS"] == "3"


def test_a_canguard_process_starts_no_blas_thread_pool(tmp_path: Path) -> None:
    """A replay long enough to import numpy runs in one thread: OpenBLAS's pool (a thread per core, spinning
    beside the replay) is kept to one thread, unless the user asked for more."""
    log = tmp_path / "long.log"
    log.write_text("".join(f"({1700000000 + k / 1000:.6f}) can0 123#0011\n" for k in range(40_000)), encoding="ascii")
    probe = ("import os, sys\n"
             "from canguard.cli.main import main\n"
             f"code = main(['replay', {str(log)!r}, '-c', {str(CONFIG)!r}, '--json'])\n"
             "assert 'numpy' in sys.modules, 'the replay did not import numpy: this proves nothing'\n"
             "blas = os.environ.get('OPENBLAS_NUM_THREADS', 'unset')\n"
             "print(len(os.listdir('/proc/self/task')), blas, file=sys.stderr)\n")
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREADS}
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    threads, setting = done.stderr.split()[-2:]
    assert setting == "1" and threads == "1", done.stderr[-500:]


def test_run_processes_keeps_input_order_with_more_workers_than_jobs() -> None:
    """Four workers for three jobs: each result at its job's place (``warm`` is imported first when forked).

    The job is the standard library's (``operator.neg``): a spawned worker (this process runs other threads
    under pytest-xdist) unpickles it without importing this test module and all it imports."""
    assert run_processes(4, operator.neg, [3, 1, 2], warm=("json",)) == [-3, -1, -2]


def test_a_process_running_other_threads_spawns_its_workers(mixed: list[Path], serial: str,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """A program that calls canguard while another of its threads runs (a GUI's, a Dask client's) is not
    forked: a worker could inherit a lock that thread held and hang. Its workers are spawned, read the
    config themselves and give the serial results."""
    stop = threading.Event()
    other = threading.Thread(target=stop.wait, name="embedding-program")
    other.start()
    try:
        assert fleet._pool_context().get_start_method() == "spawn"
        spawned = _run(["replay", *map(str, mixed[:2]), "-c", str(CONFIG), "--json", "--jobs", "2"], capsys)
        assert json.loads(spawned) == json.loads(serial)[:2]  # each log's summary is its own
    finally:
        stop.set()
        other.join()
