"""The simulated rig: plant, camera, actuator, the closed loop and run logs."""

from .actuation import SimpleArm
from .friction_field import FrictionField, FrictionPatch
from .log import LOG_COLUMNS, REQUIRED_COLUMNS, read_log, read_predictions, write_log, write_run
from .loop import ClosedLoop, FaultInjection, Frame, Observer, Pacer, ProgressBar, simulate
from .plant import CapsulePlant, ForceField, MapForces, TrueForces, UniformForce
from .runner import (
    PathProgress,
    RealtimeStats,
    RunFlags,
    RunOutcome,
    RunResult,
    realtime_scenario,
    start_pose,
)
from .sensing import Camera
from .truth import PlantTruth, draw_plant_truth, nominal_plant_truth

__all__ = [
    "LOG_COLUMNS",
    "REQUIRED_COLUMNS",
    "Camera",
    "CapsulePlant",
    "ClosedLoop",
    "FaultInjection",
    "ForceField",
    "Frame",
    "FrictionField",
    "FrictionPatch",
    "MapForces",
    "Observer",
    "Pacer",
    "PathProgress",
    "PlantTruth",
    "ProgressBar",
    "RealtimeStats",
    "RunFlags",
    "RunOutcome",
    "RunResult",
    "SimpleArm",
    "TrueForces",
    "UniformForce",
    "draw_plant_truth",
    "nominal_plant_truth",
    "read_log",
    "read_predictions",
    "realtime_scenario",
    "simulate",
    "start_pose",
    "write_log",
    "write_run",
]
