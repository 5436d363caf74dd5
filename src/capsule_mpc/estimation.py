"""Capsule state estimation from delayed, noisy camera positions.

A constant-velocity Kalman filter per axis (the camera measures position only;
velocity is what the controller needs) and a prediction over the known
latency, from the capture time of the last frame to the time the command is
applied. Written out here because the filter is a few lines of linear algebra
and none of the project's dependencies ships a Kalman filter.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["NOISE_FLOOR_M", "CapsuleEstimator"]

#: Smallest measurement noise the filter assumes, m (about a camera pixel's quantisation at
#: this field of view). With r -> 0 the constant-velocity filter's velocity gain tends to
#: 2/dt and the estimate rings from frame to frame.
NOISE_FLOOR_M = 2e-5


class CapsuleEstimator:
    """Constant-velocity Kalman filter on the plate (x and y independent, same model).

    Parameters
    ----------
    noise_std_m : float
        Camera noise per axis, m (>= 0; floored at :data:`NOISE_FLOOR_M`).
    accel_std_mps2 : float
        Process noise: std of the capsule's unmodelled acceleration, m/s^2 (> 0).
    """

    def __init__(self, noise_std_m: float, accel_std_mps2: float) -> None:
        if not accel_std_mps2 > 0:
            raise ValueError(f"accel_std_mps2: must be > 0, got {accel_std_mps2}")
        self.r = max(float(noise_std_m), NOISE_FLOOR_M) ** 2
        self.q = float(accel_std_mps2) ** 2
        self.reset()

    def reset(self) -> None:
        """Forget everything (the next measurement initialises the filter)."""
        self.x = np.zeros((2, 2))  # rows: position, velocity; columns: x, y
        self.p = np.eye(2)
        self.t_s = math.nan

    @property
    def initialised(self) -> bool:
        """Whether a measurement has been fused."""
        return math.isfinite(self.t_s)

    def _predict(self, dt: float) -> None:
        f = np.array([[1.0, dt], [0.0, 1.0]])
        # Discrete white-noise acceleration model.
        g = np.array([[0.5 * dt * dt], [dt]])
        self.x = f @ self.x
        self.p = f @ self.p @ f.T + self.q * (g @ g.T)

    def update(self, capture_t_s: float, position_m: np.ndarray) -> None:
        """Fuse a position measured at ``capture_t_s`` (s)."""
        z = np.asarray(position_m, dtype=float)
        if not self.initialised:
            self.x = np.vstack([z, np.zeros(2)])
            self.p = np.diag([self.r, 0.05**2])  # unknown initial speed: a few cm/s
            self.t_s = capture_t_s
            return
        dt = capture_t_s - self.t_s
        if dt < 0:
            raise ValueError(f"capture_t_s: must not go back in time ({capture_t_s} < {self.t_s})")
        self._predict(dt)
        s = self.p[0, 0] + self.r
        k = self.p[:, 0] / s
        self.x = self.x + np.outer(k, z - self.x[0])
        self.p = self.p - np.outer(k, self.p[0])
        self.t_s = capture_t_s

    def estimate(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and velocity (m/s) predicted to time ``t_s`` (latency compensation)."""
        if not self.initialised:
            raise RuntimeError("estimate before the first measurement")
        lag = max(t_s - self.t_s, 0.0)
        return self.x[0] + lag * self.x[1], self.x[1].copy()

    def position_std_m(self) -> float:
        """Current position standard deviation per axis, m."""
        return float(math.sqrt(self.p[0, 0]))
