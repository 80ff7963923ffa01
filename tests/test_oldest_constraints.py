"""scripts/oldest-constraints.txt (for scripts/test-oldest.sh) pins what pyproject.toml says is the oldest it allows."""

from __future__ import annotations

import sys

from checkout import REPO

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    tomllib = None



def _dependencies() -> list[str]:
    text = (REPO / "pyproject.toml").read_text(encoding="utf-8")
    if tomllib is not None:
        deps: list[str] = tomllib.loads(text)["project"]["dependencies"]
        return deps
    block = text.split("dependencies = [", 1)[1].split("]", 1)[0]  # Python 3.10: no tomllib
    return [line.strip().strip(",").strip('"') for line in block.splitlines() if line.strip().startswith('"')]


def test_each_dependency_is_pinned_on_the_release_line_of_its_lower_bound() -> None:
    # packaging here, not at module level: every pytest-xdist worker imports this module at collection
    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name
    from packaging.version import Version

    pins = {}
    for line in (REPO / "scripts" / "oldest-constraints.txt").read_text(encoding="utf-8").splitlines():
        if line.strip() and not line.startswith("#"):
            name, version = line.split("==")
            pins[canonicalize_name(name)] = Version(version)
    bounds = {}
    for dep in _dependencies():
        req = Requirement(dep)
        [lower] = [Version(s.version) for s in req.specifier if s.operator == ">="]
        bounds[canonicalize_name(req.name)] = lower
    assert pins.keys() == bounds.keys()
    for name, lower in bounds.items():
        pin = pins[name]
        assert pin >= lower and pin.release[:len(lower.release)] == lower.release, (name, str(pin), str(lower))
