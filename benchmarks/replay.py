"""Suite ``replay``: ``canguard replay`` of logs of every shape and of every log format, beside its peers.

Shapes (benchmarks/shapes.py): each shape's log replayed by ``canguard replay LOG -c CONFIG --json``
(decode, protection models, tree), beside two peers in the same rounds, the three taking turns:

* the plain cantools loop (:data:`PEER_LOOP`): split each line, ``bytes.fromhex``,
  ``Database.decode_message`` for the ids of the DBC, nothing printed: decoding alone, the
  strongest pure-Python peer;
* can-utils ``log2long`` (C: parses and prints every frame), where installed.

Formats: the simulator's overload log written again by python-can's writers (ASC, BLF, TRC, CSV; MF4
where asammdf is installed) and replayed, beside python-can's reader alone iterating the file (a floor
for the formats canguard reads through python-can).

ROS bags (where the ``rosbags`` extra is installed): the simulator's overload log written as
``can_msgs/msg/Frame`` messages on ``/from_can_bus`` into a rosbag2 MCAP bag, a rosbag2 sqlite3 bag
(``.db3``) and a ROS 1 bag (rosbags' writers; the messages serialised by canguard's
``cdr_frame``, ROS 1's packed here), each replayed beside the candump replay of the same frames;
and the MCAP bag replayed with ``--export-signals FILE.mcap`` beside its replay without it.
Goals: a bag replays in at most 2× the candump log's time; the export costs at most 1.5× the replay.

Whole processes, interpreter start-up included, best of N rounds (wall and CPU, user + system).
"× peer" is the peer's time over canguard's: above 1 canguard is faster.
"""

from __future__ import annotations

import importlib.util
import json
import os
import struct
import sys
from pathlib import Path

from benchmarks import kit, shapes
from benchmarks.kit import Options, Table, Timing

PEER_LOOP = '''
import sys, cantools
db = cantools.database.load_file(sys.argv[1])
ids = {m.frame_id for m in db.messages}
decode = db.decode_message
n = 0
with open(sys.argv[2], encoding="ascii") as f:
    for line in f:
        cid, _, data = line.split()[2].partition("#")
        if data[:1] == "#":  # CAN FD: ID##<flags><data>
            data = data[2:]
        fid = int(cid, 16)
        if fid in ids:
            decode(fid, bytes.fromhex(data))
            n += 1
print(n)
'''

READER_LOOP = """
import sys, can
n = 0
for _msg in can.LogReader(sys.argv[1]):
    n += 1
print(n)
"""

COLUMNS = ["log", "frames", "canguard s", "canguard CPU s", "peer", "peer s", "× peer", "× peer (CPU)",
           "log2long s", "× log2long"]
FORMATS = ("asc", "blf", "trc", "csv") + (("mf4",) if importlib.util.find_spec("asammdf") else ())


TOPIC = "/from_can_bus"
STORAGES = ("mcap", "sqlite3", "ros1")
STORAGE_NAMES = {"mcap": "MCAP bag (rosbag2)", "sqlite3": ".db3 bag (rosbag2 sqlite3)", "ros1": "ROS 1 bag"}


def sizes(opts: Options) -> tuple[int, int, int]:
    """Frames per shape log, frames of the formats' log, frames of the bags."""
    return (2_000, 600, 600) if opts.quick else (2_000_000, 300_000, 1_000_000)


def overload_log(frames: int) -> tuple[Path, int]:
    """The simulator's overload log of about ``frames`` frames (cached): its path and its frame count."""
    log = shapes.CACHE / f"overload-v{shapes.VERSION}-{frames}.log"
    if not log.exists():
        shapes.CACHE.mkdir(parents=True, exist_ok=True)
        import cantools

        from canguard.sim import write_log

        tmp = log.with_suffix(f".{os.getpid()}.tmp")
        write_log(tmp, frames / 2571.0, db=cantools.database.load_file(kit.DBC), scenarios=["overload"], seed=0)
        tmp.replace(log)
    with open(log, "rb") as f:
        return log, sum(1 for _ in f)


def log2long(log: Path) -> Timing:
    """can-utils' ``log2long < LOG > /dev/null``."""
    return kit.process([str(kit.which("log2long"))], kit.SRC, stdin=log, ok=(0,))


