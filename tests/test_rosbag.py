"""ROS bags as logs: rosbag2 (sqlite3, MCAP) and ROS 1 bags written by the ``rosbags`` library, replayed.

Every bag here is written with rosbags' own writers and serialisers (:mod:`tests.bagkit`);
the same frames are written as a candump -L log, and the two replays must give the same
frames, events and summary (but for the log's name and the times each frame took).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from tests.bagkit import FD_FRAME, FRAME, STORAGES, message, storage_file, typestore, write_bag
from tests.clikit import cli

from canguard.cli.replay import ReplayOptions, replay_one
from canguard.config.loader import load_config
from canguard.errors import LogFormatError
from canguard.io.bagopts import BagOptions
from canguard.io.candump import write_candump
from canguard.io.frame import Frame
from canguard.io.logs import ReadStats, read_log
from checkout import REPO

CONFIG = REPO / "config" / "canguard.yaml"
SPIKE = REPO / "examples" / "spike.log.gz"
TOPIC = "/from_can_bus"
FIRST = 4500
"""Frames of the spike example taken: its pack current trips at 1.51 s, ~3,900 frames in."""


@pytest.fixture(scope="module")
def spike() -> list[Frame]:
    """The first frames of the spike example, on the bag's topic."""
    frames = []
    for frame in read_log(SPIKE):
        frames.append(frame._replace(channel=TOPIC))
        if len(frames) == FIRST:
            return frames
    return frames


ODD = [
    Frame(1700000010.0, TOPIC, 0x123, b"", False, False, False, True, False, False, 4),
    Frame(1700000010.000001, TOPIC, 0x7FF, b"", False, False, False, True),
    Frame(1700000010.1, TOPIC, 0x1234567, b"\x01\x02", True),
    Frame(1700000010.2, TOPIC, 0x4, b"\x00\x00\x00\x00\x00\x00\x00\x00", True, False, True),
    Frame(1700000010.3, TOPIC, 0x10, b""),
]
"""Remote frames (with and without a DLC), a 29-bit id, an error frame, an empty data frame."""


def _without_times(summary: dict[str, Any]) -> dict[str, Any]:
    """A summary but for the log's name and the bag's count of stamps."""
    return {k: v for k, v in summary.items() if k not in ("log", "stamps")}


