"""``canguard simulate``'s engine: a simulated robot on a CAN bus or into a candump log."""

from canguard.sim.io import run_on_bus, write_log
from canguard.sim.robot import SimRobot
from canguard.sim.scenarios import SCENARIOS

__all__ = ["SCENARIOS", "SimRobot", "run_on_bus", "write_log"]
