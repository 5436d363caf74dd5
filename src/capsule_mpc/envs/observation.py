"""What the environment's agent sees each camera frame: what a real controller gets, nothing more.

The observation is one float64 vector (:data:`OBSERVATION_FIELDS`, m, s, m/s):

======  ===========================================================================================
index   entry
======  ===========================================================================================
0       ``t_s``: the frame's time, s (negative in the settle phase; 0 is the start of the path)
1, 2    ``meas_x_m``, ``meas_y_m``: the camera's capsule position delivered at this frame (taken
        ``camera.latency_frames`` frames earlier, with the camera's bias and noise), m; 0 when
        ``meas_valid`` is 0
3       ``meas_valid``: 1 if the frame carries a position, 0 if it was dropped or none has arrived
4       ``meas_capture_t_s``: when the delivered image was taken, s; 0 when ``meas_valid`` is 0
5-7     ``epm_x_m``, ``epm_y_m``, ``epm_height_m``: the EPM pose the arm reports, m
8-10    ``cmd_vx_mps``, ``cmd_vy_mps``, ``cmd_vz_mps``: the command in force (the previous action;
        0 in the settle phase, when the arm is held still), m/s
11-...  ``ref_x_m[i]``, ``ref_y_m[i]``: the reference at ``t + i * REFERENCE_STEP_S``,
        ``i = 0 .. REFERENCE_POINTS - 1``, m (interleaved x, y)
======  ===========================================================================================

None of it comes from the plant's truth: the capsule is seen only through the camera model
(:class:`capsule_mpc.sim.sensing.Camera`), the EPM as the arm reports it, the reference from the
nominal path.
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces

from ..budget import MAX_SIM_TIME_S
from ..config import Scenario
from ..interfaces import Measurement
from ..paths import ReferencePath

__all__ = [
    "OBSERVATION_FIELDS",
    "POSITION_BOUND_M",
    "REFERENCE_POINTS",
    "REFERENCE_STEP_S",
    "action_space",
    "measurement_from_observation",
    "observation",
    "observation_space",
]

#: Reference points ahead in the observation.
REFERENCE_POINTS = 8
#: Time between the reference points ahead, s (a 2 s preview, about the MPC's horizon).
REFERENCE_STEP_S = 0.25
#: Bound of every horizontal position in the observation, m: far beyond any plate (400 x 300 mm).
POSITION_BOUND_M = 1.0
#: Bound of the EPM height in the observation, m.
HEIGHT_BOUND_M = 1.0

#: Names of the observation's entries, in order.
OBSERVATION_FIELDS: tuple[str, ...] = (
    "t_s",
    "meas_x_m",
    "meas_y_m",
    "meas_valid",
    "meas_capture_t_s",
    "epm_x_m",
    "epm_y_m",
    "epm_height_m",
    "cmd_vx_mps",
    "cmd_vy_mps",
    "cmd_vz_mps",
    *(f"ref_{axis}_m[{i}]" for i in range(REFERENCE_POINTS) for axis in ("x", "y")),
)


def action_space(scenario: Scenario) -> spaces.Box:
    """The EPM's velocity command (vx, vy, vz), m/s, each within ``+-limits.speed_mps`` (vz moves
    the EPM's height; the arm holds it within the workspace)."""
    speed = float(scenario.limits.speed_mps)
    return spaces.Box(-speed, speed, shape=(3,), dtype=np.float64)


def observation_space(scenario: Scenario) -> spaces.Box:
    """The box of :data:`OBSERVATION_FIELDS`: times from the settle phase's start to
    :data:`~capsule_mpc.budget.MAX_SIM_TIME_S`, positions within :data:`POSITION_BOUND_M`, the
    command within the speed limit."""
    speed = float(scenario.limits.speed_mps)
    t_lo = -float(scenario.sim.settle_s) - 1.0 / float(scenario.camera.rate_hz)
    low = [t_lo, -POSITION_BOUND_M, -POSITION_BOUND_M, 0.0, t_lo]
    high = [MAX_SIM_TIME_S, POSITION_BOUND_M, POSITION_BOUND_M, 1.0, MAX_SIM_TIME_S]
    low += [-POSITION_BOUND_M, -POSITION_BOUND_M, 0.0, -speed, -speed, -speed]
    high += [POSITION_BOUND_M, POSITION_BOUND_M, HEIGHT_BOUND_M, speed, speed, speed]
    low += [-POSITION_BOUND_M] * (2 * REFERENCE_POINTS)
    high += [POSITION_BOUND_M] * (2 * REFERENCE_POINTS)
    return spaces.Box(np.array(low), np.array(high), dtype=np.float64)


def observation(
    t_s: float,
    measurement: Measurement,
    epm_position_m: np.ndarray,
    command_mps: np.ndarray,
    path: ReferencePath,
) -> np.ndarray:
    """The observation vector of one frame (module docstring).

    Parameters
    ----------
    t_s : float
        Frame time, s.
    measurement : Measurement
        What the camera delivered at the frame.
    epm_position_m : numpy.ndarray (3,)
        The EPM pose the arm reports, m.
    command_mps : numpy.ndarray (3,)
        The command in force, m/s.
    path : ReferencePath
        The nominal reference.
    """
    valid = measurement.position_m is not None
    pos = np.asarray(measurement.position_m, dtype=float)[:2] if valid else np.zeros(2)
    capture = float(measurement.capture_t_s) if valid else 0.0
    ahead = path.position(t_s + REFERENCE_STEP_S * np.arange(REFERENCE_POINTS))
    head = [t_s, pos[0], pos[1], float(valid), capture]
    return np.concatenate([head, np.asarray(epm_position_m, dtype=float)[:3], command_mps[:3], ahead.ravel()])


def measurement_from_observation(obs: np.ndarray) -> tuple[float, Measurement, np.ndarray]:
    """The frame time (s), the camera's :class:`Measurement` and the EPM pose (3,) (m) an
    observation carries, as a :class:`~capsule_mpc.interfaces.Controller` takes them."""
    o = np.asarray(obs, dtype=float)
    t = float(o[0])
    if o[3] > 0.5:
        meas = Measurement(t_s=t, capture_t_s=float(o[4]), position_m=o[1:3].copy())
    else:
        meas = Measurement(t_s=t, capture_t_s=math.nan, position_m=None)
    return t, meas, o[5:8].copy()
