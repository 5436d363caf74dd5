"""Capsule state estimation from delayed, noisy camera positions.

A constant-velocity Kalman filter per axis (the camera measures position only;
velocity is what the controller needs) and a prediction over the known
latency, from the capture time of the last frame to the time the command is
applied. Written out here because the filter is a few lines of linear algebra
and none of the project's dependencies ships a Kalman filter.

Outliers are rejected by an innovation gate: a measurement whose normalised
innovation squared ``|z - x_pred|^2 / S`` (chi-square with 2 degrees of freedom
for a valid frame; ``S`` the predicted position variance plus the camera's) is
above :data:`GATE_CHI2` is not fused -- the filter keeps its prediction, whose
variance grows, so after a long drop the gate is wide again. A capsule that
really jumped (a slip faster than the filter's acceleration model) gives
consistent rejections: after :data:`REACQUIRE_AFTER` in a row the filter
re-acquires, its position reset to the measurement.

:func:`fit_window` fits a line (or a constant) to the positions of a window of recent frames: the
speed and rest position the MPC's final approach and its friction adaptation judge by.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = [
    "GATE_CHI2",
    "MIN_FIT_FRAMES",
    "NOISE_FLOOR_M",
    "REACQUIRE_AFTER",
    "CapsuleEstimator",
    "RestFit",
    "fit_window",
]

#: Smallest measurement noise the filter assumes, m (about a camera pixel's quantisation at
#: this field of view). With r -> 0 the constant-velocity filter's velocity gain tends to
#: 2/dt and the estimate rings from frame to frame.
NOISE_FLOOR_M = 2e-5
#: Innovation gate: the chi-square (2 dof) quantile a valid frame exceeds with probability 1e-6
#: (27.6). The true camera noise of the lab rig reaches 0.5 mm against the filter's 0.3 mm, which
#: scales the statistic by up to ~2.8, so a valid frame is still rejected with probability
#: below 1e-4 there; a 10 mm outlier scores ~1e3. With 2 dof the chi-square survival function is
#: exp(-x/2), so the quantile is -2 ln(1e-6) in closed form (scipy.stats would add ~0.3 s to the
#: import of every controller; the test checks it against scipy's chi2.ppf).
GATE_CHI2 = -2.0 * math.log(1e-6)
#: Consecutive rejected frames after which the filter re-acquires at the latest measurement
#: (3 frames = 0.1 s at 30 Hz: a 10 mm jump of a real capsule is tracked again within it, and
#: three outliers in a row at a per-frame rate p happen with probability p^3).
REACQUIRE_AFTER = 3


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
        self.rejected = 0  # measurements rejected by the gate since the reset
        self.reacquisitions = 0
        self._rejected_in_row = 0

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

    def update(self, capture_t_s: float, position_m: np.ndarray) -> bool:
        """Fuse a position measured at ``capture_t_s`` (s); returns False if the gate rejected it.

        A rejected measurement is not fused (the filter is predicted to ``capture_t_s``); the
        :data:`REACQUIRE_AFTER`-th rejection in a row re-acquires instead: the position is set to
        the measurement, the velocity prediction is kept, and the covariance is that of a fresh
        start (counted in :attr:`reacquisitions`; the measurement counts as accepted).
        """
        z = np.asarray(position_m, dtype=float)
        if not self.initialised:
            self._acquire(capture_t_s, z, np.zeros(2))
            return True
        dt = capture_t_s - self.t_s
        if dt < 0:
            raise ValueError(f"capture_t_s: must not go back in time ({capture_t_s} < {self.t_s})")
        self._predict(dt)
        self.t_s = capture_t_s
        s = self.p[0, 0] + self.r
        innovation = z - self.x[0]
        if float(innovation @ innovation) / s > GATE_CHI2:
            self._rejected_in_row += 1
            if self._rejected_in_row < REACQUIRE_AFTER:
                self.rejected += 1
                return False
            self.reacquisitions += 1
            self._acquire(capture_t_s, z, self.x[1].copy())
            return True
        self._rejected_in_row = 0
        k = self.p[:, 0] / s
        self.x = self.x + np.outer(k, innovation)
        self.p = self.p - np.outer(k, self.p[0])
        return True

    def _acquire(self, capture_t_s: float, z: np.ndarray, velocity_mps: np.ndarray) -> None:
        """Start (or restart) the filter at the position ``z`` (m) with the velocity given (m/s)."""
        self.x = np.vstack([z, velocity_mps])
        self.p = np.diag([self.r, 0.05**2])  # unknown speed: a few cm/s
        self.t_s = capture_t_s
        self._rejected_in_row = 0

    def estimate(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Position (m) and velocity (m/s) predicted to time ``t_s`` (latency compensation)."""
        if not self.initialised:
            raise RuntimeError("estimate before the first measurement")
        lag = max(t_s - self.t_s, 0.0)
        return self.x[0] + lag * self.x[1], self.x[1].copy()

    def position_std_m(self) -> float:
        """Current position standard deviation per axis, m."""
        return float(math.sqrt(self.p[0, 0]))


#: Fewest frames a line fit (:func:`fit_window`) uses.
MIN_FIT_FRAMES = 4


@dataclass(frozen=True)
class RestFit:
    """A line fitted to recent camera frames: the position now (2,), m, and the velocity (2,), m/s."""

    position_m: np.ndarray
    velocity_mps: np.ndarray
    frames: int


def fit_window(
    frames: deque[tuple[float, np.ndarray]], t_s: float, window_s: float, static: bool = False
) -> RestFit | None:
    """Least-squares line through the frames captured in ``[t_s - window_s, t_s]``, evaluated at ``t_s``.

    Parameters
    ----------
    frames : deque of (capture time s, position (2,) m)
        Recent camera frames, oldest first.
    t_s : float
        Time the fit is evaluated at, s.
    window_s : float
        Length of the window, s.
    static : bool
        Fit a constant (the mean; velocity 0) instead of a line: a capsule known to be at rest.

    Returns
    -------
    RestFit or None
        None with fewer than :data:`MIN_FIT_FRAMES` frames in the window.
    """
    sel = [(tc, p) for tc, p in frames if t_s - window_s <= tc <= t_s]
    if len(sel) < MIN_FIT_FRAMES:
        return None
    times = np.array([tc for tc, _ in sel]) - t_s
    pos = np.array([p for _, p in sel])
    if static:
        return RestFit(pos.mean(axis=0), np.zeros(2), len(sel))
    design = np.column_stack([np.ones_like(times), times])
    coef, *_ = np.linalg.lstsq(design, pos, rcond=None)
    return RestFit(coef[0], coef[1], len(sel))
