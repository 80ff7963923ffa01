"""canguard.cli.deferred: a deferred module is the module, only loaded later (a package of our own, in a temp dir)."""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from canguard.cli.deferred import defer


@pytest.fixture
def package(tmp_path: Path) -> Iterator[str]:
    """A package ``cg_defer_probe`` with a slow module ``slow`` (its code sleeps 0.3 s, then defines VALUE)."""
    root = tmp_path / "cg_defer_probe"
    root.mkdir()
    (root / "__init__.py").write_text("LOADS = []\nfrom . import slow, broken\n", encoding="utf-8")
    (root / "slow.py").write_text(
        "import time\nimport cg_defer_probe\ncg_defer_probe.LOADS.append('slow')\ntime.sleep(0.3)\nVALUE = 42\n",
        encoding="utf-8")
    (root / "broken.py").write_text("import cg_defer_probe\ncg_defer_probe.LOADS.append('broken')\n1 / 0\n",
                                    encoding="utf-8")
    sys.path.insert(0, str(tmp_path))
    try:
        yield "cg_defer_probe"
    finally:
        sys.path.remove(str(tmp_path))
        for name in [m for m in sys.modules if m.split(".")[0] == "cg_defer_probe"]:
            del sys.modules[name]


def test_two_threads_first_use_both_get_the_value_and_the_code_runs_once(package: str) -> None:
    assert defer(f"{package}.slow") and defer(f"{package}.broken")
    import cg_defer_probe  # type: ignore[import-not-found]

    assert cg_defer_probe.LOADS == []  # the package imported both: neither ran
    got: list[object] = []

    def use() -> None:
        try:
            got.append(cg_defer_probe.slow.VALUE)
        except AttributeError as exc:  # what a half-run module would give the second thread
            got.append(exc)

    threads = [threading.Thread(target=use) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert got == [42, 42]
    assert cg_defer_probe.LOADS == ["slow"]


def test_a_module_that_fails_raises_at_each_use_as_an_import_would(package: str) -> None:
    assert defer(f"{package}.broken")
    import cg_defer_probe

    for _ in range(2):
        with pytest.raises(ZeroDivisionError):
            _ = cg_defer_probe.broken.anything
    assert cg_defer_probe.LOADS == ["slow", "broken", "broken"]


def test_nothing_is_deferred_once_the_package_is_imported_or_when_there_is_no_such_module(package: str) -> None:
    assert not defer(f"{package}.nothing_here")
    assert not defer("no_such_package_anywhere.mod")
    assert defer(f"{package}.broken")
    import cg_defer_probe

    assert not defer(f"{package}.slow")
    assert cg_defer_probe.slow.VALUE == 42


def test_a_module_with_its_own_getattr_keeps_it_and_runs_once(package: str, tmp_path: Path) -> None:
    """A deferred module that defines a module ``__getattr__`` (PEP 562) answers through it, from the first use."""
    root = tmp_path / package  # the fixture's package
    (root / "lazy.py").write_text(
        "import cg_defer_probe\ncg_defer_probe.LOADS.append('lazy')\n"
        "def __getattr__(name):\n    if name == 'ANSWER':\n        return 42\n"
        "    raise AttributeError(name)\n", encoding="utf-8")
    (root / "__init__.py").write_text("LOADS = []\nfrom . import lazy\n", encoding="utf-8")
    assert defer(f"{package}.lazy")
    import cg_defer_probe

    assert cg_defer_probe.LOADS == []
    assert cg_defer_probe.lazy.ANSWER == 42  # the first use: through the module's own __getattr__
    assert cg_defer_probe.lazy.ANSWER == 42
    with pytest.raises(AttributeError):
        _ = cg_defer_probe.lazy.missing
    assert cg_defer_probe.LOADS == ["lazy"]
