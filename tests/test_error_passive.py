"""Safety table row B2: a controller that reports error-passive holds the task stopped until it is error-active.

SocketCAN reports controller state in error frames of class ``CAN_ERR_CRTL`` (0x004), the state in
data[1]: RX/TX passive (0x10 / 0x20), back to active (0x40). In error-passive our own stop frames may
no longer get through, so canguard stops the task and says why, live and in replay alike.
"""

from __future__ import annotations

from pathlib import Path

from canguard.engine.gate import TaskGate
from canguard.io.frame import Frame
from checkout import REPO
from test_engine import Rig


def crtl(t: float, state: int) -> Frame:
    return Frame(t, "can0", 0x004, bytes([0, state, 0, 0, 0, 0, 0, 0]), True, False, True)


def test_error_passive_stops_and_error_active_releases(tmp_path: Path) -> None:
    rig = Rig(tmp_path)
    rig.running()
    rig.feed(crtl(rig.t + 0.001, 0x20))  # TX passive
    assert rig.engine.gate.state == TaskGate.STOPPED
    [err] = [e for e in rig.events.named("bus_error") if "passive" in e["reason"]]
    assert err["reason"] == "bus main: controller error-passive (tx): frames may not get through"
    [stop] = rig.events.named("stop")
    assert stop["reason"] == err["reason"]
    rig.run(rig.t + 0.2)
    assert rig.engine.gate.state == TaskGate.STOPPED  # still passive: held
    rig.feed(crtl(rig.t + 0.001, 0x40))  # error-active again
    rig.run(rig.t + 0.1)
    assert rig.engine.gate.state == TaskGate.RUNNING
    assert rig.events.named("resume")
    assert rig.events.named("bus_error")[-1]["reason"] == "bus main: controller error-active again"


def test_other_error_frames_do_not_stop(tmp_path: Path) -> None:
    """Bus errors (protocol class, the errorburst scenario) and warnings are counted, nothing more."""
    rig = Rig(tmp_path)
    rig.running()
    rig.feed(Frame(rig.t + 0.001, "can0", 0x088, bytes(8), True, False, True))
    rig.feed(crtl(rig.t + 0.002, 0x08))  # TX warning: not passive
    rig.run(rig.t + 0.1)
    assert rig.engine.gate.state == TaskGate.RUNNING
    assert not rig.events.named("bus_error")


def test_replay_of_a_log_with_an_error_passive_report(tmp_path: Path, capsys: object) -> None:
    """The same in replay: the candump log's error frame (id 20000004) stops the task in the summary."""
    import json

    from canguard.cli.main import main
    from test_engine import write_config

    cfg = write_config(tmp_path)
    src = REPO / "examples" / "load.log.gz"
    import gzip

    with gzip.open(src, "rt", encoding="ascii") as f:
        lines = f.read().splitlines()
    t_mid = float(lines[len(lines) // 2][1:].split(")")[0])
    lines.insert(len(lines) // 2, f"({t_mid:.6f}) can0 20000004#0020000000000000")
    log = tmp_path / "passive.log"
    log.write_text("\n".join(lines) + "\n", encoding="ascii")
    assert main(["replay", str(log), "-c", str(cfg), "--json"]) in (0, 1)
    summary = json.loads(capsys.readouterr().out)  # type: ignore[attr-defined]
    assert summary["stops"] >= 1
