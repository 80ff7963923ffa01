"""``canguard replay`` on logs of several shapes, against the strongest peers, worst shape first.

    python benchmarks/bench_replay_shapes.py [--frames N] [--repeat R] [--keep DIR]

For each shape the bench writes, deterministically (seeded), a DBC (built with
cantools' own API and dumped), a canguard config whose tree guards every configured
signal, and a candump -L log of about N frames (default 600,000). Then, whole
processes, interpreter start-up included, best of R rounds in which the three take turns
(wall time and CPU time, user + system, of each process: on a shared machine the CPU ratio
is the steadier one):

* ``canguard replay LOG -c CONFIG --json`` (decode + protection models + tree);
* the plain cantools loop (``PEER_LOOP`` below, 15 lines): split each line,
  ``bytes.fromhex``, ``Database.decode_message`` for the ids in the DBC, nothing
  printed — decoding alone, in one process, the strongest pure-Python peer;
* can-utils ``log2long`` (C; parses and prints every frame), when installed.

Shapes:

* ``own``: the project's own simulator log (4 ODrive axes + BMS + noise ids, classic, Intel);
* ``fd_mux_motorola``: 100 % configured: CAN FD 64-byte effort frames of 16 signed
  Motorola signals, a multiplexed message with 4 pages, signed Motorola currents;
* ``many_ids``: 500 distinct standard ids, 10 % configured (one signal each);
* ``ext_motorola``: extended-id Motorola drive frames + a multiplexed BMS message
  + noise ids, 30 % configured;
* ``two_buses``: a robot's two interfaces interleaved in one log (can0: drives, can1: a
  multiplexed BMS and body messages), a config of two buses, 45 % configured.

The report lists the shapes slowest (lowest canguard / cantools ratio) first.
"""

from __future__ import annotations

import argparse
import os
import random
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"
if str(SRC) not in sys.path:
    sys.path.insert(0, str(SRC))

import cantools  # noqa: E402
from cantools.database.can import Database, Message, Signal  # noqa: E402
from cantools.database.conversion import BaseConversion  # noqa: E402

from bench_common import compiled  # noqa: E402

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


@dataclass
class Shape:
    name: str
    what: str
    db: Database
    guarded: list[tuple[str, str]]  # (message, signal) pairs the config's sources read
    frame: Callable[[random.Random, float], tuple[int, bool, bool, bytes]]  # -> id, extended, fd, data
    channel_of: Callable[[int], str] | None = None  # frame id -> channel (None: all on can0, bus main)
    bus_of: dict[str, str] | None = None  # message -> bus (main on can0, aux on can1)


def sig(name: str, start: int, length: int, *, signed: bool = False, motorola: bool = False,
        scale: float = 0.01, mux_ids: list[int] | None = None, is_mux: bool = False) -> Signal:
    return Signal(name, start, length, byte_order="big_endian" if motorola else "little_endian",
                  is_signed=signed, conversion=BaseConversion.factory(scale=scale, offset=0.0),
                  multiplexer_ids=mux_ids, multiplexer_signal="Page" if mux_ids else None, is_multiplexer=is_mux)


def fd_mux_motorola() -> Shape:
    msgs = []
    # 4 FD effort frames: 16 signed Motorola 16-bit signals in 64 bytes (start bit = MSB position, DBC style)
    for a in range(4):
        signals = [sig(f"Effort{k}", 8 * (4 * k) + 7, 16, signed=True, motorola=True) for k in range(16)]
        msgs.append(Message(0x100 + a, f"Effort{a}", 64, signals, is_fd=True))
    # a multiplexed message: page selector + 4 pages of 2 signed currents
    mux_signals = [sig("Page", 0, 8, is_mux=True, scale=1)]
    for page in range(4):
        mux_signals += [sig(f"I{page}a", 8, 16, signed=True, mux_ids=[page]),
                        sig(f"I{page}b", 24, 16, signed=True, mux_ids=[page])]
    msgs.append(Message(0x200, "MuxCurrents", 8, mux_signals))
    # signed Motorola currents, classic
    for a in range(4):
        msgs.append(Message(0x300 + a, f"Motor{a}", 8, [sig("Iq", 7, 16, signed=True, motorola=True),
                                                       sig("Id", 23, 16, signed=True, motorola=True)]))
    db = Database(messages=msgs)
    guarded = [(f"Effort{a}", "Effort0") for a in range(4)] + [("MuxCurrents", "I0a")] + \
              [(f"Motor{a}", "Iq") for a in range(4)]
    ids = [(0x100 + a, True) for a in range(4)] + [(0x200, False)] + [(0x300 + a, False) for a in range(4)]

    def frame(rng: random.Random, t: float) -> tuple[int, bool, bool, bytes]:
        fid, fd = ids[rng.randrange(len(ids))]
        if fid == 0x200:
            return fid, False, False, bytes([rng.randrange(4)]) + small(rng, 7, "little")
        return fid, False, fd, small(rng, 64 if fd else 8)

    return Shape("fd_mux_motorola", "100 % configured: CAN FD 64 B, mux, signed Motorola", db, guarded, frame)