class TestFrames:
    """A bag's frames are the frames candump has for the same traffic."""

    @pytest.mark.parametrize("storage", STORAGES)
    def test_each_storage_reads_what_candump_reads(self, tmp_path: Path, storage: str, spike: list[Frame]) -> None:
        """rosbag2 (sqlite3, MCAP) and ROS 1: every frame, its time, id, flags and payload as in candump -L."""
        frames = spike[:400] + ODD
        bag = write_bag(tmp_path / "bag", storage, {TOPIC: frames})
        log = tmp_path / "same.log"
        with open(log, "w", encoding="ascii") as out:
            write_candump(frames, out)
        stats = ReadStats()
        assert list(read_log(bag, stats=stats)) == list(read_log(log))
        assert stats.frames == len(frames)
        assert stats.stamps == {"header": len(frames), "record": 0}

    def test_only_data_up_to_dlc_is_payload(self, tmp_path: Path) -> None:
        """The bytes past ``dlc`` (ros2_socketcan's leftovers) are not part of the frame."""
        frame = Frame(5.0, TOPIC, 0x20, b"\x01\x02\x03")
        bag = write_bag(tmp_path / "bag", "mcap", {TOPIC: [frame]})
        assert [f.data for f in read_log(bag)] == [b"\x01\x02\x03"]

    def test_can_fd_frames(self, tmp_path: Path) -> None:
        """ros2_socketcan's FdFrame: a CAN FD frame of ``len`` bytes."""
        frames = [Frame(5.0, "/fd", 0x20, bytes(range(12)), False, True),
                  Frame(5.5, "/fd", 0x1ABCDEF, bytes(range(64)), True, True)]
        bag = write_bag(tmp_path / "bag", "sqlite3", {"/fd": frames}, msgtype=FD_FRAME)
        assert list(read_log(bag)) == frames

    @pytest.mark.parametrize("storage", STORAGES)
    def test_each_topic_is_a_channel_and_topic_chooses(self, tmp_path: Path, storage: str) -> None:
        """Two topics (messages of two sizes): both read (each its own channel), or those ``--topic`` names."""
        a = [Frame(1.0, "/a", 0x1, b"\x01"), Frame(3.0, "/a", 0x1, b"\x03")]
        b = [Frame(2.0, "/bcdef", 0x2, b"\x02")]
        bag = write_bag(tmp_path / "bag", storage, {"/a": a, "/bcdef": b})
        assert list(read_log(bag)) == [a[0], b[0], a[1]]
        assert list(read_log(bag, bag=BagOptions(("/bcdef",)))) == b

    @pytest.mark.parametrize("storage", ["sqlite3", "ros1"])
    def test_bags_without_definitions(self, tmp_path: Path, storage: str) -> None:
        """A bag that stores no message definition (rosbag2 before Iron) reads with the carried ones."""
        frames = [Frame(1.0, TOPIC, 0x1, b"\x01\x02"), Frame(2.0, TOPIC, 0x1FFFFFFF, b"", True)]
        bag = write_bag(tmp_path / "bag", storage, {TOPIC: frames}, definitions=False)
        assert list(read_log(bag)) == frames

    def test_zero_stamps_take_the_record_time(self, tmp_path: Path) -> None:
        """A zero header stamp: the record time; ``stamp="record"``: the record time throughout."""
        frames = [Frame(1.0, TOPIC, 0x1, b"\x01"), Frame(2.0, TOPIC, 0x1, b"\x02")]
        late = write_bag(tmp_path / "late", "mcap", {TOPIC: frames},
                         record_ns=lambda i, f: int(f.t * 1e9) + 250_000_000)
        stats = ReadStats()
        assert [f.t for f in read_log(late, stats=stats, bag=BagOptions(stamp="record"))] == [1.25, 2.25]
        assert stats.stamps == {"header": 0, "record": 2}
        assert [f.t for f in read_log(late)] == [1.0, 2.0]
        zero = write_bag(tmp_path / "zero", "mcap", {TOPIC: frames}, zero_stamps=True,
                         record_ns=lambda i, f: int(f.t * 1e9) + 250_000_000)
        stats = ReadStats()
        assert [f.t for f in read_log(zero, stats=stats)] == [1.25, 2.25]
        assert stats.stamps == {"header": 0, "record": 2}


class TestReplay:
    """A bag replays as the candump log of the same frames: the same events and summary."""

    @pytest.mark.parametrize("storage", STORAGES)
    def test_events_and_summary_equal_candump(self, tmp_path: Path, storage: str, spike: list[Frame]) -> None:
        """The spike example's pack trip falls at the frames' header stamps, as in candump."""
        cfg = load_config(CONFIG)
        bag = write_bag(tmp_path / "bag", storage, {TOPIC: spike})
        log = tmp_path / "same.log"
        with open(log, "w", encoding="ascii") as out:
            write_candump(spike, out)
        got = replay_one(cfg, bag, ReplayOptions(events=tmp_path / "bag.jsonl"))
        want = replay_one(cfg, log, ReplayOptions(events=tmp_path / "log.jsonl"))
        assert want["trip_count"] == 1
        assert _without_times(got) == _without_times(want)
        assert got["stamps"] == {"header": len(spike), "record": 0} and "stamps" not in want
        assert (tmp_path / "bag.jsonl").read_text() == (tmp_path / "log.jsonl").read_text()


def _error(capsys: pytest.CaptureFixture[str], *argv: object) -> str:
    """The one line ``canguard replay`` says of a bad bag (exit 2)."""
    code, _out, err = cli(capsys, "replay", *argv, "-c", CONFIG)
    assert code == 2, err
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("canguard replay: error")]
    assert len(lines) == 1, err
    return lines[0]