def shape_row(w: shapes.Written, opts: Options, rounds: int) -> list[kit.Cell]:
    """One shape: canguard, the loop and log2long taking turns."""
    runs = [lambda: kit.canguard(["replay", str(w.log), "-c", str(w.config), "--json"], opts),
            lambda: kit.python(PEER_LOOP, [str(w.dbc), str(w.log)], opts)]
    if kit.which("log2long"):
        runs.append(lambda: log2long(w.log))
    got = kit.best_of(runs, rounds)
    cg, loop = got[0], got[1]
    l2l = got[2] if len(got) > 2 else None
    return [f"{w.name}: {w.what}", w.frames, cg.wall_s, cg.cpu_s, "plain cantools loop", loop.wall_s,
            kit.ratio(loop.wall_s, cg.wall_s), kit.ratio(loop.cpu_s, cg.cpu_s),
            l2l.wall_s if l2l else None, kit.ratio(l2l.wall_s, cg.wall_s) if l2l else None]


def convert(log: Path, fmt: str) -> Path:
    """``log`` (candump -L) written again by python-can's writer for ``fmt`` (cached beside it)."""
    import can

    out = log.with_suffix("." + fmt)
    if not out.exists():
        tmp = out.with_name(f"{out.stem}.{os.getpid()}.tmp.{fmt}")
        with can.Logger(str(tmp)) as writer:
            for msg in can.CanutilsLogReader(str(log)):
                writer.on_message_received(msg)
        tmp.replace(out)
    return out


def comparable(summary: bytes) -> dict[str, object]:
    """A ``--json`` summary without what differs by format alone (the log's name, relative timestamps)."""
    doc = json.loads(summary)
    for key in ("log", "first_t", "last_t"):
        doc.pop(key, None)
    return doc  # type: ignore[no-any-return]


def format_rows(frames: int, opts: Options, rounds: int) -> list[list[kit.Cell]]:
    """Each format of the overload log: canguard's replay beside python-can's reader alone; summaries equal."""
    log, n = overload_log(frames)
    rows, reference = [], None
    for fmt in FORMATS:
        path = convert(log, fmt)
        argv = ["replay", str(path), "-c", str(kit.CONFIG), "--json"]
        cg, reader = kit.best_of([lambda a=argv: kit.canguard(a, opts),
                                  lambda p=path: kit.python(READER_LOOP, [str(p)], opts)], rounds)
        got = comparable(cg.out)
        reference = reference or got
        if got != reference:
            raise RuntimeError(f"replay of the {fmt} log: its summary differs from the {FORMATS[0]} log's")
        rows.append([f"{fmt.upper()} (overload scenario)", n, cg.wall_s, cg.cpu_s, "python-can reader alone",
                     reader.wall_s, kit.ratio(reader.wall_s, cg.wall_s), kit.ratio(reader.cpu_s, cg.cpu_s), None, None])
    return rows


def ros_messages(log: Path, ros1: bool) -> list[tuple[int, bytes]]:
    """The candump log's frames as (record time ns, serialised ``can_msgs/msg/Frame``): rosbag2's CDR
    (canguard's :func:`~canguard.io.rosmsgs.cdr_frame`), or ROS 1's layout packed here."""
    import can

    from canguard.io.rosmsgs import cdr_frame

    out = []
    for msg in can.CanutilsLogReader(str(log)):
        ns = round(msg.timestamp * 1e6) * 1000
        data = bytes(msg.data)
        if ros1:
            sec, nsec = divmod(ns, 10**9)
            raw = struct.pack("<IIII4sI???B", 0, sec, nsec, 4, b"can0", msg.arbitration_id, msg.is_remote_frame,
                              msg.is_extended_id, msg.is_error_frame, len(data)) + data.ljust(8, b"\x00")
        else:
            raw = cdr_frame(ns, "can0", msg.arbitration_id, data, extended=msg.is_extended_id,
                            remote=msg.is_remote_frame, error=msg.is_error_frame)
        out.append((ns, raw))
    return out


