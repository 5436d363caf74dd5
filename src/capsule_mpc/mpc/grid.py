"""The MPC's stage grid: how long each prediction stage lasts and when it ends.

The first stage is one camera frame (the command is sent for a frame); stages 2..N last
``mpc.dt_s`` (one frame when None), so a longer step stretches the horizon at the same N.
"""

from __future__ import annotations

import numpy as np

from ..config import Scenario

__all__ = ["prediction_steps_s", "prediction_times_s", "stage_end_times_s"]


def prediction_steps_s(scenario: Scenario) -> np.ndarray:
    """Durations of the MPC's N prediction stages, s: one camera frame, then ``mpc.dt_s``
    (one frame when None)."""
    frame = 1.0 / scenario.camera.rate_hz
    step = frame if scenario.mpc.dt_s is None else float(scenario.mpc.dt_s)
    return np.concatenate([[frame], np.full(scenario.mpc.horizon - 1, step)])


def prediction_times_s(scenario: Scenario) -> np.ndarray:
    """Look-ahead times of the MPC's stages 1..N from the frame it plans at, s."""
    return stage_end_times_s(prediction_steps_s(scenario))


def stage_end_times_s(steps_s: np.ndarray) -> np.ndarray:
    """End times of consecutive stages, s: ``steps_s`` is a first step, then equal ones (the MPC's
    grid, :func:`prediction_steps_s`). A uniform grid's are products ``k dt``, the times it always
    had (a cumulative sum rounds differently and shifts knot look-ups)."""
    steps = np.asarray(steps_s, dtype=float)
    if np.all(steps == steps[0]):
        return steps[0] * np.arange(1, len(steps) + 1)
    return steps[0] + steps[-1] * np.arange(len(steps))
