"""Running ``canguard`` in-process in tests: exit code, stdout and stderr."""

from __future__ import annotations

import pytest

from canguard.cli.main import main


def cli(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str, str]:
    """``canguard *argv`` in-process: (exit code, stdout, stderr); argparse's exits become codes."""
    capsys.readouterr()
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    out, err = capsys.readouterr()
    return code, out, err
