"""Runs of the stop confirmation's source and of a presence flag, in blocks and frame by frame.

The bundled config confirms a stop on ``axis0``'s current (``stop.confirm``), which the
gate reads between ticks while a stop waits for it, and its battery carries a presence
flag. Each test replays a log in column blocks (the sources' health and models advance
over runs up to the next due time or edge) and frame by frame
(``tests/test_replay_columns.compare``) and requires the same bytes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from canguard.config.loader import load_config
from test_replay_columns import BUNDLED, Row, bms_data, compare, iq_data, msg_id, torques_data, write_rows


def _drives(t: float, k: int, axis0_amps: float) -> list[Row]:
    """One 20 ms step of the four drives: currents (axis0 at ``axis0_amps``, the others at 2 A) and efforts."""
    rows = [Row(t + 0.001, 10 * k, cid=msg_id("Axis0_Get_Iq"), data=iq_data(axis0_amps))]
    for j in (1, 2, 3):
        rows.append(Row(t + 0.001 + 0.002 * j, 10 * k + j, cid=msg_id(f"Axis{j}_Get_Iq"), data=iq_data(2.0)))
    for j in range(4):
        rows.append(Row(t + 0.009 + 0.001 * j, 10 * k + 4 + j, cid=msg_id(f"Axis{j}_Get_Torques"),
                        data=torques_data(1.0)))
    return rows


def _events(log_dir: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (log_dir / "events.jsonl").read_text().splitlines()]


def test_a_stop_held_back_by_the_start_window_reads_the_confirmation_at_its_time(
    tmp_path: Path
) -> None:
    """No battery at all: the start window holds the stop back to 0.5 s; axis0 carries 3 A until 0.52 s,
    then 0.2 A, and the stop is confirmed when it drops (within the confirmation's 0.2 s), not at the stop.

    A block from the start to past the drop would settle were the start window left out of its
    horizon: the confirmation would then read axis0's last value (0.2 A) at the stop.
    """
    rows = []
    for k in range(150):
        t = k * 0.02
        rows += _drives(t, k, 3.0 if t < 0.52 else 0.2)
    log = write_rows(tmp_path / "no_battery.log", rows)
    outcomes = compare(load_config(BUNDLED), log, tmp_path, (1009, 2048, 4096, 8192), min_handled=0)
    confirmed = [e for e in _events(tmp_path / "col-8192") if e.get("event") == "confirmed"]
    assert len(confirmed) == 1 and confirmed[0]["t"] >= 0.52 - 1e-9, confirmed
    assert all(o.column_blocks > 0 for o in outcomes)


def test_a_battery_going_silent_mid_block_stops_at_its_staleness(tmp_path: Path) -> None:
    """The battery (present, 5 A) goes silent at 1.5 s and is stale 0.5 s later; axis0 drops below the
    confirmation's 1 A at 2.1 s. The blocks of healthy battery and drives before settle; the block
    holding the silence does not, and the stop is confirmed at the drop."""
    bms = msg_id("BMS_Status")
    rows = []
    for k in range(200):
        t = k * 0.02
        rows += _drives(t, k, 3.0 if t < 2.1 else 0.2)
        if t < 1.5:
            rows.append(Row(t + 0.015, 10 * k + 9, cid=bms, data=bms_data(5.0)))
    log = write_rows(tmp_path / "battery_silent.log", rows)
    compare(load_config(BUNDLED), log, tmp_path, (1009, 4096, 8192, 16384), min_handled=0)
    events = _events(tmp_path / "col-16384")
    confirmed = [e for e in events if e.get("event") == "confirmed"]
    assert len(confirmed) == 1 and confirmed[0]["t"] >= 2.1 - 1e-9, events


def test_presence_dropping_to_zero_and_back(tmp_path: Path) -> None:
    """The battery's presence flag reads 0 for 0.3 s in the middle of a healthy run: its rows go frame by
    frame (a trip of the battery guard and its recovery), the blocks of present rows around settle."""
    bms = msg_id("BMS_Status")
    rows = []
    for k in range(250):
        t = k * 0.02
        rows += _drives(t, k, 0.5)
        rows.append(Row(t + 0.015, 10 * k + 9, cid=bms, data=bms_data(5.0, present=0 if 2.0 <= t < 2.3 else 1)))
    log = write_rows(tmp_path / "presence.log", rows)
    compare(load_config(BUNDLED), log, tmp_path, (4096, 8192), min_handled=0)
    reasons = {e.get("reason") for e in _events(tmp_path / "col-8192")}
    assert any("not_present" in str(r) for r in reasons), reasons
