"""YAML config -> frozen dataclasses, validated once.

The dataclasses are :mod:`.schema`'s; every problem of a file comes in one :class:`ConfigError`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any

import yaml

from canguard.config.node_ids import RESERVED_NODE_IDS
from canguard.config.schema import ActionConfig, Config, PartialConfig, TreeConfig
from canguard.config.sections import _Sections
from canguard.config.sources import _IDENT
from canguard.config.yamlsrc import _found, _path, load_yaml
from canguard.errors import ConfigError


class _Loader(_Sections):
    """One pass over one config file, collecting every problem instead of stopping at the first."""

    def partial(
        self, doc: Mapping[str, Any], tree: TreeConfig | None, actions: Mapping[str, ActionConfig]
    ) -> PartialConfig:
        """What of a config with problems is sound enough to check its tree against."""
        raw_actions = doc.get("actions")
        names = [n for n in raw_actions if isinstance(n, str)] if isinstance(raw_actions, Mapping) else []
        # An action whose frames are wrong is still an action node ID the tree may use.
        all_actions = {n: actions.get(n, ActionConfig(name=n)) for n in names
                       if _IDENT.fullmatch(n) and n not in RESERVED_NODE_IDS}
        raw_sources = doc.get("sources")
        declared = frozenset(str(n) for n in raw_sources) if isinstance(raw_sources, Mapping) else frozenset()
        return PartialConfig(tree=tree if tree is not None and tree.file.is_file() else None,
                             sources=MappingProxyType(dict(self.sources)), declared_sources=declared,
                             sources_ok=self._sources_ok, actions=MappingProxyType(all_actions))

    def config(self, doc: Any) -> Config:
        top = ("dbc", "buses", "canopen", "sources", "tree", "task", "stop", "actions", "events", "state",
               "simulation", "monitor")
        # dbc: is optional when the drives come from canopen: (every source and frame may then use them)
        required = ("buses",) if isinstance(doc, dict) and "canopen" in doc else ("dbc", "buses")
        if not self.mapping(doc, "", top, required):
            raise self.fail()
        dbc_files = self.load_dbc(doc["dbc"]) if "dbc" in doc else ()
        buses = self.buses(doc["buses"]) if "buses" in doc else {}
        if "canopen" in doc:
            from canguard.config.canopen_section import CanopenSection

            self.canopen = CanopenSection(self)
            self.canopen.load(doc["canopen"])
        raw_sources = doc.get("sources") or {}
        if not isinstance(raw_sources, Mapping):
            self.problem("sources", _found(raw_sources), "a mapping of source name -> source")
            self._sources_ok = False
            raw_sources = {}
        for name, body in raw_sources.items():
            if not isinstance(name, str) or not name:
                self.problem(_path("sources", name), _found(name), "a source name (a string)")
                continue
            before = len(self.problems)
            src = self.source(name, body)
            if src is not None:
                self.sources[name] = src
            if len(self.problems) > before:
                # Already reported: references to this source must not add follow-on errors.
                self._broken_sources.add(name)
        if self.canopen is not None:
            self.add_messages(self.canopen.messages())
        tree = self.tree(doc.get("tree"))
        task = self.task(doc.get("task"))
        stop = self.stop(doc.get("stop"))
        actions = self.actions(doc.get("actions"))
        events = self.file_path(doc["events"], "events") if doc.get("events") is not None else None
        state = self.state(doc.get("state"))
        monitor = self.monitor(doc.get("monitor"))
        simulation = self.choice(doc, "simulation", "", (True, False), False)
        if self.problems:
            err = self.fail()
            err.partial = self.partial(doc, tree, actions)
            raise err
        drives = MappingProxyType(dict(self.canopen.drives) if self.canopen is not None else {})
        return Config(path=self.path, dbc_files=dbc_files, buses=MappingProxyType(buses),
                      sources=MappingProxyType(dict(self.sources)), tree=tree, task=task, stop=stop,
                      actions=MappingProxyType(actions), events=events, state=state, monitor=monitor,
                      simulation=simulation, database=self.database, canopen=drives,
                      dbc_notes=tuple(self.dbc_checks.notes))


def load_config_text(text: str, path: str | Path) -> Config:
    """Validate config ``text`` as if read from ``path`` (relative paths resolve against its folder).

    Raises :class:`ConfigError` listing every problem, each as
    ``"{file}: {key.path}: found ..., expected ..."``; YAML syntax errors as ``"{file}:{line}: ..."``.
    """
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
    return _Loader(p, display, text).config(doc)


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
