"""Files canguard writes: can they be written there? Asked before anything runs, answered in words.

One line naming the path and what is wrong, never a traceback half-way; found by trying (root ignores permission
bits), nothing left behind.
"""

from __future__ import annotations

import dataclasses
import errno
import os
import stat
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from canguard.errors import ConfigError

if TYPE_CHECKING:
    from canguard.config.schema import Config


def _user(uid: int) -> str:
    """The name of user ``uid`` (its number when it has none, e.g. a systemd dynamic user that has gone)."""
    try:
        import pwd

        return pwd.getpwuid(uid).pw_name
    except (ImportError, KeyError):
        return str(uid)


def _whose(path: Path) -> str:
    """``: PATH belongs to root (mode 0755) and canguard runs as alice``: what a refused permission depends on."""
    try:
        st = path.stat()
    except OSError:
        return ""
    return (f": {path} belongs to {_user(st.st_uid)} (mode {stat.S_IMODE(st.st_mode):04o}) and canguard runs as "
            f"{_user(os.geteuid())}")


def _new_file_problem(directory: Path, target: Path) -> str:
    """Why ``directory`` takes no new file (or, when it is not ``target``'s parent, no new directory)."""
    if not directory.is_dir():
        return f"{directory} is a file, expected a directory"
    try:
        fd, probe = tempfile.mkstemp(prefix=".canguard-probe-", dir=directory)
    except OSError as exc:
        what = "its directory" if directory == target.parent else f"the directories up to {target.parent}"
        reason = exc.strerror or str(exc)
        if exc.errno in (errno.EACCES, errno.EPERM):
            return f"{what} cannot be written: {reason}{_whose(directory)}"
        return f"{what} cannot be written ({directory}: {reason})"
    os.close(fd)
    os.unlink(probe)
    return ""


def _append_problem(path: Path) -> str:
    """Why the existing regular file ``path`` cannot be appended to, with whose it is and the ways out."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CLOEXEC)
    except OSError as exc:
        reason = exc.strerror or str(exc)
        if exc.errno not in (errno.EACCES, errno.EPERM):
            return f"it cannot be opened for writing ({reason})"
        me = _user(os.geteuid())
        return (f"it cannot be appended to ({reason}){_whose(path)}; move it aside (sudo mv {path} "
                f"{path}.old) or give it to {me} (sudo chown {me} {path})")
    os.close(fd)
    return ""


def output_problem(path: Path, *, beside: bool = False, makes_dirs: bool = False) -> str:
    """Why canguard cannot write ``path`` ("" when it can), found by trying; ``makes_dirs``/``beside``: the writer's."""
    path = Path(os.path.abspath(path))
    if path.is_dir():
        return "it is a directory, expected a file path"
    if path.exists():
        if not path.is_file():
            return ""  # a device or a FIFO: opening one to try it could block or consume
        why = _append_problem(path)
        if why or not beside:
            return why
    ancestor = path.parent  # the nearest that exists (``/`` at worst)
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if ancestor != path.parent and ancestor.is_dir() and not makes_dirs:
        return f"its directory {path.parent} does not exist"
    return _new_file_problem(ancestor, path)


def check_output(path: Path | None, flag: str, *, beside: bool = False, makes_dirs: bool = False,
                 expected: str = "") -> None:
    """:class:`ConfigError` naming ``flag`` and ``path`` when a command cannot write it (:func:`output_problem`)."""
    if path is None:
        return
    why = output_problem(path, beside=beside, makes_dirs=makes_dirs)
    if why:
        raise ConfigError(f"{flag} {path}: cannot be written: {why}" + (f"; expected {expected}" if expected else ""))


def check_config_outputs(cfg: Config) -> None:
    """One :class:`ConfigError` listing each file the config makes the daemon write that cannot be written."""
    problems = []
    for key, path, what in (
        ("events", cfg.events, "the event journal would be lost"),
        ("state.file", cfg.state.file, "the I²t heat would be lost at the next restart"),
    ):
        if path is None:
            continue
        why = output_problem(path, beside=True, makes_dirs=True)
        if why:
            problems.append(f"{cfg.path}: {key}: {path}: cannot be written, {what}: {why} (or write it elsewhere: "
                            "run --state-dir DIR)")
    if problems:
        raise ConfigError(problems)


def load_run_config(path: Path, state_dir: Path | None) -> Config:
    """The config at ``path`` as ``canguard run`` runs it (and ``check`` judges it): with ``state_dir``, its event
    journal and I²t state file there, their names kept."""
    from canguard.config.loader import load_config

    cfg = load_config(path)
    if state_dir is None:
        return cfg
    where = Path(os.path.abspath(state_dir))
    state = cfg.state if cfg.state.file is None else dataclasses.replace(cfg.state, file=where / cfg.state.file.name)
    return dataclasses.replace(cfg, events=None if cfg.events is None else where / cfg.events.name, state=state)


def user_state_dir() -> Path:
    """``$XDG_STATE_HOME/canguard`` (if absolute), else ``~/.local/state/canguard``; ConfigError without a home."""
    xdg = os.environ.get("XDG_STATE_HOME", "")
    if xdg and os.path.isabs(xdg):
        return Path(xdg) / "canguard"
    try:
        return Path.home() / ".local" / "state" / "canguard"
    except RuntimeError:
        raise ConfigError("no home directory to keep the bundled config's events and I²t state in "
                          "(~/.local/state/canguard): set XDG_STATE_HOME, or give --state-dir DIR or -c CONFIG"
                          ) from None
