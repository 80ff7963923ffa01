"""Safety table row F5: a source's alive counter that stops changing makes the source unusable.

``counter: SIGNAL`` on a battery or current source (e.g. ``BMS_Status.Alive_Counter``): when the
counter has not changed for longer than the source's ``max_age`` although frames keep coming, the
sender is stuck (a frozen ECU, a gateway replaying a cached frame): the source's reason is
``frozen_counter``, its guards fail and the task stops; a moving counter clears it.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from canguard.engine.gate import TaskGate
from canguard.errors import ConfigError
from canguard.io.frame import Frame
from test_engine import BUNDLED, T0, Rig, _db


def bms(t: float, counter: int, current_a: float = 10.0) -> Frame:
    msg = _db().get_message_by_name("BMS_Status")
    data = msg.encode({"Pack_Current": current_a, "Pack_Voltage": 48.0, "State_Of_Charge": 80.0,
                       "Present": 1, "Fault": 0, "Alive_Counter": counter % 256})
    return Frame(t, "can0", msg.frame_id, bytes(data), True)


def counter_rig(tmp_path: Path) -> Rig:
    doc = yaml.safe_load(BUNDLED.read_text(encoding="utf-8"))
    sources = doc["sources"]
    sources["/battery_state"]["counter"] = "Alive_Counter"
    return Rig(tmp_path, sources=sources)


def test_a_frozen_counter_makes_the_source_unusable_and_a_moving_one_clears_it(tmp_path: Path) -> None:
    rig = counter_rig(tmp_path)
    health = rig.engine.ctx.health["/battery_state"]
    t = T0
    for k in range(30):  # a moving counter: normal operation
        t += 0.01
        rig.feed(bms(t, k))
    assert health.reason(t) == ""
    for _ in range(80):  # frozen at 29 while frames keep coming: frozen after max_age (0.5 s)
        t += 0.01
        rig.feed(bms(t, 29))
    assert health.reason(t) == "frozen_counter"
    frozen = [e for e in rig.events.named("stale") if e.get("reason") == "frozen_counter"]
    assert frozen and frozen[0]["source"] == "/battery_state"
    assert T0 + 0.29 + 0.5 < frozen[0]["t"] <= T0 + 0.29 + 0.52
    t += 0.01
    rig.feed(bms(t, 30))  # moving again
    assert health.reason(t) == ""


def test_a_frozen_counter_stops_a_running_task(tmp_path: Path) -> None:
    """The engine rig's BMS frames carry Alive_Counter 0 every time: fine for max_age, then a stop."""
    rig = counter_rig(tmp_path)
    rig.running()  # up within 0.1 s: the counter has not been still for max_age yet
    rig.run(T0 + 0.8)
    assert rig.engine.gate.state == TaskGate.STOPPED
    [stop] = rig.events.named("stop")
    assert "frozen_counter" in stop["reason"], stop


def test_counter_must_name_a_signal_of_the_message(tmp_path: Path) -> None:
    import pytest

    from test_engine import write_config

    path = write_config(tmp_path)
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    doc["sources"]["/battery_state"]["counter"] = "Alive_Countr"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    from canguard.config.loader import load_config

    with pytest.raises(ConfigError, match=r"sources\./battery_state\.counter.*Alive_Countr"):
        load_config(path)
