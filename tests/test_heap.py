"""A replay keeps its freed memory until it ends (canguard.cli.heap).

Dask starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536``; in such a process every large
buffer a replay frees is given back and faulted in again. These tests run a process with that
variable, as Dask's nanny does, and count its page faults.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from canguard.cli import heap

CHURN = textwrap.dedent("""
    import json, resource, sys
    from canguard.cli.heap import keep_freed_memory

    def churn():
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        for _ in range(200):
            buf = bytearray(1 << 20)  # 1 MiB, freed at once: 256 pages each time when given back
            del buf
        return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

    outside = churn()
    with keep_freed_memory():
        inside = churn()
    after = churn()
    print(json.dumps({"outside": outside, "inside": inside, "after": after}))
""")


def _faults(env_extra: dict[str, str]) -> dict[str, int]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    env.update(env_extra)
    out = subprocess.run([sys.executable, "-c", CHURN], capture_output=True, text=True, env=env, timeout=60,
                         check=True)
    return json.loads(out.stdout)  # type: ignore[no-any-return]


@pytest.mark.skipif(not sys.platform.startswith("linux") or heap._glibc() is None, reason="glibc's mallopt only")
class TestKeepFreedMemory:
    def test_dask_environment(self) -> None:
        """With Dask's variable: inside the scope freed buffers are reused (few faults); after it, the
        process gives memory back again, as Dask asked."""
        got = _faults({"MALLOC_TRIM_THRESHOLD_": "65536"})
        assert got["outside"] > 200 * 200, got  # each 1 MiB buffer faulted in again
        assert got["inside"] < got["outside"] / 20, got
        assert got["after"] > 200 * 200, got  # the environment's thresholds are back

    def test_thresholds_put_back(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """The scope raises the thresholds once for replays at once, and puts back the environment's, else
        glibc's defaults, when the last ends."""
        calls: list[tuple[str, tuple[int, ...]]] = []

        class Spy:
            def mallopt(self, *a: int) -> int:
                calls.append(("mallopt", a))
                return 1

            def malloc_trim(self, *a: int) -> int:
                calls.append(("malloc_trim", a))
                return 1

        spy = Spy()
        monkeypatch.setattr(heap, "_glibc", lambda: spy)
        monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
        monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
        with heap.keep_freed_memory():
            pass
        assert calls[2:] == [("mallopt", (heap.M_MMAP_THRESHOLD, heap.DEFAULT_THRESHOLD)),
                             ("mallopt", (heap.M_TRIM_THRESHOLD, heap.DEFAULT_THRESHOLD)), ("malloc_trim", (0,))]
        calls.clear()
        monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")
        with heap.keep_freed_memory(), heap.keep_freed_memory():  # two replays at once (threads of one worker)
            assert [c[0] for c in calls] == ["mallopt", "mallopt"]
        assert calls[2:] == [("mallopt", (heap.M_MMAP_THRESHOLD, heap.DEFAULT_THRESHOLD)),
                             ("mallopt", (heap.M_TRIM_THRESHOLD, 65536)), ("malloc_trim", (0,))]
