"""Groot2's monitor, spoken to by a client written from BehaviorTree.CPP 4's ``groot2_protocol.h``.

The client below is the header's framing and nothing of canguard's: a request is a multipart
message whose first part is ``protocol (u8) | type (u8) | unique_id (u32)``; a reply's first part
repeats them and adds the tree's 16-byte UUID; an error is ``["error", text]``. Statuses are
BT.CPP's ``NodeStatus`` (IDLE 0, RUNNING 1, SUCCESS 2, FAILURE 3, SKIPPED 4; ``10 + s``: idle
after ``s``, as the publisher writes them).
"""

from __future__ import annotations

import contextlib
import json
import random
import struct
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import pytest

from monitorkit import (
    DEMO_GUARDS,
    Watched,
    real_signals,
    running,
    shared_daemon,
    sighup_with_threshold,
    wait_for,
    watched_daemon,
)

FAILURE = 3


class Groot2Client:
    """A REQ socket speaking the protocol header's framing."""

    def __init__(self, port: int) -> None:
        import zmq  # here, not at module level: only the worker running these tests pays for it at collection

        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.REQ)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.RCVTIMEO, 5000)
        self.sock.connect(f"tcp://127.0.0.1:{port}")
        self.sub = self.ctx.socket(zmq.SUB)  # the publisher's second socket, PORT + 1
        self.sub.setsockopt(zmq.LINGER, 0)
        self.sub.connect(f"tcp://127.0.0.1:{port + 1}")

    def request(self, kind: str, *parts: bytes) -> tuple[bytes, list[bytes]]:
        """Send one request; return the reply's 16-byte tree UUID and its payload parts (AssertionError on error)."""
        request_id = random.getrandbits(32)
        self.sock.send_multipart([struct.pack("<BBI", 2, ord(kind), request_id), *parts])
        reply = self.sock.recv_multipart()
        assert reply[0] != b"error", f"error reply: {reply[1:]!r}"
        protocol, got_kind, got_id = struct.unpack("<BBI", reply[0][:6])
        assert (protocol, chr(got_kind), got_id) == (2, kind, request_id)
        assert len(reply[0]) == 22
        return reply[0][6:], reply[1:]

    def raw(self, *parts: bytes) -> list[bytes]:
        """Send any parts; return the reply's parts as they come."""
        self.sock.send_multipart(list(parts))
        return list(self.sock.recv_multipart())

    def statuses(self) -> dict[int, int]:
        """STATUS as {uid: status}."""
        _, [buffer] = self.request("S")
        assert len(buffer) % 3 == 0
        return {uid: status for uid, status in struct.iter_unpack("<HB", buffer)}

    def close(self) -> None:
        """Close both sockets and the context, never waiting on unsent messages."""
        self.ctx.destroy(linger=0)


@pytest.fixture(autouse=True)
def _clean_blackboard() -> Iterator[None]:
    """Not cleared between this module's tests: the shared daemon's tree holds it (monitorkit.shared_daemon)."""
    yield


@pytest.fixture(scope="module")
def shared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Watched]:
    """The demo's daemon with its Groot2 monitor (and page), its task running, for the tests that only ask."""
    with shared_daemon(tmp_path_factory, groot2=True) as w:
        yield w


@contextlib.contextmanager
def connected(w: Watched) -> Iterator[tuple[Watched, Groot2Client]]:
    """Once ``w``'s task runs (again, after any stop late frames on a loaded machine caused), ``w`` and a Groot2
    client of its own connected to it; the client is closed after."""
    wait_for("the task to run", lambda: running(w))
    client = Groot2Client(w.groot2)
    try:
        yield w, client
    finally:
        client.close()


@pytest.fixture
def groot(shared: Watched) -> Iterator[tuple[Watched, Groot2Client]]:
    """The shared daemon, its task running, and a client of its own connected to it."""
    with connected(shared) as pair:
        yield pair


@pytest.fixture
def own_groot(tmp_path: Path) -> Iterator[tuple[Watched, Groot2Client]]:
    """A daemon of the test's own with its Groot2 monitor, its task running, and a client connected to it."""
    with watched_daemon(tmp_path, groot2=True) as w, connected(w) as pair:
        yield pair


def uids_by_name(xml: str) -> dict[str, int]:
    """``name -> _uid`` of every node element in FULLTREE's XML."""
    root = ET.fromstring(xml)
    return {e.get("name", ""): int(e.get("_uid", "0")) for e in root.iter() if e.get("_uid") is not None}


class TestFullTree:
    """FULLTREE (``T``)."""

    def test_tree_xml_with_uids_and_nodes_model(self, groot: tuple[Watched, Groot2Client]) -> None:
        """The reply carries the tree with a distinct ``_uid`` on every node and the TreeNodesModel of its types."""
        _, client = groot
        tree_uuid, [xml] = client.request("T")
        assert len(tree_uuid) == 16
        root = ET.fromstring(xml)
        assert root.get("BTCPP_format") == "4"
        [tree] = root.findall("BehaviorTree")
        assert tree.get("ID") == "RobotGuard"
        uids = [int(e.get("_uid", "0")) for e in tree.iter() if e.tag != "BehaviorTree"]
        assert sorted(uids) == list(range(1, len(uids) + 1))
        assert set(DEMO_GUARDS) <= set(uids_by_name(xml.decode()))
        guard = next(e for e in tree.iter("IsCurrentSafe") if e.get("name") == "PackCurrent")
        assert guard.get("overcurrent_threshold") == "35.0"
        models = root.find("TreeNodesModel")
        assert models is not None
        modelled = {m.get("ID") for m in models}
        assert {"IsCurrentSafe", "IsI2tSafe", "IsJointEffortNormal", "ExecuteTask", "ReactiveSequence"} <= modelled


