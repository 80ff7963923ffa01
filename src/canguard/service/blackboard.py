"""Taking a discarded tree out of py_trees' global blackboard (config reloads).

py_trees keeps one blackboard per process, where every node registers a client and keys that nothing removes when
a tree is dropped: the daemon releases the old tree after a reload, and whatever a rejected reload registered.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterable

import py_trees
from py_trees.blackboard import Blackboard


def tree_clients(root: py_trees.behaviour.Behaviour) -> set[uuid.UUID]:
    """The ids of the blackboard clients attached to the nodes of the tree under ``root``."""
    return {client.id() for node in root.iterate() for client in node.blackboards}


def registered_clients() -> set[uuid.UUID]:
    """The ids of every client on the global blackboard now."""
    return set(Blackboard.clients)


def release_clients(ids: Iterable[uuid.UUID]) -> int:
    """Remove these clients from the global blackboard; how many keys (with their values) went with them: those no
    other client holds, as py_trees' ``Client.unregister(clear=True)``. From the ids alone: also after a tree whose
    build failed half-way."""
    ids = set(ids)
    gone = 0
    for key, meta in list(Blackboard.metadata.items()):
        if ids.isdisjoint(meta.read) and ids.isdisjoint(meta.write) and ids.isdisjoint(meta.exclusive):
            continue
        meta.read -= ids
        meta.write -= ids
        meta.exclusive -= ids
        if not (meta.read or meta.write or meta.exclusive):
            del Blackboard.metadata[key]
            Blackboard.storage.pop(key, None)
            gone += 1
    for client in ids:
        Blackboard.clients.pop(client, None)
    return gone
