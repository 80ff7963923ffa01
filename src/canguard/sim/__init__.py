"""``canguard simulate``'s engine: a simulated robot on a CAN bus or into a candump log.

:class:`SimRobot` is N ODrive CANSimple axes and a BMS speaking ``dbc/robot.dbc`` in seeded simulated
time; :data:`SCENARIOS` lists what can go wrong and when; :func:`write_log` writes a deterministic
candump -L file; :func:`run_on_bus` plays the robot on a bus and answers canguard's stop and recovery frames.
"""

from canguard.sim.io import run_on_bus, write_log
from canguard.sim.robot import SimRobot
from canguard.sim.scenarios import SCENARIOS

__all__ = ["SCENARIOS", "SimRobot", "run_on_bus", "write_log"]
