"""The paper's baselines: the EPM runs the preset path and the capsule trails it.

* ``follow``: the EPM runs the path at the nominal speed v.
* ``paper_0.8v``: the same path at 0.8 v (the paper's heuristic, §IV-D).

The EPM's target is the reference point plus the *calibrated offset*, the lead
``EPM - capsule`` at which the capsule rests under the magnet (off-centre with
the Halbach array). A baseline does not read the plant: it calibrates the offset
from the camera measurements averaged over the settle phase (EPM at rest), and
falls back to the controller model's equilibrium (:func:`model_equilibrium_lead`) if no
valid frame arrived. The command is the
path's feed-forward velocity plus a proportional correction of the EPM's own
position error (the robot knows its pose), clipped to the speed limit.
"""

from __future__ import annotations

import math

import numpy as np

from .config import Scenario
from .interfaces import Command, Controller, Measurement, StepStats, register_controller
from .magnetics import model_equilibrium_lead
from .paths import ReferencePath

__all__ = [
    "DEFAULT_POSITION_GAIN_PER_S",
    "PAPER_SPEED_FACTOR",
    "FollowPath",
    "PaperSlowFollow",
]

#: Proportional gain on the EPM's own position error, 1/s (a few times slower than the 30 Hz
#: frame rate, so the correction never overshoots within a frame).
DEFAULT_POSITION_GAIN_PER_S = 3.0
#: The paper's speed reduction: the same preset path at 0.8 v (paper §IV-D).
PAPER_SPEED_FACTOR = 0.8


class FollowPath(Controller):
    """The EPM runs the reference path (at ``speed_factor`` times its speed) with a fixed offset.

    Parameters
    ----------
    speed_factor : float
        Multiplies the path's nominal speed, > 0 (1 for ``follow``, 0.8 for ``paper_0.8v``).
    position_gain_per_s : float
        Gain of the EPM position correction, 1/s, >= 0.
    """

    name = "follow"

    def __init__(
        self, speed_factor: float = 1.0, position_gain_per_s: float = DEFAULT_POSITION_GAIN_PER_S
    ) -> None:
        if not (math.isfinite(speed_factor) and speed_factor > 0):
            raise ValueError(f"speed_factor: must be > 0, got {speed_factor}")
        if not (math.isfinite(position_gain_per_s) and position_gain_per_s >= 0):
            raise ValueError(f"position_gain_per_s: must be >= 0, got {position_gain_per_s}")
        self.speed_factor = float(speed_factor)
        self.position_gain_per_s = float(position_gain_per_s)
        self.offset_m = np.zeros(2)
        self.offset_source = "none"

    def reset(self, scenario: Scenario, path: ReferencePath, epm_position_m: np.ndarray) -> None:
        """Prepare a run; the offset is calibrated during the settle phase (t < 0)."""
        self.scenario = scenario
        self.path = path.with_speed(path.speed_mps * self.speed_factor)
        self.height_m = float(epm_position_m[2])
        self.speed_limit_mps = scenario.limits.speed_mps
        self._settle_sum = np.zeros(2)
        self._settle_n = 0
        self._settle_epm = np.asarray(epm_position_m, dtype=float)[:2].copy()
        self._calibrated = False
        self.offset_m = np.zeros(2)
        self.offset_source = "none"

    def _model_offset(self) -> np.ndarray:
        return model_equilibrium_lead(self.scenario, self.height_m)

    def _calibrate(self) -> None:
        if self._settle_n > 0:
            self.offset_m = self._settle_epm - self._settle_sum / self._settle_n
            self.offset_source = f"camera ({self._settle_n} frames)"
        else:
            self.offset_m = self._model_offset()
            self.offset_source = f"model ({self.scenario.force_model})"
        self._calibrated = True

    def step(self, t_s: float, measurement: Measurement, epm_position_m: np.ndarray) -> Command:
        """EPM velocity: path feed-forward + gain * (path point + offset - EPM position)."""
        epm = np.asarray(epm_position_m, dtype=float)
        if t_s < 0 and not self._calibrated:
            if measurement.position_m is not None:
                self._settle_sum += measurement.position_m
                self._settle_n += 1
                self._settle_epm = epm[:2].copy()
            return Command(np.zeros(3), StepStats(status="calibrating", phase="settle"))
        if not self._calibrated:
            self._calibrate()
        target = self.path.position(t_s) + self.offset_m
        vel_xy = self.path.velocity(t_s) + self.position_gain_per_s * (target - epm[:2])
        vel_z = self.position_gain_per_s * (self.height_m - epm[2])
        vel = np.clip(np.array([vel_xy[0], vel_xy[1], vel_z]), -self.speed_limit_mps, self.speed_limit_mps)
        # No solver: solve_ms stays NaN. The phase as the MPC's are named: the path runs, then it holds.
        phase = "slide" if t_s < self.path.duration_s else "hold"
        return Command(vel, StepStats(status="ok", phase=phase))


@register_controller("follow")
def _follow() -> Controller:
    """``follow``: the EPM runs the path at the nominal speed."""
    return FollowPath(1.0)


class PaperSlowFollow(FollowPath):
    """``paper_0.8v``: :class:`FollowPath` at :data:`PAPER_SPEED_FACTOR` times the nominal speed."""

    name = "paper_0.8v"

    def __init__(self, position_gain_per_s: float = DEFAULT_POSITION_GAIN_PER_S) -> None:
        super().__init__(PAPER_SPEED_FACTOR, position_gain_per_s)


@register_controller("paper_0.8v")
def _paper_slow() -> Controller:
    """``paper_0.8v``: the path at 0.8 v."""
    return PaperSlowFollow()