def write_bag(log: Path, storage: str) -> Path:
    """``log``'s frames as a bag of ``storage`` (mcap, sqlite3: rosbag2 directories; ros1: a .bag), cached beside it."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from canguard.io.rosmsgs import CAN_MSGS_FRAME

    ros1 = storage == "ros1"
    path = log.with_name(f"{log.stem}.bag" if ros1 else f"{log.stem}-{storage}")
    if path.exists():
        return path
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(CAN_MSGS_FRAME, "can_msgs/msg/Frame"))
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp{path.suffix}")
    if ros1:
        with Writer1(tmp) as w:
            msgdef, md5 = store.generate_msgdef("can_msgs/msg/Frame")
            conn = w.add_connection(TOPIC, "can_msgs/msg/Frame", msgdef=msgdef, md5sum=md5)
            for ns, raw in ros_messages(log, True):
                w.write(conn, ns, raw)
    else:
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        with Writer2(tmp, version=9, storage_plugin=plugin) as w:
            conn = w.add_connection(TOPIC, "can_msgs/msg/Frame", typestore=store)
            for ns, raw in ros_messages(log, False):
                w.write(conn, ns, raw)
    tmp.rename(path)
    return path


def bag_rows(frames: int, opts: Options, rounds: int, tmp: Path) -> list[list[kit.Cell]]:
    """Each storage of the overload log's frames beside the candump replay of the log, and the MCAP bag with
    ``--export-signals`` beside it without; all taking turns, summaries equal (but for the bag's stamp counts)."""
    log, n = overload_log(frames)
    runs = {"candump": (log, ())} | {s: (write_bag(log, s), ()) for s in STORAGES}
    runs["export"] = (runs["mcap"][0], ("--export-signals", str(tmp / "signals.mcap")))
    argvs = [["replay", str(path), "-c", str(kit.CONFIG), "--json", *extra] for path, extra in runs.values()]
    got = dict(zip(runs, kit.best_of([lambda a=a: kit.canguard(a, opts) for a in argvs], rounds), strict=True))
    reference = comparable(got["candump"].out)
    for name, timing in got.items():
        if {k: v for k, v in comparable(timing.out).items() if k != "stamps"} != reference:
            raise RuntimeError(f"replay of the {name} bag: its summary differs from the candump log's")
    peer = got["candump"]
    rows = [[f"{STORAGE_NAMES[s]} (overload scenario)", n, got[s].wall_s, got[s].cpu_s, "candump replay, same frames",
             peer.wall_s, kit.ratio(peer.wall_s, got[s].wall_s), kit.ratio(peer.cpu_s, got[s].cpu_s), None, None]
            for s in STORAGES]
    rows.sort(key=lambda r: r[6] if isinstance(r[6], float) else 0.0)
    size_mb = (tmp / "signals.mcap").stat().st_size / 1e6
    ex, plain = got["export"], got["mcap"]
    rows.append([f"MCAP bag with --export-signals FILE.mcap ({size_mb:.3g} MB)", n, ex.wall_s, ex.cpu_s,
                 "the same replay without it", plain.wall_s, kit.ratio(plain.wall_s, ex.wall_s),
                 kit.ratio(plain.cpu_s, ex.cpu_s), None, None])
    return rows


def run(opts: Options) -> Table:
    """The replay table: shapes worst first (× plain cantools loop), then formats worst first."""
    rounds = 1 if opts.quick else opts.rounds
    frames, format_frames, bag_frames = sizes(opts)
    table = Table("replay", f"`canguard replay` against the plain cantools loop, can-utils `log2long` and python-can's "
                  f"readers; best of {rounds}, {'in-process (--quick)' if opts.inprocess else 'whole processes'}",
                  COLUMNS, costs=["canguard s", "canguard CPU s"])
    with kit.scratch("replay") as d:
        rows = [shape_row(w, opts, rounds) for w in shapes.all_shapes(Path(d), frames)]
        rows.sort(key=lambda r: r[6] if isinstance(r[6], float) else 0.0)
        fmts = format_rows(format_frames, opts, rounds)
        fmts.sort(key=lambda r: r[6] if isinstance(r[6], float) else 0.0)
        bags = bag_rows(bag_frames, opts, rounds, Path(d)) if importlib.util.find_spec("rosbags") else []
    table.rows = rows + fmts + bags
    if not bags:
        table.notes.append("ROS bags not measured: the rosbags extra is not installed (pip install -e '.[rosbags]')")
    if not kit.which("log2long"):
        table.notes.append("log2long not installed (apt-get install -y can-utils): its columns are empty")
    table.notes += ["× peer: the peer's time over canguard's (above 1: canguard is faster); wall time, then CPU",
                    "shapes first, then formats, then ROS bags (× peer: the candump replay of the same frames), each "
                    "worst first, then the MCAP export (× peer: the replay without it); the formats' and bags' "
                    "replays give equal summaries",
                    f"Python {sys.version.split()[0]}; logs cached in {shapes.CACHE}"]

    if opts.quick:
        table.notes.append("--quick: tiny logs, canguard and the loop in this process: checks that the suite runs, "
                           "its figures mean nothing")
    return table