class TestBadBags:
    """Every bad bag is exit 2, one line naming the file and what was found."""

    @pytest.mark.parametrize("storage", STORAGES)
    def test_a_cut_bag(self, capsys: pytest.CaptureFixture[str], tmp_path: Path, storage: str) -> None:
        """A bag cut short (the recorder died): its name, and how many frames were read."""
        frames = [Frame(1.0 + i / 1000, TOPIC, 0x1, b"\x01\x02") for i in range(300)]
        whole = storage_file(write_bag(tmp_path / "bag", storage, {TOPIC: frames}))
        cut = tmp_path / f"cut{whole.suffix}"
        cut.write_bytes(whole.read_bytes()[: whole.stat().st_size * 2 // 3])
        line = _error(capsys, cut)
        assert line.startswith(f"{cut}: ") and "frames" in line

    def test_a_cut_mcap_keeps_the_frames_before_the_cut(self, capsys: pytest.CaptureFixture[str],
                                                        tmp_path: Path) -> None:
        """A recorder that died mid-MCAP: the chunks before the cut replay, and the error says how many frames."""
        from rosbags.rosbag2 import StoragePlugin, Writer

        store = typestore()
        raw = store.serialize_cdr(message(store, FRAME, Frame(1.0, TOPIC, 0x1, b"\x01\x02"), 10**9), FRAME)
        bag = tmp_path / "bag"
        with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:  # chunks of 1 MiB: ~14,000 messages
            conn = w.add_connection(TOPIC, FRAME, typestore=store)
            for i in range(30_000):
                w.write(conn, 10**9 + i * 1000, raw)
        whole = storage_file(bag)
        cut = tmp_path / "cut.mcap"
        cut.write_bytes(whole.read_bytes()[: whole.stat().st_size * 2 // 3])
        stats = ReadStats()
        with pytest.raises(LogFormatError) as err:
            for _frame in read_log(cut, stats=stats):
                pass
        assert str(err.value).startswith(f"{cut}: truncated MCAP: the file ends at byte {cut.stat().st_size}, inside "
                                         "the chunk record of ")
        assert str(err.value).endswith(f"; {stats.frames} frames were read before the cut")
        assert 10_000 < stats.frames < 30_000

    def test_no_can_topic(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """A bag without any CAN topic names the topics it has."""
        from rosbags.rosbag2 import Writer

        store = typestore()
        bag = tmp_path / "bag"
        with Writer(bag, version=9) as w:
            conn = w.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
            w.write(conn, 1, store.serialize_cdr(store.types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String"))
        line = _error(capsys, bag)
        assert line.startswith(f"{bag}: no topic of a CAN frame type") and "/chatter (std_msgs/msg/String)" in line

    def test_a_topic_not_in_the_bag(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """``--topic`` naming a topic the bag lacks: the bag's topics listed."""
        bag = write_bag(tmp_path / "bag", "mcap", {TOPIC: [Frame(1.0, TOPIC, 0x1, b"")]})
        line = _error(capsys, bag, "--topic", "/can1")
        assert line == f"{bag}: no topic /can1 in the bag; its topics: {TOPIC} ({FRAME})"

    def test_an_unknown_can_type(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """A topic of a CAN-ish type canguard does not know: its type named."""
        from rosbags.rosbag2 import Writer

        definition = "uint32 id\nuint8[8] data\n"
        store = typestore(definitions={"can_msgs/msg/CanFrame": definition})
        bag = tmp_path / "bag"
        with Writer(bag, version=9) as w:
            conn = w.add_connection("/can", "can_msgs/msg/CanFrame", typestore=store)
            msg = store.types["can_msgs/msg/CanFrame"](id=1, data=np.zeros(8, np.uint8))
            w.write(conn, 1, store.serialize_cdr(msg, "can_msgs/msg/CanFrame"))
        line = _error(capsys, bag)
        assert line.startswith(f"{bag}: topic /can has type can_msgs/msg/CanFrame, not a CAN frame type canguard")

    def test_a_known_type_defined_otherwise(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """A bag whose definition of can_msgs/msg/Frame has other fields is refused, not read at guessed places."""
        from rosbags.rosbag2 import Writer

        definition = "std_msgs/Header header\nuint32 id\nuint8 dlc\nuint8[8] data\n"
        store = typestore(definitions={FRAME: definition})
        bag = tmp_path / "bag"
        with Writer(bag, version=9) as w:
            w.add_connection(TOPIC, FRAME, typestore=store)
        line = _error(capsys, bag)
        assert line.startswith(f"{bag}: topic {TOPIC}: its type {FRAME} is defined in the bag with fields")

    def test_a_bad_message(self, capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
        """A message no CAN frame (an 11-bit id above 7FF): its number and topic, and the frames before it."""
        frames = [Frame(1.0, TOPIC, 0x1, b"\x01"), Frame(2.0, TOPIC, 0x1, b"\x02"), Frame(3.0, TOPIC, 0x800, b"")]
        bag = write_bag(tmp_path / "bag", "mcap", {TOPIC: frames})
        line = _error(capsys, bag)
        assert line == f"{bag}: message 3 (topic {TOPIC}): 11-bit id 800 is above 7FF; 2 frames were read before it"
        code, out, _err = cli(capsys, "replay", bag, "-c", CONFIG, "--skip-bad", "--json")
        assert code == 0 and json.loads(out)["frames"]["bad_lines"] == 1


@pytest.mark.slow
def test_replay_a_bag_directory_end_to_end(installed_canguard: Path, tmp_path: Path, spike: list[Frame]) -> None:
    """``canguard replay BAG --topic /from_can_bus --json`` on a rosbag2 directory; without the extra, how to get it."""
    import subprocess
    import sys

    bag = write_bag(tmp_path / "bag", "mcap", {TOPIC: spike})
    argv = ["replay", str(bag), "--topic", TOPIC, "-c", str(CONFIG), "--json", "--fail-on-trip"]
    proc = subprocess.run([sys.executable, "-m", "canguard", *argv], capture_output=True, text=True, timeout=120,
                          check=False, cwd=tmp_path)
    assert proc.returncode == 1, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["trip_count"] == 1 and 1700000001.5 < summary["trips"][0]["t"] < 1700000001.52  # header stamps
    assert summary["stamps"] == {"header": len(spike), "record": 0}
    bare = subprocess.run([str(installed_canguard), *argv], capture_output=True, text=True, timeout=120, check=False)
    assert bare.returncode == 2
    assert f"{bag}: reading ROS bags needs rosbags: pip install 'canguard[rosbags]'" in bare.stderr


class TestMcapOut:
    """``--export-signals FILE.mcap`` and ``--emit FILE.mcap`` / a rosbag2 directory, read back with the ``mcap``
    library's reader and rosbags' (not canguard's)."""

    @pytest.fixture(scope="class")
    @classmethod
    def replayed(cls, tmp_path_factory: pytest.TempPathFactory, spike: list[Frame]) -> dict[str, Any]:
        """The spike bag replayed once with every output: MCAP export, events, emits as MCAP, directory, candump;
        and once with the Parquet export."""
        tmp = tmp_path_factory.mktemp("mcap")
        bag = write_bag(tmp / "bag", "sqlite3", {TOPIC: spike})
        cfg = load_config(CONFIG)
        summary = replay_one(cfg, bag, ReplayOptions(export=tmp / "out.mcap", events=tmp / "events.jsonl",
                                                     emit=tmp / "stops.mcap"))
        replay_one(cfg, bag, ReplayOptions(export=tmp / "out.parquet", emit=tmp / "stops.log"))
        replay_one(cfg, bag, ReplayOptions(emit=tmp / "stops"))
        return {"tmp": tmp, "summary": summary}

    @staticmethod
    def _messages(path: Path) -> dict[str, list[Any]]:
        from mcap.reader import make_reader

        out: dict[str, list[Any]] = {}
        with open(path, "rb") as f:
            for _schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
                out.setdefault(channel.topic, []).append(message)
        return out

    def test_samples_equal_the_parquet_export(self, replayed: dict[str, Any]) -> None:
        """Per source and role a channel of its samples: the values and times the Parquet export has."""
        pq = pytest.importorskip("pyarrow.parquet")
        tmp = replayed["tmp"]
        got = self._messages(tmp / "out.mcap")
        table = pq.read_table(tmp / "out.parquet").to_pylist()
        want: dict[str, list[tuple[int, float]]] = {}
        for row in table:
            topic = f"/canguard/samples/{row['source'].strip('/')}/{row['signal']}"
            want.setdefault(topic, []).append((round(row["t"] * 1e6), row["value"]))
        samples = {t: m for t, m in got.items() if t.startswith("/canguard/samples/")}
        assert set(samples) == set(want)
        for topic, messages in samples.items():
            values = [(round(m.log_time / 1000), struct.unpack_from("<d", m.data, 4)[0]) for m in messages]
            assert values == want[topic], topic

    def test_events_guards_and_frames(self, replayed: dict[str, Any]) -> None:
        """The events as the journal has them, at the bag's stamps; the guard's threshold; the frames sent."""
        tmp, summary = replayed["tmp"], replayed["summary"]
        got = self._messages(tmp / "out.mcap")
        journal = [json.loads(line) for line in (tmp / "events.jsonl").read_text().splitlines()]
        events = [json.loads(m.data) for m in got["/canguard/events"]]
        assert [(e["event"], e["t"]) for e in events] == [(e["event"], e["t"]) for e in journal]
        trip = next(m for m in got["/canguard/events"] if json.loads(m.data)["event"] == "trip")
        assert abs(trip.log_time - summary["trips"][0]["t"] * 1e9) < 1000
        (guard,) = [t for t in got if t.startswith("/canguard/guards/")]
        assert {struct.unpack_from("<d", m.data, 12)[0] for m in got[guard]} == {35.0}
        sent = got["/canguard/frames_out"]
        assert len(sent) == summary["frames_sent"]
        store = typestore()
        frames = [store.deserialize_cdr(m.data, FRAME) for m in sent]
        text = list(read_log(tmp / "stops.log"))
        assert [(f.id, bytes(f.data[:f.dlc])) for f in frames] == [(f.arbitration_id, f.data) for f in text]

    @pytest.mark.parametrize("name", ["stops.mcap", "stops"])
    def test_emit_as_a_bag(self, replayed: dict[str, Any], name: str) -> None:
        """``--emit`` as MCAP or a rosbag2 directory: can_msgs/msg/Frame on /to_can_bus, stamped at the sends."""
        from rosbags.rosbag2 import Reader

        tmp = replayed["tmp"]
        text = list(read_log(tmp / "stops.log"))
        store = typestore()
        with Reader(tmp / name) as reader:
            assert [(c.topic, c.msgtype) for c in reader.connections] == [("/to_can_bus", FRAME)]
            got = []
            for _conn, record_ns, raw in reader.messages():
                msg = store.deserialize_cdr(raw, FRAME)
                stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                assert abs(stamp - record_ns) == 0
                got.append((stamp / 1e9, msg.id, bytes(msg.data[:msg.dlc])))
        assert [g[1:] for g in got] == [(f.arbitration_id, f.data) for f in text]
        assert all(abs(g[0] - f.t) < 1.5e-6 for g, f in zip(got, text, strict=True))  # candump keeps microseconds


def test_a_directory_of_logs_holds_bags_whole(tmp_path: Path) -> None:
    """``replay DIR``: a rosbag2 directory inside is one log (not its storage file), beside the other logs."""
    from canguard.cli.fleet import expand_logs

    bag = write_bag(tmp_path / "run1", "mcap", {TOPIC: [Frame(1.0, TOPIC, 0x1, b"")]})
    ros1 = write_bag(tmp_path / "old", "ros1", {TOPIC: [Frame(1.0, TOPIC, 0x1, b"")]})
    (tmp_path / "can.log").write_text("(1.000000) can0 001#\n", encoding="ascii")
    assert expand_logs([tmp_path]) == sorted([bag, ros1, tmp_path / "can.log"])
    assert expand_logs([bag]) == [bag]
