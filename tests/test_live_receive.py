"""The live receive path without a thread hand-off: ``BusReader(direct=True)`` and the daemon on it.

A bus with a socket (udp_multicast here, SocketCAN on the robot) is waited on and drained by the
caller's thread; a bus without one (python-can's virtual bus) keeps its receive thread. Both give
``(bus, frame, received)`` through :meth:`BusReader.receive`.
"""

from __future__ import annotations

import errno
import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from canguard.config.schema import BusConfig
from canguard.engine.events import SYNC_INTERVAL_S, EventJournal
from canguard.engine.gate import TaskGate
from canguard.io.bus import BusReader, open_bus
from canguard.service.daemon import Daemon
from canguard.service.systemd import Notifier
from test_daemon import BmsFeeder, is_stop, is_task, read_events, unique_udp, write_config
from waitkit import WAIT_S, receive_until, wait_until

pytest.importorskip("msgpack")  # python-can's udp_multicast needs it


def udp_config(name: str = "main") -> BusConfig:
    """A udp_multicast bus on a group and port no other test uses."""
    return BusConfig(name=name, kwargs=unique_udp())


def threads_named(name_prefix: str = "canguard-bus-") -> set[threading.Thread]:
    """The threads alive now whose names start so (compared before and after: other tests may leave theirs ending)."""
    return {t for t in threading.enumerate() if t.name.startswith(name_prefix) and t.is_alive()}


def collect(reader: BusReader, n: int) -> list[tuple[str, can.Message, float]]:
    """The next ``n`` frames :meth:`BusReader.receive` gives, as soon as they are there."""
    out: list[tuple[str, can.Message, float]] = []

    def enough() -> bool:
        out.extend(reader.receive(0.05, n - len(out)))
        return len(out) >= n

    wait_until(enough, what=f"{n} frames from the reader")
    return out


def kernel_stamps_on(reader: BusReader, peer: can.BusABC) -> None:
    """Wait until a frame left in the reader's socket comes out stamped when it arrived. Linux switches its receive
    timestamps on for every socket a moment after the first socket asks (deferred work, late on a loaded machine)
    and off after the last one closes; until then a datagram is stamped when it is read."""

    def stamped() -> bool:
        peer.send(can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False))
        peer.recv(5)  # the peer's own loopback copy
        time.sleep(0.02)  # the frame waits in the reader's socket
        read = time.monotonic()
        ((_, _, received),) = collect(reader, 1)
        return received < read - 0.01

    wait_until(stamped, what="the kernel's receive timestamps")


@pytest.fixture
def udp() -> Iterator[tuple[BusConfig, can.BusABC]]:
    """A udp_multicast bus config and a peer bus on it."""
    cfg = udp_config()
    peer = can.Bus(**cfg.kwargs)
    try:
        yield cfg, peer
    finally:
        peer.shutdown()


