"""A CANopen drive's log replays the same through the column path as frame by frame (the live daemon's way).

The drive's TPDO carrying the guarded current goes through the replay's column path; its
heartbeat, EMCY and statusword frames (the drive's health roles) are fed row by row. The
helper ``compare`` (tests/test_replay_columns.py) proves both paths journal the same events
and send the same frames at several block sizes.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

from canguard.config.loader import load_config
from test_canopen_config import config
from test_replay_columns import Row, compare, write_rows

NODE = 2


def drive_log(path: Path) -> Path:
    """12 s of a drive: a current trip at 2 s, heartbeat gap 4-5 s, EMCY 6-7 s, Fault bit 8-8.5 s."""
    rows: list[Row] = []
    seq = 0

    def add(t: float, cob: int, data: bytes) -> None:
        nonlocal seq
        seq += 1
        rows.append(Row(round(t, 6), seq, cid=f"{cob:03X}", data=data.hex().upper()))

    for k in range(1200):
        t = 1.0 + k * 0.01
        rel = t - 1.0
        current = 400 if 2.0 <= rel < 2.3 else 120  # 40 % of rated (> 35) for 0.3 s
        status = 0x27 | (0x08 if 8.0 <= rel < 8.5 else 0)
        add(t, 0x180 + NODE, struct.pack("<h", current))  # TPDO1 as overridden: the current actual value
        add(t + 0.001, 0x280 + NODE, struct.pack("<Hhh", status, 50, current))  # TPDO2: statusword first
        if k % 10 == 0 and not 4.0 <= rel < 5.0:
            add(t + 0.002, 0x700 + NODE, bytes([5]))
        if k == 600:
            add(t + 0.003, 0x080 + NODE, bytes.fromhex("1023 01 0102030405".replace(" ", "")))
        if k == 700:
            add(t + 0.003, 0x080 + NODE, bytes(8))
    return write_rows(path, rows)


def test_drive_log_replays_the_same_through_columns_and_frame_by_frame(tmp_path: Path) -> None:
    """Trip, no_heartbeat, emcy and drive_fault come out the same at every block size of the column path."""
    cfg = load_config(config(tmp_path, drive={"heartbeat": 0.1, "pdo": {"TPDO1": ["0x6078"]}},
                             source={"object": "Current actual value"}))
    log = drive_log(tmp_path / "drive.log")
    compare(cfg, log, tmp_path, (4096, 8192))
    events = [json.loads(x) for x in (tmp_path / "col-8192" / "events.jsonl").read_text().splitlines() if x]
    reasons = [e.get("reason") for e in events if e["event"] == "stale"]
    assert reasons == ["no_heartbeat", "emcy", "drive_fault"], reasons
    trips = [e["reason"] for e in events if e["event"] == "trip"]
    assert trips == ["overcurrent", "no_heartbeat", "emcy", "drive_fault"], trips
    assert [(e["code"], e["reset"]) for e in events if e["event"] == "emcy"] == [("0x2310", False), ("0x0000", True)]
