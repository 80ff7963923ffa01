"""The logs the replay suite times: one DBC, config, tree and candump -L log per shape, seeded.

Each shape is a robot's traffic of a kind canguard meets: the project's own simulator log, and
synthetic shapes built here with cantools' own API (DBC dumped by cantools, config and tree
written beside it, every configured signal guarded). Frames are 125 µs apart (8,000 frames/s).

* ``own``: the simulator's log (4 ODrive axes + BMS + noise ids), the bundled config;
* ``stopped_guarded``: every frame feeds a guard, the robot mostly stopped: two drive currents
  under leaky I²t, a BMS message with a presence flag, six joint efforts in one message;
* ``foreign_ext``: 70 % of the frames on extended ids the config does not know, three
  configured messages, one under leaky I²t;
* ``fd_mux_motorola``: 100 % configured: CAN FD 64-byte frames of 16 signed Motorola signals,
  a multiplexed message, signed Motorola currents;
* ``many_ids``: 500 distinct standard ids, 10 % configured;
* ``ext_motorola``: extended-id Motorola drives + a multiplexed BMS + noise, 30 % configured;
* ``two_buses``: two interfaces interleaved in one log, a config of two buses, 45 % configured.

Logs are cached by shape and size in ``$TMPDIR/canguard-bench-logs`` (writing 2 M lines takes
longer than replaying them).
"""

from __future__ import annotations

import random
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import BaseConversion

from benchmarks.kit import CONFIG, DBC

CACHE = Path(tempfile.gettempdir()) / "canguard-bench-logs"
VERSION = 2
"""Bump when a generator changes: cached logs of another version are not reused."""
STEP_S = 0.000125

Frame = tuple[int, bool, bool, bytes]  # id, extended, FD, data


@dataclass
class Shape:
    """A synthetic shape: its DBC, the config's sources, the tree's guards and a frame generator."""

    name: str
    what: str
    db: Database
    sources: dict[str, dict[str, Any]]
    guards: list[str]  # the tree's guard elements, one XML element each
    frame: Callable[[random.Random, float], Frame]
    channel_of: Callable[[int], str] = field(default=lambda _fid: "can0")
    two_buses: bool = False


def sig(name: str, start: int, length: int, *, signed: bool = False, motorola: bool = False,
        scale: float = 0.01, mux_ids: list[int] | None = None, is_mux: bool = False) -> Signal:
    """A DBC signal (cantools' own type)."""
    return Signal(name, start, length, byte_order="big_endian" if motorola else "little_endian",
                  is_signed=signed, conversion=BaseConversion.factory(scale=scale, offset=0.0),
                  multiplexer_ids=mux_ids, multiplexer_signal="Page" if mux_ids else None, is_multiplexer=is_mux)