def small(rng: random.Random, n: int, order: str = "big") -> bytes:
    """Bytes whose 16-bit signals stay small (|x| < 20 A at 0.01 A/bit): no trips, every sample judged."""
    out = bytearray()
    for _ in range(n // 2):
        v = rng.randrange(-1500, 1500) & 0xFFFF
        out += v.to_bytes(2, order)  # type: ignore[arg-type]
    return bytes(out[:n]) + bytes(n - len(out))


def many_ids() -> Shape:
    configured = list(range(0x100, 0x100 + 50))
    msgs = [Message(fid, f"M{fid:03X}", 8, [sig("Cur", 0, 16, signed=True)]) for fid in configured]
    db = Database(messages=msgs)
    guarded = [(f"M{fid:03X}", "Cur") for fid in configured[:20]]
    noise = list(range(0x400, 0x400 + 450))

    def frame(rng: random.Random, t: float) -> tuple[int, bool, bool, bytes]:
        fid = configured[rng.randrange(50)] if rng.random() < 0.10 else noise[rng.randrange(450)]
        data = bytearray(rng.randbytes(8))
        data[0:2] = (rng.randrange(-1500, 1500) & 0xFFFF).to_bytes(2, "little")
        return fid, False, False, bytes(data)

    return Shape("many_ids", "500 ids, 10 % configured", db, guarded, frame)


def ext_motorola() -> Shape:
    drives = [0x18FF0000 + a for a in range(6)]
    msgs = [Message(fid, f"Drive{i}", 8, [sig("Iq", 7, 16, signed=True, motorola=True),
                                          sig("Vel", 23, 16, signed=True, motorola=True)], is_extended_frame=True)
            for i, fid in enumerate(drives)]
    bms = [sig("Page", 0, 8, is_mux=True, scale=1)] + [sig(f"P{p}", 8, 16, signed=True, mux_ids=[p]) for p in range(3)]
    msgs.append(Message(0x18FF50E5, "BMS", 8, bms, is_extended_frame=True))
    db = Database(messages=msgs)
    guarded = [(f"Drive{i}", "Iq") for i in range(6)] + [("BMS", "P0")]
    noise = [0x18FE0000 + k for k in range(40)] + list(range(0x700, 0x720))

    def frame(rng: random.Random, t: float) -> tuple[int, bool, bool, bytes]:
        r = rng.random()
        if r < 0.25:
            return drives[rng.randrange(6)], True, False, small(rng, 8)
        if r < 0.30:
            return 0x18FF50E5, True, False, bytes([rng.randrange(3)]) + small(rng, 7, "little")
        fid = noise[rng.randrange(len(noise))]
        return fid, fid > 0x7FF, False, rng.randbytes(8)

    return Shape("ext_motorola", "extended-id Motorola drives + mux BMS + noise, 30 % configured", db, guarded, frame)


def two_buses() -> Shape:
    """A robot with two interfaces interleaved in one log: drives on can0, BMS and body on can1."""
    drives = list(range(0x140, 0x148))  # 8 drive messages, 4 guarded
    body = list(range(0x300, 0x306))  # 6 on can1, 2 guarded (a mux BMS among them)
    msgs = [Message(fid, f"Drv{fid:03X}", 8, [sig("Iq", 0, 16, signed=True), sig("Vel", 16, 16, signed=True)])
            for fid in drives]
    msgs += [Message(fid, f"Body{fid:03X}", 8, [sig("Cur", 0, 16, signed=True)]) for fid in body[1:]]
    bms = [sig("Page", 0, 8, is_mux=True, scale=1)] + [sig(f"P{p}", 8, 16, signed=True, mux_ids=[p]) for p in range(3)]
    msgs.append(Message(body[0], "BMS", 8, bms))
    db = Database(messages=msgs)
    guarded = [(f"Drv{fid:03X}", "Iq") for fid in drives[:4]] + [("BMS", "P0"), (f"Body{body[1]:03X}", "Cur")]
    noise0, noise1 = list(range(0x500, 0x520)), list(range(0x600, 0x620))
    on_can1 = set(body) | set(noise1)

    def frame(rng: random.Random, t: float) -> tuple[int, bool, bool, bytes]:
        r = rng.random()
        if r < 0.35:
            return drives[rng.randrange(8)], False, False, small(rng, 8, "little")
        if r < 0.45:
            fid = body[rng.randrange(6)]
            if fid == body[0]:
                return fid, False, False, bytes([rng.randrange(3)]) + small(rng, 7, "little")
            return fid, False, False, small(rng, 8, "little")
        return (noise0 if r < 0.75 else noise1)[rng.randrange(20)], False, False, rng.randbytes(8)

    return Shape("two_buses", "two interfaces interleaved: can0 drives, can1 BMS + body, 2 buses, 45 % configured",
                 db, guarded, frame, channel_of=lambda fid: "can1" if fid in on_can1 else "can0",
                 bus_of={m.name: ("aux" if m.frame_id in on_can1 else "main") for m in msgs})


def write_shape(shape: Shape, out: Path, frames: int) -> tuple[Path, Path, Path]:
    """DBC, config (+ tree) and log of a shape in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    dbc = out / f"{shape.name}.dbc"
    dbc.write_text(shape.db.as_dbc_string(), encoding="ascii")
    bus_of = shape.bus_of or {}
    sources = "\n".join(f"  s{i}: {{kind: current, bus: {bus_of.get(m, 'main')}, message: {m}, signal: {s}, "
                        "max_age: 5}" for i, (m, s) in enumerate(shape.guarded))
    guards = "\n".join(f'      <IsCurrentSafe topic_name="s{i}" overcurrent_threshold="100" recovery_threshold="90"/>'
                       for i in range(len(shape.guarded)))
    tree = out / f"{shape.name}.xml"
    tree.write_text(f'<root BTCPP_format="4" main_tree_to_execute="Main">\n  <BehaviorTree ID="Main">\n'
                    f"    <ReactiveSequence>\n{guards}\n      <ExecuteTask/>\n    </ReactiveSequence>\n"
                    "  </BehaviorTree>\n</root>\n", encoding="ascii")
    cfg = out / f"{shape.name}.yaml"
    buses = "  main: {interface: virtual, channel: can0}\n" + (
        "  aux: {interface: virtual, channel: can1}\n" if shape.bus_of else "")
    cfg.write_text(f"dbc: [{dbc.name}]\nbuses:\n{buses}sources:\n{sources}\n"
                   f"tree: {{file: {tree.name}, main: Main, tick_hz: 100}}\n"
                   "task: {period: 0.02, frames: []}\nstop: {repeat: 0.05, frames: []}\n", encoding="ascii")
    log = out / f"{shape.name}.log"
    rng = random.Random(16)
    t = 1_700_000_000.0
    with open(log, "w", encoding="ascii") as f:
        for _ in range(frames):
            t += 0.000125
            fid, ext, fd, data = shape.frame(rng, t)
            cid = f"{fid:08X}" if ext else f"{fid:03X}"
            sep = "##0" if fd else "#"
            chan = shape.channel_of(fid) if shape.channel_of else "can0"
            f.write(f"({t:.6f}) {chan} {cid}{sep}{data.hex().upper()}\n")
    return dbc, cfg, log


def own_shape(out: Path, frames: int) -> tuple[Path, Path, Path]:
    """The simulator log the project's own benchmark uses, with the bundled config."""
    from canguard.config.loader import load_config
    from canguard.sim import write_log

    cfg = REPO / "config" / "canguard.yaml"
    log = out / "own.log"
    if not log.exists():
        db = load_config(cfg).database
        probe = out / "own-probe.log"
        write_log(probe, 10.0, db=db, scenarios=("normal", "load"), seed=0)
        with open(probe, encoding="ascii") as f:
            rate = sum(1 for _ in f) / 10.0  # the simulator's frames per second
        probe.unlink()
        write_log(log, frames / rate, db=db, scenarios=("normal", "load"), seed=0)
    return REPO / "dbc" / "robot.dbc", cfg, log


def run_once(cmd: list[str], stdin: Path | None = None) -> tuple[float, float]:
    """(wall, CPU) seconds of one run of ``cmd`` (CPU: user + system of the child); raises when it fails."""
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with open(stdin, "rb") if stdin else open(os.devnull, "rb") as inp:
        proc = subprocess.run(cmd, stdin=inp, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    elapsed = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(cmd)}: exit {proc.returncode}: {proc.stderr.decode()[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return elapsed, cpu


def timed_together(cmds: list[tuple[list[str], Path | None]], repeat: int) -> list[tuple[float, float]]:
    """Best (wall, CPU) of each command over ``repeat`` rounds, the commands taking turns in each round.

    Taking turns, the peers of one shape meet the same load on a shared machine; CPU time
    counts what each process did, whatever else ran beside it (wall time does not).
    """
    best = [(float("inf"), float("inf"))] * len(cmds)
    for _ in range(repeat):
        for k, (cmd, stdin) in enumerate(cmds):
            wall, cpu = run_once(cmd, stdin)
            best[k] = (min(best[k][0], wall), min(best[k][1], cpu))
    return best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=600_000)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--keep", type=Path, default=None, help="write the logs here and keep them")
    args = ap.parse_args(argv)
    compiled(SRC)  # bytecode as an installed wheel has it (bench_common.compiled)
    work = args.keep or Path(tempfile.mkdtemp(prefix="canguard-shapes-"))
    work.mkdir(parents=True, exist_ok=True)
    peer = work / "peer_loop.py"
    peer.write_text(PEER_LOOP, encoding="ascii")
    log2long = shutil.which("log2long")
    rows = []
    shapes: list[tuple[str, str, tuple[Path, Path, Path]]] = [
        ("own", "the project's own simulator log (classic, Intel, 4 axes + BMS + noise)", own_shape(work, args.frames))]
    for make in (fd_mux_motorola, many_ids, ext_motorola, two_buses):
        s = make()
        shapes.append((s.name, s.what, write_shape(s, work, args.frames)))
    for name, what, (dbc, cfg, log) in shapes:
        with open(log, encoding="ascii") as f:
            n = sum(1 for _ in f)
        cmds: list[tuple[list[str], Path | None]] = [
            ([sys.executable, "-m", "canguard", "replay", str(log), "-c", str(cfg), "--json"], None),
            ([sys.executable, str(peer), str(dbc), str(log)], None),
        ]
        if log2long:
            cmds.append(([log2long], log))
        times = timed_together(cmds, args.repeat)
        t_cg, t_ct = times[0], times[1]
        t_l2l = times[2] if log2long else None
        rows.append((name, what, n, t_cg, t_ct, t_l2l))
        print(f"measured {name}: {n} frames", file=sys.stderr)
    rows.sort(key=lambda r: r[4][0] / r[3][0])  # worst first: lowest canguard / cantools ratio (wall)
    print(f"\nreplay, whole processes, best of {args.repeat} (the three take turns), {args.frames} frames per log "
          f"(python {sys.version.split()[0]}, cantools {cantools.__version__}); worst shape first; "
          "ratios on wall time, then on CPU time (user + system)\n")
    print("| shape | frames | canguard replay | plain cantools loop | log2long "
          "| canguard / cantools | canguard / log2long | CPU: canguard / cantools | CPU: canguard / log2long |")
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name, what, n, t_cg, t_ct, t_l2l in rows:
        l2l = f"{n / t_l2l[0]:,.0f} f/s" if t_l2l else "n/a"
        r_l2l = f"{t_l2l[0] / t_cg[0]:.2f}x" if t_l2l else "n/a"
        c_l2l = f"{t_l2l[1] / t_cg[1]:.2f}x" if t_l2l else "n/a"
        print(f"| {name}: {what} | {n:,} | {n / t_cg[0]:,.0f} f/s | {n / t_ct[0]:,.0f} f/s | {l2l} | "
              f"{t_ct[0] / t_cg[0]:.2f}x | {r_l2l} | {t_ct[1] / t_cg[1]:.2f}x | {c_l2l} |")
    if args.keep is None:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