class TestDirectReceive:
    """BusReader(direct=True) on a bus with a socket: the caller's thread receives."""

    def test_frames_arrive_in_order_without_a_receive_thread(self, udp: tuple[BusConfig, can.BusABC]) -> None:
        """Frames from a peer come out of receive() in the order sent, and no receive thread is started."""
        cfg, peer = udp
        before = threads_named()
        with BusReader([cfg], direct=True) as reader:
            assert reader.direct
            assert not threads_named() - before
            for i in range(50):
                peer.send(can.Message(arbitration_id=0x123, data=bytes([i]) * 8, is_extended_id=False))
            got = collect(reader, 50)
            assert [f.data[0] for _, f, _ in got] == list(range(50))
            assert {name for name, _, _ in got} == {cfg.name}
            assert reader.received[cfg.name] == 50
            assert reader.alive() == {cfg.name: True}
        assert reader.alive() == {cfg.name: False}

    def test_foreign_traffic_that_never_stops_still_ends_each_wait_in_time(
            self, udp: tuple[BusConfig, can.BusABC]) -> None:
        """Frames of ids the config does not read, every millisecond: receive() still returns when its time is up
        (the engine's ticks are due), empty, and a configured frame among them comes out alone."""
        cfg, peer = udp
        stop = threading.Event()
        foreign = can.Message(arbitration_id=0x600, data=bytes(8), is_extended_id=False)

        def flood() -> None:  # for 10 s at most: a receive that waited for the traffic to end fails, not hangs
            end = time.monotonic() + 10.0
            while not stop.is_set() and time.monotonic() < end:
                peer.send(foreign)
                time.sleep(0.001)

        sender = threading.Thread(target=flood, daemon=True)
        with BusReader([cfg], direct=True, wanted={cfg.name: frozenset({0x123})}) as reader:
            sender.start()
            try:
                wait_until(lambda: reader.receive(0.0, 8) == [] and not reader.received[cfg.name],
                           what="an empty receive while foreign frames flow")
                for _ in range(5):
                    t0 = time.monotonic()
                    assert reader.receive(0.05, 8) == []
                    assert time.monotonic() - t0 < 2.0  # ends at its time (0.05 s), not when the traffic does
                peer.send(can.Message(arbitration_id=0x123, data=b"\x07", is_extended_id=False))
                got = collect(reader, 1)
            finally:
                stop.set()
                sender.join()
        assert [(f.arbitration_id, bytes(f.data)) for _, f, _ in got] == [(0x123, b"\x07")]
        assert reader.received[cfg.name] == 1

    def test_a_frame_that_waited_in_the_kernel_counts_its_wait(self, udp: tuple[BusConfig, can.BusABC]) -> None:
        """A frame left in the socket's buffer is received with the time it arrived, not the time it was read."""
        cfg, peer = udp
        with BusReader([cfg], direct=True) as reader:
            kernel_stamps_on(reader, peer)  # and the bus's first frame tells that it stamps with the wall clock
            sent = time.monotonic()
            peer.send(can.Message(arbitration_id=0x124, data=b"\x02", is_extended_id=False))
            time.sleep(0.5)  # the loop is busy elsewhere: the frame waits in the kernel's buffer
            read = time.monotonic()
            ((_, frame, received),) = collect(reader, 1)
        assert frame.data == b"\x02"
        assert sent - 0.05 <= received < read - 0.1  # 0.4 s of slack for a loaded machine's send, not the read time

    def test_a_receive_error_is_reported_and_the_bus_reopened(self, udp: tuple[BusConfig, can.BusABC]) -> None:
        """A failing recv is handed to on_error, the bus is reopened after its backoff, and frames come again."""
        cfg, peer = udp
        opened: list[can.BusABC] = []

        def opener(c: BusConfig) -> can.BusABC:
            bus = open_bus(c)
            if not opened:  # the first bus breaks on its first recv

                def broken(timeout: float | None = None) -> can.Message | None:
                    raise can.CanOperationError("interface went down")

                bus.recv = broken  # type: ignore[method-assign]
            opened.append(bus)
            return bus

        errors: list[tuple[str, str]] = []
        reader = BusReader([cfg], direct=True, opener=opener, backoff_min_s=0.01,
                           on_error=lambda n, e: errors.append((n, str(e))))
        with reader:
            assert reader.direct
            msg = can.Message(arbitration_id=0x125, data=b"\x07", is_extended_id=False)

            def reopened() -> bool:
                peer.send(msg)  # something to read, so that the broken recv is called
                reader.receive(0.02, 10)
                return reader.reopens[cfg.name] >= 1

            wait_until(reopened, what="the bus reopened")
            assert errors == [(cfg.name, "interface went down")]
            peer.send(msg)
            got = collect(reader, 1)
            assert got[0][1].arbitration_id == 0x125
            assert reader.alive() == {cfg.name: True}

    def test_a_bus_is_taken_as_wall_stamped_once_one_frame_says_so(self) -> None:
        """A first frame read long after its stamp (a starved daemon) does not make the bus's later stamps ignored."""
        import socket

        cfg = BusConfig(name="stamped", kwargs={"interface": "virtual", "channel": f"w-{time.monotonic_ns()}"})
        ours, theirs = socket.socketpair()
        waiting: list[can.Message] = []

        def opener(c: BusConfig) -> can.BusABC:
            bus = open_bus(c)
            bus.fileno = ours.fileno  # type: ignore[method-assign]

            def recv(timeout: float | None = None) -> can.Message | None:
                if not waiting:
                    return None
                ours.recv(1)
                return waiting.pop(0)

            bus.recv = recv  # type: ignore[method-assign]
            return bus

        def arrive(stamp: float) -> None:
            waiting.append(can.Message(timestamp=stamp, arbitration_id=0x128, data=b"\x01", is_extended_id=False))
            theirs.send(b"x")

        try:
            with BusReader([cfg], direct=True, opener=opener) as reader:
                assert reader.direct
                arrive(time.time() - 5.0)  # stamped 5 s before it is read: no proof of a wall-clock stamp
                ((_, _, first),) = collect(reader, 1)
                assert abs(first - time.monotonic()) < 1.0  # so it arrived when read
                arrive(time.time() - 0.3)  # waited 0.3 s in the kernel: a wall-clock stamp
                ((_, _, second),) = collect(reader, 1)
                arrive(time.time() - 3.0)  # from now on a stamp is an arrival time, however old
                ((_, _, third),) = collect(reader, 1)
                read = time.monotonic()
            assert 0.2 < read - second < 1.0
            assert read - third > 2.5
        finally:
            ours.close()
            theirs.close()

    def test_two_buses_come_out_in_arrival_order(self) -> None:
        """Frames sent alternately on two buses come out of one receive() in the order they arrived."""
        first, second = udp_config("a"), udp_config("b")
        peers = [can.Bus(**first.kwargs), can.Bus(**second.kwargs)]
        try:
            with BusReader([first, second], direct=True) as reader:
                assert reader.direct
                for peer in peers:
                    kernel_stamps_on(reader, peer)
                for i in range(20):
                    peers[i % 2].send(can.Message(arbitration_id=0x127, data=bytes([i]), is_extended_id=False))
                    assert peers[i % 2].recv(5) is not None  # its loopback copy: the reader's socket holds it too
                got = collect(reader, 20)
            assert [f.data[0] for _, f, _ in got] == list(range(20))
            assert [name for name, _, _ in got] == ["a", "b"] * 10
        finally:
            for peer in peers:
                peer.shutdown()

    def test_a_descriptor_that_is_no_socket_keeps_the_receive_thread(self) -> None:
        """A bus whose descriptor is not a socket (a serial adapter's tty: python-can buffers it) is not direct."""
        cfg = BusConfig(name="serial", kwargs={"interface": "virtual", "channel": f"t-{time.monotonic_ns()}"})
        read_end, write_end = os.pipe()

        def opener(c: BusConfig) -> can.BusABC:
            bus = open_bus(c)
            bus.fileno = lambda: read_end  # type: ignore[method-assign]
            return bus

        try:
            with BusReader([cfg], direct=True, opener=opener) as reader:
                assert not reader.direct
                assert threads_named("canguard-bus-serial")
        finally:
            os.close(read_end)
            os.close(write_end)

    def test_a_bus_without_a_socket_keeps_its_receive_thread(self) -> None:
        """A virtual bus has no file descriptor: direct=True falls back to a receive thread, same receive()."""
        cfg = BusConfig(name="virt", kwargs={"interface": "virtual", "channel": f"t-{time.monotonic_ns()}"})
        peer = can.Bus(**cfg.kwargs)
        try:
            with BusReader([cfg], direct=True) as reader:
                assert not reader.direct
                assert threads_named("canguard-bus-virt")
                peer.send(can.Message(arbitration_id=0x126, data=b"", is_extended_id=False))
                assert collect(reader, 1)[0][1].arbitration_id == 0x126
        finally:
            peer.shutdown()