def small(rng: random.Random, n: int, order: str = "big", limit: int = 1500) -> bytes:
    """``n`` bytes of 16-bit values below ``limit`` (20 A at 0.01 A a bit: no trips, every sample judged)."""
    out = bytearray()
    for _ in range(n // 2):
        out += (rng.randrange(-limit, limit) & 0xFFFF).to_bytes(2, order)  # type: ignore[arg-type]
    return bytes(out[:n]) + bytes(n - len(out))


def current(message: str, signal: str, bus: str = "main") -> dict[str, Any]:
    """A ``kind: current`` source."""
    return {"kind": "current", "bus": bus, "message": message, "signal": signal, "max_age": 5}


def safe(topic: str) -> str:
    """A hysteresis guard far above the shapes' currents: every sample judged, none trips."""
    return f'<IsCurrentSafe topic_name="{topic}" overcurrent_threshold="100" recovery_threshold="90"/>'


def i2t(topic: str) -> str:
    """A leaky I²t guard (10 A continuous, 20 A for 1 s)."""
    return (f'<IsI2tSafe topic_name="{topic}" model="leaky" continuous_current="10.0" peak_current="20.0" '
            'peak_time="1.0"/>')


def stopped_guarded() -> Shape:
    """Every frame feeds a guard; the robot stands still but for a 1 s move every 20 s."""
    drives = [Message(0x101 + a, f"Drive{a}", 8, [sig("Iq", 0, 16, signed=True), sig("Vel", 16, 16, signed=True)])
              for a in range(2)]
    bms = Message(0x18FF50E5, "BMS", 8, [sig("Pack_Current", 0, 16, signed=True), sig("Present", 16, 1, scale=1),
                                        sig("Voltage", 24, 16)], is_extended_frame=True)
    joints = Message(0x200, "Joints", 8, [sig(f"Effort{j}", 8 * j, 8, signed=True, scale=1) for j in range(6)])
    db = Database(messages=[*drives, bms, joints])
    sources = {f"drive{a}": current(f"Drive{a}", "Iq") for a in range(2)}
    sources["battery"] = {"kind": "battery", "bus": "main", "message": "BMS", "current": "Pack_Current",
                          "present": "Present", "max_age": 5}
    sources["joints"] = {"kind": "joints", "effort": [
        {"message": "Joints", "signal": f"Effort{j}", "name": f"j{j}"} for j in range(6)]}
    guards = [i2t("drive0"), i2t("drive1"), safe("battery"),
              '<IsJointEffortNormal topic_name="joints" max_effort="150.0"/>']

    def frame(rng: random.Random, t: float) -> Frame:
        moving = t % 20.0 < 1.0
        r = rng.random()
        if r < 0.5:
            amps = rng.gauss(6.0 if moving else 0.0, 0.3)
            return 0x101 + (r < 0.25), False, False, (round(amps * 100) & 0xFFFF).to_bytes(2, "little") + bytes(6)
        if r < 0.8:
            return 0x200, False, False, bytes(rng.randrange(-20, 20) & 0xFF for _ in range(6)) + bytes(2)
        pack = round(rng.gauss(12.0 if moving else 1.5, 0.2) * 100) & 0xFFFF
        data = pack.to_bytes(2, "little") + b"\x01\x00" + (4800).to_bytes(2, "little") + bytes(2)
        return 0x18FF50E5, True, False, data

    return Shape("stopped_guarded", "every frame feeds a guard, robot mostly stopped (2 drives under I²t, BMS with "
                 "presence flag, 6 efforts in one message)", db, sources, guards, frame)


def foreign_ext() -> Shape:
    """70 % of the frames on extended ids the DBC does not know; three configured messages, one under I²t."""
    msgs = [Message(0x18FF0100, "Motor", 8, [sig("Iq", 7, 16, signed=True, motorola=True)], is_extended_frame=True),
            Message(0x18FF0200, "Aux", 8, [sig("Cur", 0, 16, signed=True)], is_extended_frame=True),
            Message(0x18FF50E5, "BMS", 8, [sig("Pack", 0, 16, signed=True)], is_extended_frame=True)]
    db = Database(messages=msgs)
    sources = {"motor": current("Motor", "Iq"), "aux": current("Aux", "Cur"), "bms": current("BMS", "Pack")}
    guards = [i2t("motor"), safe("aux"), safe("bms")]
    foreign = [0x0CF00000 + 0x100 * k + 0x21 for k in range(120)]
    ids = [m.frame_id for m in msgs]

    def frame(rng: random.Random, t: float) -> Frame:
        if rng.random() < 0.7:
            return foreign[rng.randrange(len(foreign))], True, False, rng.randbytes(8)
        fid = ids[rng.randrange(3)]
        return fid, True, False, small(rng, 2, "big" if fid == ids[0] else "little", 900) + rng.randbytes(6)

    return Shape("foreign_ext", "70 % foreign extended ids, 3 configured messages, one under I²t", db, sources,
                 guards, frame)


def fd_mux_motorola() -> Shape:
    """100 % configured: CAN FD efforts, a multiplexed message, signed Motorola currents."""
    msgs = [Message(0x100 + a, f"Effort{a}", 64, [sig(f"Effort{k}", 8 * (4 * k) + 7, 16, signed=True, motorola=True)
                                                  for k in range(16)], is_fd=True) for a in range(4)]
    mux = [sig("Page", 0, 8, is_mux=True, scale=1)]
    for page in range(4):
        mux += [sig(f"I{page}a", 8, 16, signed=True, mux_ids=[page]), sig(f"I{page}b", 24, 16, signed=True,
                                                                          mux_ids=[page])]
    msgs.append(Message(0x200, "MuxCurrents", 8, mux))
    msgs += [Message(0x300 + a, f"Motor{a}", 8, [sig("Iq", 7, 16, signed=True, motorola=True),
                                                sig("Id", 23, 16, signed=True, motorola=True)]) for a in range(4)]
    guarded = [(f"Effort{a}", "Effort0") for a in range(4)] + [("MuxCurrents", "I0a")] + \
              [(f"Motor{a}", "Iq") for a in range(4)]
    ids = [(0x100 + a, True) for a in range(4)] + [(0x200, False)] + [(0x300 + a, False) for a in range(4)]

    def frame(rng: random.Random, t: float) -> Frame:
        fid, fd = ids[rng.randrange(len(ids))]
        if fid == 0x200:
            return fid, False, False, bytes([rng.randrange(4)]) + small(rng, 7, "little")
        return fid, False, fd, small(rng, 64 if fd else 8)

    return guarded_shape("fd_mux_motorola", "100 % configured: CAN FD 64 B, mux, signed Motorola", msgs, guarded, frame)


def guarded_shape(name: str, what: str, msgs: list[Message], guarded: list[tuple[str, str]],
                  frame: Callable[[random.Random, float], Frame], bus_of: dict[str, str] | None = None,
                  channel_of: Callable[[int], str] | None = None) -> Shape:
    """A shape whose guarded signals are currents under one hysteresis guard each."""
    sources = {f"s{i}": current(m, s, (bus_of or {}).get(m, "main")) for i, (m, s) in enumerate(guarded)}
    return Shape(name, what, Database(messages=msgs), sources, [safe(f"s{i}") for i in range(len(guarded))], frame,
                 channel_of or (lambda _fid: "can0"), two_buses=bus_of is not None)


def many_ids() -> Shape:
    """500 standard ids, 10 % of the frames configured."""
    configured = list(range(0x100, 0x100 + 50))
    msgs = [Message(fid, f"M{fid:03X}", 8, [sig("Cur", 0, 16, signed=True)]) for fid in configured]
    noise = list(range(0x400, 0x400 + 450))

    def frame(rng: random.Random, t: float) -> Frame:
        fid = configured[rng.randrange(50)] if rng.random() < 0.10 else noise[rng.randrange(450)]
        data = bytearray(rng.randbytes(8))
        data[0:2] = (rng.randrange(-1500, 1500) & 0xFFFF).to_bytes(2, "little")
        return fid, False, False, bytes(data)

    return guarded_shape("many_ids", "500 ids, 10 % configured", msgs, [(f"M{fid:03X}", "Cur") for fid in
                                                                        configured[:20]], frame)


def ext_motorola() -> Shape:
    """Extended-id Motorola drives, a multiplexed BMS and noise ids: 30 % configured."""
    drives = [0x18FF0000 + a for a in range(6)]
    msgs = [Message(fid, f"Drive{i}", 8, [sig("Iq", 7, 16, signed=True, motorola=True),
                                          sig("Vel", 23, 16, signed=True, motorola=True)], is_extended_frame=True)
            for i, fid in enumerate(drives)]
    bms = [sig("Page", 0, 8, is_mux=True, scale=1)] + [sig(f"P{p}", 8, 16, signed=True, mux_ids=[p]) for p in range(3)]
    msgs.append(Message(0x18FF50E5, "BMS", 8, bms, is_extended_frame=True))
    noise = [0x18FE0000 + k for k in range(40)] + list(range(0x700, 0x720))

    def frame(rng: random.Random, t: float) -> Frame:
        r = rng.random()
        if r < 0.25:
            return drives[rng.randrange(6)], True, False, small(rng, 8)
        if r < 0.30:
            return 0x18FF50E5, True, False, bytes([rng.randrange(3)]) + small(rng, 7, "little")
        fid = noise[rng.randrange(len(noise))]
        return fid, fid > 0x7FF, False, rng.randbytes(8)

    return guarded_shape("ext_motorola", "extended-id Motorola drives + mux BMS + noise, 30 % configured", msgs,
                         [(f"Drive{i}", "Iq") for i in range(6)] + [("BMS", "P0")], frame)


def two_buses() -> Shape:
    """Two interfaces interleaved in one log: drives on can0, a multiplexed BMS and body messages on can1."""
    drives, body = list(range(0x140, 0x148)), list(range(0x300, 0x306))
    msgs = [Message(fid, f"Drv{fid:03X}", 8, [sig("Iq", 0, 16, signed=True), sig("Vel", 16, 16, signed=True)])
            for fid in drives]
    msgs += [Message(fid, f"Body{fid:03X}", 8, [sig("Cur", 0, 16, signed=True)]) for fid in body[1:]]
    bms = [sig("Page", 0, 8, is_mux=True, scale=1)] + [sig(f"P{p}", 8, 16, signed=True, mux_ids=[p]) for p in range(3)]
    msgs.append(Message(body[0], "BMS", 8, bms))
    noise0, noise1 = list(range(0x500, 0x520)), list(range(0x600, 0x620))
    on_can1 = set(body) | set(noise1)

    def frame(rng: random.Random, t: float) -> Frame:
        r = rng.random()
        if r < 0.35:
            return drives[rng.randrange(8)], False, False, small(rng, 8, "little")
        if r < 0.45:
            fid = body[rng.randrange(6)]
            head = bytes([rng.randrange(3)]) + small(rng, 7, "little") if fid == body[0] else small(rng, 8, "little")
            return fid, False, False, head
        return (noise0 if r < 0.75 else noise1)[rng.randrange(20)], False, False, rng.randbytes(8)

    guarded = [(f"Drv{fid:03X}", "Iq") for fid in drives[:4]] + [("BMS", "P0"), (f"Body{body[1]:03X}", "Cur")]
    return guarded_shape("two_buses", "two interfaces interleaved, 2 buses, 45 % configured", msgs, guarded, frame,
                         bus_of={m.name: ("aux" if m.frame_id in on_can1 else "main") for m in msgs},
                         channel_of=lambda fid: "can1" if fid in on_can1 else "can0")


SYNTHETIC = (stopped_guarded, foreign_ext, fd_mux_motorola, many_ids, ext_motorola, two_buses)


@dataclass
class Written:
    """A shape on disk."""

    name: str
    what: str
    dbc: Path
    config: Path
    log: Path
    frames: int


def write_shape(shape: Shape, out: Path, frames: int) -> Written:
    """DBC, tree, config and log of ``shape`` in ``out`` (the log reused when cached)."""
    out.mkdir(parents=True, exist_ok=True)
    dbc = out / f"{shape.name}.dbc"
    dbc.write_text(shape.db.as_dbc_string(), encoding="ascii")
    tree = out / f"{shape.name}.xml"
    guards = "\n".join(f"      {g}" for g in shape.guards)
    tree.write_text(f'<root BTCPP_format="4" main_tree_to_execute="Main">\n  <BehaviorTree ID="Main">\n'
                    f"    <ReactiveSequence>\n{guards}\n      <ExecuteTask/>\n    </ReactiveSequence>\n"
                    "  </BehaviorTree>\n</root>\n", encoding="ascii")
    buses = {"main": {"interface": "virtual", "channel": "can0"}}
    if shape.two_buses:
        buses["aux"] = {"interface": "virtual", "channel": "can1"}
    doc = {"dbc": [dbc.name], "buses": buses, "sources": shape.sources,
           "tree": {"file": tree.name, "main": "Main", "tick_hz": 100},
           "task": {"period": 0.02, "frames": []}, "stop": {"repeat": 0.05, "frames": []},
           "events": str(out / f"{shape.name}.events.jsonl"), "state": {"file": str(out / f"{shape.name}.i2t.json")}}
    cfg = out / f"{shape.name}.yaml"
    cfg.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="ascii")
    log = CACHE / f"{shape.name}-v{VERSION}-{frames}.log"
    if not log.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        tmp = log.with_suffix(f".{random.getrandbits(32):08x}.tmp")
        rng = random.Random(16)
        t = 1_700_000_000.0
        with open(tmp, "w", encoding="ascii") as f:
            for _ in range(frames):
                t += STEP_S
                fid, ext, fd, data = shape.frame(rng, t)
                f.write(f"({t:.6f}) {shape.channel_of(fid)} {fid:08X}" if ext else
                        f"({t:.6f}) {shape.channel_of(fid)} {fid:03X}")
                f.write(f"{'##0' if fd else '#'}{data.hex().upper()}\n")
        tmp.replace(log)
    return Written(shape.name, shape.what, dbc, cfg, log, frames)


def own_shape(frames: int) -> Written:
    """The simulator's log (scenarios normal + load) with the bundled config."""
    from canguard.config.loader import load_config
    from canguard.sim import write_log

    log = CACHE / f"own-v{VERSION}-{frames}.log"
    if not log.exists():
        CACHE.mkdir(parents=True, exist_ok=True)
        tmp = log.with_suffix(f".{random.getrandbits(32):08x}.tmp.log")
        write_log(tmp, frames / 8000.0, db=load_config(CONFIG).database, scenarios=("normal", "load"), seed=0)
        tmp.replace(log)
    with open(log, "rb") as f:
        n = sum(chunk.count(b"\n") for chunk in iter(lambda: f.read(1 << 20), b""))
    return Written("own", "the project's simulator log (4 axes + BMS + noise, bundled config)", DBC, CONFIG, log, n)


def all_shapes(out: Path, frames: int) -> list[Written]:
    """Every shape written for ``frames`` frames."""
    return [own_shape(frames)] + [write_shape(make(), out, frames) for make in SYNTHETIC]
