"""Validating every node of a tree against the registry before py_trees sees it."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from typing import cast

from py_trees.parsers.behaviour_tree_xml import is_key
from py_trees.ports import PortInformation, PortsMixin
from py_trees.ports_utils import convert_str_to_type

from canguard.bt import conditions
from canguard.bt.conditions import take_conditions
from canguard.bt.loaded import NodeInfo
from canguard.bt.nodes import ConfiguredAction, GuardNode
from canguard.bt.nodes.base import node_kind, port_table
from canguard.bt.registry import _SUBTREE, _TOKEN, children_problem, known_node_ids
from canguard.bt.xmlread import _closest, _Reader, _type_name
from canguard.errors import TreeError, closest, quote

NEAR_NODE_IDS = 5  # an unknown node ID is answered with this many known ones, the closest
LIST_NODE_IDS = "`canguard tree --nodes-model FILE` writes every one with its ports"


class _Validator(_Reader):
    """Step 3: every node, port, SubTree and cycle checked; every problem collected."""

    def check(self, main: str | None) -> str:
        """Read, rewrite, choose the main tree, validate: its ID; problems go to ``errors`` (unreadable: raise)."""
        self.read()
        self.rewrite()
        try:
            main_id = self.choose_main(main)
        except TreeError as exc:
            self.errors.extend(exc.problems)
            main_id = ""
        self.make_registry()
        self.validate()
        return main_id

    def validate(self) -> None:
        """Check every node of every tree, collecting every problem (see :meth:`raise_collected`)."""
        counter = 0
        pending: list[tuple[int, str]] = []  # unknown sources, with their place in errors
        for tree_id, bt in self.trees.items():
            if tree_id in self.broken_trees:
                continue
            subtree_names: dict[str, int] = {}
            for elem in bt[0].iter():
                subtree = elem.tag == _SUBTREE
                scripts, problems = take_conditions(elem.attrib)  # on a SubTree, BT.CPP applies them to that node
                what = f"SubTree {elem.attrib.get('ID')}" if subtree else f"node {elem.tag}"
                self.errors.extend(f"{self.at(elem)}: {what} (BehaviorTree {tree_id}), {p}" for p in problems)
                if subtree:
                    if scripts:
                        self.subtree_conditions[elem] = scripts
                    try:
                        self._check_subtree(elem, tree_id, subtree_names)
                    except TreeError as exc:
                        self.errors.extend(exc.problems)
                    continue
                cls = self._check_node(elem, tree_id)
                if cls is not None and issubclass(cls, GuardNode):
                    source_error = self._check_source(elem, cls, tree_id)
                    if source_error is not None:
                        pending.append((len(self.errors), source_error))
                counter += 1
                token = f"{_TOKEN}{counter}"
                file, line = self.where.get(elem, (self.path, 0))
                self.infos[token] = NodeInfo(elem.tag, elem.attrib.get("name") or elem.tag, file, line, tree_id)
                if scripts:
                    self.conditions[token] = scripts
                if elem in self.private:
                    self.private_tokens[token] = self.private[elem]
                elem.attrib["name"] = token
        if self.source_check == "always" or (self.errors and self.source_check == "with_others"):
            # The tree will not be built, so binding (which resolves the sources and reports an
            # unknown one) will not run: the guards' unknown sources join this report, in place.
            for place, text in reversed(pending):
                self.errors.insert(place, text)

    def _check_source(self, elem: ET.Element, cls: type, tree_id: str) -> str | None:
        """The problem of a guard's constant ``topic_name`` naming no configured source of its kinds."""
        value = elem.attrib.get("topic_name")
        try:
            if value is None or is_key(value) or self.source_check == "never":
                return None
        except ValueError:
            return None  # a malformed {key}: already reported
        if value in self.unsure_sources and value not in self.ctx.sources:
            return None
        read_before = set(self.ctx.read_sources)
        try:
            self.ctx.source(value, cls.SOURCE_KINDS)  # type: ignore[attr-defined]
        except (KeyError, ValueError) as exc:
            return str(self.error(elem, str(exc.args[0]), tree_id, "topic_name"))
        finally:
            self.ctx.read_sources.intersection_update(read_before)  # only a check: nothing is read yet
        return None

    def _check_subtree(self, elem: ET.Element, tree_id: str, names: dict[str, int]) -> None:
        if not elem.attrib.get("ID"):
            raise self.error(elem, 'SubTree without ID="..."', tree_id)
        target = self.target(elem, tree_id)
        if len(elem):
            raise self.error(elem, "a SubTree takes no child elements (its ports are attributes)", tree_id)
        for attr, value in elem.attrib.items():
            if attr in ("ID", "name"):
                continue
            if attr.startswith("_"):
                raise self.error(elem, f"attribute {attr} is not supported", tree_id)
            self._check_key_syntax(elem, attr, value, tree_id)
        name = elem.attrib.get("name") or ""
        explicit = bool(name)
        name = (name or target).replace(".", "_")
        n = names.get(name, 0) + 1
        names[name] = n
        if n > 1:
            if explicit:
                raise self.error(
                    elem, f"two SubTrees named {quote(name)} in BehaviorTree {tree_id}: names must differ", tree_id
                )
            name = f"{name}_{n}"
        elem.attrib["name"] = name

    def _check_key_syntax(self, elem: ET.Element, attr: str, value: str, tree_id: str) -> re.Match | None:
        try:
            match = is_key(value)
        except ValueError:
            raise self.error(
                elem, f"malformed blackboard reference {quote(value)} (expected {{key}})", tree_id, attr
            ) from None
        return match

    def _check_node(self, elem: ET.Element, tree_id: str) -> type[PortsMixin] | None:
        """Record every problem of one node (ID, each port, children); its class, or None if unknown."""
        node_id = elem.tag
        entry = self.registry.get(node_id)
        cls = cast("type[PortsMixin] | None", entry.func if entry is not None else None)
        decl = self.declared(node_id)
        if decl is not None and (cls is None or issubclass(cls, ConfiguredAction)):
            # declared by a palette: checked against the declaration; it runs only when bound
            from canguard.bt.palette import check_node, unbound_message

            self.errors.extend(check_node(elem, decl, self.at(elem), tree_id))
            if cls is None:
                self.unbound.append(unbound_message(node_id, self.at(elem), decl))
                return None
            extra = [a for a in elem.attrib if a in decl.ports]
            if extra:
                self.palette_ports.append((elem, extra))
            return cls
        if cls is None:
            known = set(known_node_ids(self.ctx)) | set(self.palette.nodes)
            near = closest(node_id, known, NEAR_NODE_IDS) or _closest(node_id, known)[:NEAR_NODE_IDS]
            self.errors.append(
                f"{self.at(elem)}: unknown node ID {quote(node_id)} (BehaviorTree {tree_id}); "
                f"known node IDs, closest first: {', '.join(near)} ({len(known)} in all: {LIST_NODE_IDS})"
            )
            return None
        ports = port_table(cls)
        for attr, value in elem.attrib.items():
            if attr == "name":
                continue
            try:
                self._check_port(elem, tree_id, attr, value, ports, cls)
            except TreeError as exc:
                self.errors.extend(exc.problems)
        missing = [
            n for n, (_, info) in ports.items() if info.required and not info.has_default and n not in elem.attrib
        ]
        if missing:
            self.errors.append(str(self.error(
                elem,
                f"missing required port {', '.join(missing)} (ports of {node_id}: {', '.join(ports)})",
                tree_id,
            )))
        kind_error = children_problem(node_kind(cls), len(elem))
        if kind_error is not None:
            self.errors.append(str(self.error(elem, kind_error, tree_id)))
        return cls

    def _check_port(self, elem: ET.Element, tree_id: str, attr: str, value: str,
                    ports: Mapping[str, tuple[str, PortInformation]], cls: type) -> None:
        """Raise the TreeError of one attribute of a node of ``cls`` (unknown port, bad value...), if any."""
        node_id = elem.tag
        if attr.startswith("_"):
            known = ", ".join(conditions.ALL)
            raise self.error(elem, f"attribute {attr} (BT.CPP pre/post-conditions) is not supported; "
                                   f"the supported ones: {known}", tree_id)
        if attr not in ports:
            listing = ", ".join(_closest(attr, ports)) if ports else "(none)"
            raise self.error(elem, f"unknown port {quote(attr)}; ports of {node_id}: {listing}", tree_id)
        direction, info = ports[attr]
        match = self._check_key_syntax(elem, attr, value, tree_id)
        if match:
            if attr in getattr(cls, "CONST_PORTS", ()):
                raise self.error(elem, f"takes a constant (it configures the node at load time), not {value}",
                                 tree_id, attr)
            return
        if direction == "output":
            raise self.error(elem, f"an output port takes a blackboard key like {{{attr}}}, not {quote(value)}",
                             tree_id, attr)
        if attr in getattr(cls, "KEY_PORTS", ()):
            raise self.error(elem, f"takes a blackboard key like {{{attr}}}, not {quote(value)}", tree_id, attr)
        try:
            converted, parsed = convert_str_to_type(value, info.data_type)
        except (ValueError, TypeError):
            converted, parsed = False, None
        if not converted:
            raise self.error(elem, f"{quote(value)} is not a valid {_type_name(info.data_type)}", tree_id, attr)
        if isinstance(parsed, float) and math.isnan(parsed):
            raise self.error(elem, f"{quote(value)} is not a number", tree_id, attr)
        allowed = getattr(cls, "CHOICES", {}).get(attr)
        if allowed is not None and parsed not in allowed:
            raise self.error(elem, f"unknown value {quote(value)}; expected one of {', '.join(allowed)}", tree_id, attr)

    def check_cycles(self, main_id: str) -> None:
        def visit(tree_id: str, stack: list[str]) -> None:
            for elem in self.trees[tree_id].iter(_SUBTREE):
                target = elem.attrib["ID"]
                if target in stack:
                    chain = " -> ".join([*stack[stack.index(target) :], target])
                    raise self.error(elem, f"SubTree cycle: {chain}", tree_id)
                visit(target, [*stack, target])

        visit(main_id, [main_id])