class TestStatus:
    """STATUS (``S``)."""

    def test_one_entry_per_node_and_failures_show(self, own_groot: tuple[Watched, Groot2Client]) -> None:
        """STATUS lists every FULLTREE uid; with the robot silent, the guards show FAILURE."""
        w, client = own_groot
        _, [xml] = client.request("T")
        uids = uids_by_name(xml.decode())
        status = client.statuses()
        assert set(status) == set(uids.values())
        assert status[uids["ExecuteTask"]] == 1  # RUNNING: the task runs
        assert status[uids["PackCurrent"]] == 2
        w.robot_stop.set()
        failed = wait_for("PackCurrent to fail", lambda: client.statuses()[uids["PackCurrent"]] == FAILURE)
        assert failed
        assert client.statuses()[uids["ExecuteTask"]] in (0, 11)  # halted: idle after RUNNING

    def test_same_tree_uuid_on_every_reply(self, groot: tuple[Watched, Groot2Client]) -> None:
        """FULLTREE and STATUS name the same tree (Groot2 asks for the tree again when it changes)."""
        _, client = groot
        first, _ = client.request("T")
        second, _ = client.request("S")
        assert first == second


def test_reload_gives_groot2_the_new_tree(tmp_path: Path) -> None:
    """After a SIGHUP reload the replies carry a new tree UUID, and FULLTREE the new tree's attributes."""
    with watched_daemon(tmp_path, groot2=True) as w, real_signals(w.daemon):
        wait_for("the task to run", lambda: running(w))
        client = Groot2Client(w.groot2)
        try:
            before, [xml] = client.request("T")
            assert b'overcurrent_threshold="35.0"' in xml
            sighup_with_threshold(w, tmp_path, "30.0")
            wait_for("a new tree UUID", lambda: client.request("S")[0] != before)
            _, [xml] = client.request("T")
            assert b'overcurrent_threshold="30.0"' in xml
        finally:
            client.close()


class TestBlackboard:
    """BLACKBOARD (``B``)."""

    def test_main_tree_blackboard_as_msgpack(self, groot: tuple[Watched, Groot2Client]) -> None:
        """Asking for the main tree's blackboard gives MessagePack with its entries (the I²t levels)."""
        import msgpack

        _, client = groot

        def board() -> dict[str, dict[str, object]]:
            _, [payload] = client.request("B", b"RobotGuard")
            return msgpack.unpackb(payload)

        assert set(board()) == {"RobotGuard"}
        # the entries come with the first snapshot after a monitor asked for them (the daemon copies the
        # blackboard only while someone watches it): on a loaded machine that tick may not have run yet
        wait_for("the I²t level in the blackboard", lambda: "axis0_i2t_pct" in board()["RobotGuard"])

    def test_needs_the_names_part(self, groot: tuple[Watched, Groot2Client]) -> None:
        """A BLACKBOARD request without its second part is an error reply, as BT.CPP's."""
        _, client = groot
        reply = client.raw(struct.pack("<BBI", 2, ord("B"), 7))
        assert reply == [b"error", b"must be 2 parts message"]


class TestReadOnly:
    """Nothing from Groot2 may pause or change the loop."""

    @pytest.mark.parametrize("kind", ["I", "U", "R", "r", "t"])
    def test_hooks_breakpoints_and_recording_are_refused(self, groot: tuple[Watched, Groot2Client],
                                                         kind: str) -> None:
        """Hook insertion, breakpoint unlock, hook removal and recording get an error reply saying why."""
        w, client = groot
        hook = json.dumps({"enabled": True, "uid": 2, "mode": 0, "once": False, "desired_status": "SUCCESS",
                           "position": 0, "remove_when_done": True}).encode()
        reply = client.raw(struct.pack("<BBI", 2, ord(kind), 9), hook)
        assert reply[0] == b"error" and b"read-only" in reply[1]
        assert w.status()["task"]["state"] == "running"

    def test_disconnect_requests_are_answered(self, groot: tuple[Watched, Groot2Client]) -> None:
        """REMOVE_ALL_HOOKS and DISABLE_ALL_HOOKS succeed (there are none); HOOKS_DUMP is an empty list."""
        _, client = groot
        assert client.request("A")[1] == []
        assert client.request("X")[1] == []
        assert client.request("D")[1] == [b"[]"]

    def test_bad_header_gets_an_error(self, groot: tuple[Watched, Groot2Client]) -> None:
        """A first part that is not 6 bytes is answered ``wrong request header``."""
        _, client = groot
        assert client.raw(b"\x02T") == [b"error", b"wrong request header"]
