"""The controller's estimator: what it believes about the capsule each frame, from the camera alone.

Three parts, each a few lines of bookkeeping around :class:`capsule_mpc.estimation.CapsuleEstimator`:

* the Kalman filter: position and velocity from delayed, noisy camera positions (outliers gated),
  predicted over the latency to the frame's time;
* the force-disturbance observer (offset-free MPC): the velocity the last plan predicted for now
  against the estimate, turned into the force that explains the difference over one frame, split
  into a constant force across the motion (gain ``estimator.disturbance_gain``, bounded by
  ``estimator.disturbance_max_n``) and an extra friction along it (``estimator.friction_gain``,
  bounded by ``estimator.friction_max_n``); a capsule at rest teaches nothing (static friction
  holds it), and nor does the settle phase (the sliding producer folds innovations in from t = 0);
* the rest calibration: while the rig holds the EPM before t = 0, where the capsule rests under it
  tells the model's force bias; at t = 0 the constant disturbance is set to cancel the model's
  lateral force at the mean rest lead;
* the rest detector (:class:`~capsule_mpc.mpc.contact.RestDetector`): whether the capsule rests
  and since when.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..config import Scenario
from ..estimation import CapsuleEstimator
from ..interfaces import Measurement
from .contact import RestDetector
from .problem import N_DIST

__all__ = ["MOVING_MPS", "Estimate", "StateEstimator"]

#: Speed above which the velocity innovation is attributed to friction along the motion, and above
#: which a line through the recent positions says the capsule has not come to rest, m/s.
MOVING_MPS = 2e-3


@dataclass(frozen=True)
class Estimate:
    """The estimator's belief at one frame.

    Attributes
    ----------
    position_m, velocity_mps : numpy.ndarray (2,)
        The capsule's estimated position (m) and velocity (m/s) at the frame's time.
    measured : bool
        Whether this frame brought a camera position the filter fused (dropped and gated frames
        teach nothing).
    resting : bool
        Whether the capsule rests (:class:`~capsule_mpc.mpc.contact.RestDetector`).
    rest_s : float
        How long it has rested, s (0 while it moves).
    """

    position_m: np.ndarray
    velocity_mps: np.ndarray
    measured: bool
    resting: bool
    rest_s: float


class StateEstimator:
    """The Kalman filter, the disturbance observer, the rest calibration and the rest detector of
    one run (see the module docstring).

    Parameters
    ----------
    scenario : Scenario
        The controller's scenario: the camera's noise, the capsule's nominal mass and the
        ``estimator`` section.
    force : casadi.Function
        The controller's force model ``(lead (2), height) -> (F_x, F_y, F_att)``, N.
    dt_s : float
        The frame period, s.
    """

    def __init__(self, scenario: Scenario, force: ca.Function, dt_s: float) -> None:
        cfg = scenario.estimator
        self.cfg = cfg
        self.mass_kg = scenario.capsule.mass_kg
        self.force = force
        self.dt_s = dt_s
        self.kalman = CapsuleEstimator(scenario.camera.noise_std_m, cfg.accel_std_mps2)
        #: The estimated disturbance: constant force (x, y) and extra friction along the motion, N.
        self.disturbance_n = np.zeros(N_DIST)
        self.rest = RestDetector(scenario.camera.noise_std_m, MOVING_MPS)
        self._rest_leads: list[np.ndarray] = []
        self._calibrated = False

    @property
    def initialised(self) -> bool:
        """Whether a camera frame has been fused."""
        return self.kalman.initialised

    @property
    def rejected(self) -> int:
        """Camera frames the filter's gate rejected so far."""
        return self.kalman.rejected

    def fuse(self, measurement: Measurement) -> bool:
        """Fuse the frame's camera position, if any; False when the filter's gate rejected it."""
        if measurement.position_m is None:
            return True
        return self.kalman.update(measurement.capture_t_s, measurement.position_m)

    def estimate(self, t_s: float, measured_m: np.ndarray | None, epm_m: np.ndarray) -> Estimate:
        """The belief at ``t_s`` (after :meth:`fuse`); ``measured_m``: the camera position fused
        this frame (None: dropped or rejected), m; ``epm_m`` the EPM's position (3,), m. Collects
        the rest leads before t = 0 and calibrates at t = 0."""
        pos, vel = self.kalman.estimate(t_s)
        self._calibrate(t_s, epm_m, measured_m)
        resting = self.rest.update(t_s, pos)
        return Estimate(pos, vel, measured_m is not None, resting, self.rest.rest_s(t_s))

    def _calibrate(self, t_s: float, epm_m: np.ndarray, measured_m: np.ndarray | None) -> None:
        """Before t = 0 collect the measured rest leads; at t = 0 set the constant disturbance to
        cancel the model's lateral force at their mean (runs without a settle phase skip this)."""
        if t_s < 0:
            if measured_m is not None:
                self._rest_leads.append(epm_m[:2] - measured_m)
            return
        if self._calibrated or not self._rest_leads:
            return
        self._calibrated = True
        lead = np.mean(self._rest_leads, axis=0)
        force = np.asarray(self.force(lead, epm_m[2])).ravel()
        limit = self.cfg.disturbance_max_n
        self.disturbance_n[0:2] = np.clip(-force[0:2], -limit, limit)

    def update_disturbance(self, v_est: np.ndarray, v_pred: np.ndarray) -> None:
        """Fold the frame's velocity innovation (the estimate ``v_est`` against the plan's
        prediction ``v_pred``, m/s) into the disturbance: along the predicted motion as extra
        friction, across it (or all of it, for a capsule the plan holds still) as a constant force.
        Nothing while the capsule is (nearly) at rest: static friction holds it."""
        across_gain, along_gain = self.cfg.disturbance_gain, self.cfg.friction_gain
        if float(np.linalg.norm(v_est)) < MOVING_MPS:
            return
        innov = self.mass_kg * (v_est - v_pred) / self.dt_s
        speed = float(np.linalg.norm(v_pred))
        d = self.disturbance_n.copy()
        if speed > MOVING_MPS:
            v_hat = v_pred / speed
            along = float(innov @ v_hat)
            d[2] -= along_gain * along
            d[0:2] += across_gain * (innov - along * v_hat)
        else:
            d[0:2] += across_gain * innov
        limit = np.array([self.cfg.disturbance_max_n] * 2 + [self.cfg.friction_max_n])
        self.disturbance_n = np.clip(d, -limit, limit)