class TestDaemonReceivesDirectly:
    """Daemon.run on a udp_multicast bus receives in its own thread and still trips."""

    def test_overcurrent_brings_the_estop_without_a_receive_thread(self, tmp_path: Path) -> None:
        """On a bus with a socket the daemon starts no receive thread, and a peer's overcurrent stops the task."""
        bus = unique_udp()
        daemon = Daemon(write_config(tmp_path, bus), notifier=Notifier(env={}))
        peer = can.Bus(**bus)
        result: list[int] = []
        before = threads_named()
        thread = threading.Thread(target=lambda: result.append(daemon.run()), name="daemon", daemon=True)
        thread.start()
        try:
            with BmsFeeder(peer) as feeder:
                receive_until(peer, is_task, "task frame while the current is normal")
                assert daemon.reader.direct
                assert not threads_named() - before
                feeder.current_a = 40.0
                receive_until(peer, is_stop, "Estop after the overcurrent")
            # the stop frames leave first; the gate's state follows in the same step
            wait_until(lambda: daemon.engine.gate.state == TaskGate.STOPPED, what="the task stopped")
        finally:
            daemon.request_stop("test over")
            thread.join(10)
            peer.shutdown()
        assert result == [0]

    @pytest.mark.parametrize("filtered", [True, False])
    def test_foreign_frames_are_not_taken_and_a_configured_one_still_trips(self, tmp_path: Path,
                                                                         filtered: bool) -> None:
        """Frames of ids the config does not read never reach the engine (``filter: false``: they are counted
        as skipped), and the overcurrent after them still brings the Estop."""
        bus = unique_udp()
        edit = None if filtered else lambda doc: doc["buses"]["main"].update(filter=False)
        daemon = Daemon(write_config(tmp_path, bus, edit=edit), notifier=Notifier(env={}))
        peer = can.Bus(**bus)
        thread = threading.Thread(target=daemon.run, name="daemon", daemon=True)
        thread.start()
        try:
            with BmsFeeder(peer) as feeder:
                receive_until(peer, is_task, "task frame while the current is normal")
                with feeder.held:
                    for i in range(40):
                        peer.send(can.Message(arbitration_id=0x600 + i, data=bytes(8), is_extended_id=False))
                        peer.send(can.Message(arbitration_id=0x1ABC00 + i, data=bytes(8), is_extended_id=True))
                    feeder.current_a = 40.0
                receive_until(peer, is_stop, "Estop after the overcurrent")
            decoder = daemon.engine.decoder
            if not filtered:
                wait_until(lambda: decoder.skipped >= 80, what="the 80 foreign frames counted")
        finally:
            daemon.request_stop("test over")
            thread.join(10)
            peer.shutdown()
        if filtered:  # the loop has ended: every frame it received was taken
            assert decoder.skipped == 0
            assert daemon.reader.received["main"] == decoder.frames


