"""The simulated rig: plant, camera, actuator, closed-loop runner and run logs."""

from .actuation import Actuator, SimpleArm, make_actuator, register_actuator
from .log import LOG_COLUMNS, REQUIRED_COLUMNS, read_log, read_predictions, write_log, write_run
from .plant import CapsulePlant, ForceField, MapForces, UniformForce
from .runner import PathProgress, RealtimeStats, RunFlags, RunResult, realtime_scenario, simulate
from .sensing import Camera

__all__ = [
    "LOG_COLUMNS",
    "REQUIRED_COLUMNS",
    "Actuator",
    "Camera",
    "CapsulePlant",
    "ForceField",
    "MapForces",
    "PathProgress",
    "RealtimeStats",
    "RunFlags",
    "RunResult",
    "SimpleArm",
    "UniformForce",
    "make_actuator",
    "read_log",
    "read_predictions",
    "realtime_scenario",
    "register_actuator",
    "simulate",
    "write_log",
    "write_run",
]
