"""``canguard simulate``'s engine: a simulated robot on a CAN bus or into a candump log.

:class:`SimRobot` is N ODrive CANSimple axes and a BMS speaking ``dbc/robot.dbc``
in simulated time (seeded, no wall clock); :data:`SCENARIOS` lists what can go
wrong and when; :func:`write_log` writes a deterministic candump -L file;
:func:`run_on_bus` plays the robot on a python-can bus and answers canguard's
stop and recovery frames, so the loop closes.

::

    import cantools
    from canguard.sim import SimRobot, write_log

    db = cantools.database.load_file("dbc/robot.dbc")
    write_log("spike.log", 3.0, db=db, scenarios=["spike"], seed=1)
    for frame in SimRobot(db, scenarios=["overload", "spike@6"]).frames(10.0):
        ...
"""

from canguard.sim.encode import MessageEncoder
from canguard.sim.io import MAX_FRAMES_PER_S_1MBIT, run_on_bus, write_log
from canguard.sim.robot import (
    AXIS_STATE_CLOSED_LOOP,
    AXIS_STATE_IDLE,
    DEFAULT_RATES_HZ,
    ERROR_ESTOP_REQUESTED,
    KT_NM_PER_A,
    SimRobot,
)
from canguard.sim.scenarios import SCENARIO_CLASSES, SCENARIOS, Scenario, parse_scenario

__all__ = [
    "AXIS_STATE_CLOSED_LOOP",
    "AXIS_STATE_IDLE",
    "DEFAULT_RATES_HZ",
    "ERROR_ESTOP_REQUESTED",
    "KT_NM_PER_A",
    "MAX_FRAMES_PER_S_1MBIT",
    "SCENARIOS",
    "SCENARIO_CLASSES",
    "MessageEncoder",
    "Scenario",
    "SimRobot",
    "parse_scenario",
    "run_on_bus",
    "write_log",
]