class TestJournalSyncsInBackground:
    """The live daemon's journal fsyncs in a thread of its own, so the loop never waits for the disk."""

    @pytest.fixture
    def fsyncs(self, monkeypatch: pytest.MonkeyPatch) -> list[str]:
        """The name of the thread of every os.fsync from now on."""
        seen: list[str] = []
        real = os.fsync

        def recording(fd: int) -> None:
            seen.append(threading.current_thread().name)
            real(fd)

        monkeypatch.setattr(os, "fsync", recording)
        return seen

    def test_flush_leaves_the_fsync_to_the_sync_thread(self, tmp_path: Path, fsyncs: list[str]) -> None:
        """flush() returns without syncing; the sync thread syncs the file soon after."""
        journal = EventJournal(tmp_path / "events.jsonl", sync_in_background=True)
        try:
            fsyncs.clear()  # creating the file synced its directory
            journal.write({"event": "trip", "reason": "overcurrent"})
            journal.flush()
            assert threading.current_thread().name not in fsyncs
            wait_until(lambda: "canguard-journal-fsync" in fsyncs, what="the sync thread's fsync")
        finally:
            journal.close()

    def test_close_syncs_every_line_and_ends_the_thread(self, tmp_path: Path, fsyncs: list[str]) -> None:
        """close() syncs in the caller before it returns, and the sync thread is gone."""
        before = threads_named("canguard-journal-fsync")
        journal = EventJournal(tmp_path / "events.jsonl", sync_in_background=True)
        for k in range(5):
            journal.write({"event": "stop", "reason": f"stop {k}"})
        journal.flush()
        journal.close()
        assert fsyncs and fsyncs[-1] == threading.current_thread().name
        assert not threads_named("canguard-journal-fsync") - before
        assert [e["reason"] for e in read_events(tmp_path / "events.jsonl")] == [f"stop {k}" for k in range(5)]

    def test_a_close_just_as_the_interval_ends_still_ends_the_thread(self, tmp_path: Path) -> None:
        """close() while the sync thread has waited out its interval but not yet taken the flush's request: the
        thread's clear drops close's request too, and the thread still ends. It used to wait for a next flush that
        never came, and close() with it: a daemon that did not stop at SIGTERM (seen in the suite's teardowns)."""
        journal = EventJournal(tmp_path / "events.jsonl", sync_in_background=True)
        in_window, closed = threading.Event(), threading.Event()

        class Window(threading.Event):
            def clear(self) -> None:  # the sync thread's, after its interval
                if not in_window.is_set():
                    in_window.set()
                    closed.wait(WAIT_S)  # close() asks meanwhile: this clear drops its request
                super().clear()

        asked = journal._sync_due
        journal._sync_due = Window()
        journal.write({"event": "stop", "reason": "estop"})
        journal.flush()
        asked.set()  # the thread waits on the flag it started with
        wait_until(in_window.is_set, what="the sync thread between its interval and its clear")
        closer = threading.Thread(target=journal.close, name="closer", daemon=True)
        closer.start()
        wait_until(lambda: journal._sync_stop.is_set() and journal._sync_due.is_set(), what="close() to ask")
        closed.set()
        closer.join(WAIT_S)
        assert not closer.is_alive(), "close() waited for a sync thread that waited for another flush"
        assert [e["reason"] for e in read_events(tmp_path / "events.jsonl")] == ["estop"]

    def test_flushes_within_the_interval_share_one_fsync_made_in_time(self, tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
        """A flush's fsync comes SYNC_INTERVAL_S later, never at once (a stop's flush starts no disk stall),
        shared by the flushes meanwhile: a flushed line lags on disk by the interval (and the disk's sync time)."""
        path = tmp_path / "events.jsonl"
        synced: list[tuple[float, int]] = []  # (when, file size) at each fsync of the journal's file
        real = os.fsync

        def recording(fd: int) -> None:
            if threading.current_thread().name == "canguard-journal-fsync":
                synced.append((time.monotonic(), os.fstat(fd).st_size))
            real(fd)

        monkeypatch.setattr(os, "fsync", recording)
        journal = EventJournal(path, sync_in_background=True)
        try:
            journal.write({"event": "start", "reason": "first"})
            flushed = time.monotonic()
            journal.flush()
            wait_until(lambda: synced, what="the first fsync")
            assert synced[0][0] - flushed >= SYNC_INTERVAL_S - 0.05
            for k in range(20):
                journal.write({"event": "trip", "reason": f"trip {k}"})
                journal.flush()
            size = path.stat().st_size
            wait_until(lambda: len(synced) >= 2, what="the fsync at the end of the interval")
            assert synced[1][0] - synced[0][0] >= SYNC_INTERVAL_S - 0.05  # not at once: at the end of the interval
            assert synced[1][1] == size  # every line flushed meanwhile, in that one fsync
            assert len(synced) == 2
        finally:
            journal.close()

    def test_flushes_that_never_pause_still_reach_the_disk_within_the_interval(
            self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """Flushes without a pause do not put the fsync off: the lines are synced an interval after the first one."""
        synced: list[float] = []
        real = os.fsync

        def recording(fd: int) -> None:
            if threading.current_thread().name == "canguard-journal-fsync":
                synced.append(time.monotonic())
            real(fd)

        monkeypatch.setattr(os, "fsync", recording)
        journal = EventJournal(tmp_path / "events.jsonl", sync_in_background=True)
        try:
            first = time.monotonic()
            while not synced and time.monotonic() - first < 5.0:
                journal.write({"event": "trip", "reason": "again"})
                journal.flush()
            assert synced and synced[0] - first < SYNC_INTERVAL_S + 1.0  # the interval, and a loaded machine's slack
        finally:
            journal.close()

    def test_a_failed_background_fsync_is_logged_and_tried_again(self, tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch,
                                                               caplog: pytest.LogCaptureFixture) -> None:
        """An fsync the disk refuses is logged as an error and done again at the next flush."""
        journal = EventJournal(tmp_path / "events.jsonl", sync_in_background=True)
        real = os.fsync
        calls: list[bool] = []

        def failing_once(fd: int) -> None:
            calls.append(not calls)
            if len(calls) == 1:
                raise OSError(errno.EIO, "I/O error")
            real(fd)

        monkeypatch.setattr(os, "fsync", failing_once)
        try:
            journal.write({"event": "trip", "reason": "overcurrent"})
            journal.flush()
            wait_until(lambda: "fsync failed" in caplog.text, what="the failed fsync logged")
            journal.flush()
            wait_until(lambda: len(calls) >= 2, what="the fsync tried again")
        finally:
            journal.close()
