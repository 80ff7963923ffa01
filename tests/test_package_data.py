"""Bundled data resolves through importlib.resources."""

from __future__ import annotations

from canguard.data import data_path


def test_bundled_files_resolve_through_the_package() -> None:
    for parts in [
        ("config", "canguard.yaml"),
        ("config", "examples", "robot_guard.yaml"),
        ("config", "trees", "robot_guard.xml"),
        ("dbc", "robot.dbc"),
        ("systemd", "canguard.service"),
    ]:
        path = data_path(*parts)
        assert path.is_file(), path
        assert path.read_text(encoding="utf-8").strip()


def test_cli_defaults_come_from_the_package_not_the_checkout() -> None:
    from canguard.cli.common import bundled_config
    from canguard.cli.demo import DEMO_CONFIG

    for path in (bundled_config(), DEMO_CONFIG):
        assert path.is_file(), path
        assert "canguard/data/config" in path.as_posix(), path
