"""Byte-aligned signals of numpy blocks (decoded a message's rows at a time), held to the per-frame engine.

A battery message whose presence flag is a whole byte, with a float32 voltage-like
current and integer raws under integer and float scales, replayed with numpy reading
every message's payloads: the events, stops, summary and engine state must be those of
the frame-by-frame replay that ticks every tick. The presence flag drops to 0 and comes
back, values go out of the DBC range and to NaN.
"""

from __future__ import annotations

import math
import random
import struct
from pathlib import Path

import yaml
from cantools.database.can import Database, Message, Signal
from cantools.database.conversion import BaseConversion

from canguard.config.loader import load_config
from test_replay_columns import compare


def _dbc() -> Database:
    def sig(name: str, start: int, length: int, *, signed: bool = False, is_float: bool = False,
            scale: float = 1, offset: float = 0, lo: float | None = None, hi: float | None = None,
            motorola: bool = False) -> Signal:
        return Signal(name, start, length, byte_order="big_endian" if motorola else "little_endian",
                      is_signed=signed, conversion=BaseConversion.factory(scale=scale, offset=offset,
                                                                          is_float=is_float),
                      minimum=lo, maximum=hi)

    batt = Message(0x300, "Batt", 8, [
        sig("Pack_Current", 0, 16, signed=True, scale=0.1, offset=-5.0, lo=-400.0, hi=400.0),
        sig("Present", 16, 8),
        sig("Volts", 32, 32, is_float=True),
    ])
    drive = Message(0x301, "Drive", 8, [
        sig("Iq", 7, 16, signed=True, scale=2, offset=-3, motorola=True),  # integer scale and offset
        sig("Torque", 23, 32, signed=True, scale=0.001, motorola=True),
    ])
    return Database([batt, drive])


def _case(out: Path, frames: int = 4000) -> tuple[Path, Path]:
    out.mkdir(parents=True, exist_ok=True)
    db = _dbc()
    (out / "n.dbc").write_text(db.as_dbc_string(), encoding="ascii")
    (out / "n.xml").write_text(
        '<root BTCPP_format="4" main_tree_to_execute="Main"><BehaviorTree ID="Main"><ReactiveSequence>'
        '<IsCurrentSafe name="Pack" topic_name="pack" overcurrent_threshold="60" recovery_threshold="40"/>'
        '<IsCurrentNormal name="Volts" topic_name="volts" max_current="50"/>'
        '<IsCurrentSafe name="Iq" topic_name="iq" overcurrent_threshold="500" recovery_threshold="300"/>'
        '<IsCurrentNormal name="Torque" topic_name="torque" max_current="20"/>'
        "<ExecuteTask/></ReactiveSequence></BehaviorTree></root>\n", encoding="utf-8")
    doc = {
        "dbc": [str(out / "n.dbc")],
        "buses": {"main": {"interface": "virtual", "channel": "can0"}},
        "sources": {
            "pack": {"kind": "battery", "message": "Batt", "current": "Pack_Current", "present": "Present",
                     "max_age": 0.2},
            "volts": {"kind": "current", "message": "Batt", "signal": "Volts", "max_age": 0.2},
            "iq": {"kind": "current", "message": "Drive", "signal": "Iq", "max_age": 0.2},
            "torque": {"kind": "current", "message": "Drive", "signal": "Torque", "max_age": 0.2},
        },
        "tree": {"file": str(out / "n.xml"), "main": "Main", "tick_hz": 100},
        "task": {"period": 0.02, "frames": [{"id": 0x7F0, "data": "01"}]},
        "stop": {"repeat": 0.05, "frames": [{"id": 0x7F1, "data": "00"}]},
    }
    cfg = out / "n.yaml"
    cfg.write_text(yaml.safe_dump(doc), encoding="utf-8")
    rng = random.Random(5)
    t = 2000.0
    lines = []
    for k in range(frames):
        t += rng.choice([0.0005, 0.001, 0.002])
        if k % 2:
            raw_i = rng.choice([rng.randrange(-200, 300), 700, 2000])  # amps ~ -25..25, then 65, 195
            present = 0 if 1500 <= k < 1560 else rng.choice([1, 1, 1, 2])
            volts = rng.choice([rng.uniform(0, 40), math.nan, 60.0]) if k % 7 == 0 else rng.uniform(0, 40)
            data = struct.pack("<hBxf", raw_i, present, volts).hex().upper()
            lines.append(f"({t:.6f}) can0 300#{data}")
        else:
            iq = rng.choice([rng.randrange(-100, 100), 400])  # 2 * raw - 3
            torque = rng.randrange(-15000, 15000) if k % 50 else rng.choice([25000, 2**30 + 3])  # float32 loses +3
            data = struct.pack(">hih", iq, torque, 0).hex()
            lines.append(f"({t:.6f}) can0 301#{data}")
    log = out / "n.log"
    log.write_text("\n".join(lines) + "\n", encoding="ascii")
    return cfg, log


def test_numpy_struct_reads_equal_the_per_frame_engine(tmp_path: Path) -> None:
    """Presence 0 and back, NaN, out of range, integer and float scales: the same replay as frame by frame."""
    cfg, log = _case(tmp_path)
    [col] = compare(load_config(cfg), log, tmp_path / "run", (4096,), min_handled=100)
    assert col.widest > 1
