"""YAML config -> frozen dataclasses, validated once."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any

import yaml

from canguard.config import sections
from canguard.config.dbc import Messages
from canguard.config.monitor import read_monitor
from canguard.config.node_ids import RESERVED_NODE_IDS
from canguard.config.schema import Config, PartialConfig
from canguard.config.yamlsrc import Checks, load_yaml
from canguard.errors import ConfigError


def _config(c: Checks, path: Path, doc: Any) -> Config:
    """The config of ``doc`` (the file at ``path`` read as YAML), every section checked; ConfigError as below."""
    top = ("dbc", "buses", "canopen", "sources", "tree", "task", "stop", "actions", "events", "state",
           "simulation", "monitor")
    # dbc: is optional when the drives come from canopen: (every source and frame may then use them)
    required = ("buses",) if isinstance(doc, dict) and "canopen" in doc else ("dbc", "buses")
    if not c.mapping(doc, "", top, required):
        raise c.fail()
    m = Messages(c)
    dbc_files = m.load_dbc(doc["dbc"]) if "dbc" in doc else ()
    buses = sections.buses(c, doc["buses"]) if "buses" in doc else {}
    if "canopen" in doc:
        from canguard.config.canopen import CanopenSection

        m.canopen = CanopenSection(c)
        m.canopen.load(doc["canopen"])
    read = sections.read_sources(c, m, doc.get("sources"))
    if m.canopen is not None:
        m.add(m.canopen.messages())
    tree = sections.tree(c, doc.get("tree"))
    task = sections.task(c, m, doc.get("task"))
    stop = sections.stop(c, m, doc.get("stop"), read)
    actions = sections.actions(c, m, doc.get("actions"))
    events = c.file_path(doc["events"], "events") if doc.get("events") is not None else None
    state = sections.state(c, doc.get("state"))
    monitor = read_monitor(c, doc.get("monitor"))
    simulation = c.choice(doc, "simulation", "", (True, False), False)
    sources = MappingProxyType(dict(read.sources))
    if c.problems:  # what is sound enough to check the tree against goes with the error
        err = c.fail()
        named = doc.get("sources")
        err.partial = PartialConfig(
            tree=tree if tree is not None and tree.file.is_file() else None, sources=sources,
            declared_sources=frozenset(str(n) for n in named) if isinstance(named, Mapping) else frozenset(),
            sources_ok=read.ok,
            actions=MappingProxyType({n: a for n, a in actions.items() if n not in RESERVED_NODE_IDS}))
        raise err
    drives = MappingProxyType(dict(m.canopen.drives) if m.canopen is not None else {})
    return Config(path=path, dbc_files=dbc_files, buses=MappingProxyType(buses), sources=sources, tree=tree,
                  task=task, stop=stop, actions=MappingProxyType(actions), events=events, state=state, monitor=monitor,
                  simulation=simulation, database=m.database, canopen=drives, dbc_notes=tuple(m.notes))


def load_config_text(text: str, path: str | Path) -> Config:
    """Validate config ``text`` as if read from ``path`` (relative paths resolve against its folder); ConfigError
    lists every problem, each ``"{file}:{line}: {key.path}: found ..., expected ..."``."""
    display = str(path)
    p = Path(path).expanduser().absolute()
    try:
        doc = load_yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{display}:{mark.line + 1}:{mark.column + 1}" if mark is not None else display
        problem = getattr(exc, "problem", None) or str(exc)
        context = getattr(exc, "context", None)
        detail = f"{context}, {problem}" if context else str(problem)
        raise ConfigError(f"{where}: YAML syntax error: {detail}") from exc
    if doc is None:
        raise ConfigError(f"{display}: (top level): found an empty file, expected a mapping with dbc, buses, sources")
    return _config(Checks(p, display, text), p, doc)


def load_config(path: str | Path) -> Config:
    """Read and validate the YAML config at ``path`` (and every DBC file it names); ConfigError as above."""
    try:
        text = Path(path).expanduser().read_text(encoding="utf-8")
    except OSError as exc:
        why = exc.strerror or exc
        raise ConfigError(f"{path}: found a file that cannot be read ({why}), expected a YAML config") from exc
    except RuntimeError as exc:  # Path.expanduser: ~user of no such user
        raise ConfigError(f"{path}: found {exc}, expected a config path whose ~ names an existing user") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: found bytes that are not UTF-8 ({exc.reason}), expected a YAML text file") from exc
    return load_config_text(text, path)
