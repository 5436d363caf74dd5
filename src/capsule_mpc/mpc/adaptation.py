"""Online estimate of the friction the controller's model gets wrong (``mpc.adaptation``).

What is estimated: an offset ``dmu`` on the model's friction coefficient, so that the OCP's
friction force is ``(mu(v) + dmu) F_N + f_s`` against the motion (:mod:`capsule_mpc.mpc.problem`,
the last parameter). An offset and not a scale: the controller's law is the paper's c(v), whose
mu(v) is 0-0.008 at 3-30 mm/s (clipped at 0 below 20 mm/s) while the lab plant's steady friction is
0.09-0.16 (``friction.mu0`` and the rate-and-state constants of paper.yaml), so a scale on the
model's mu would have nothing to multiply; an offset times F_N is Coulomb friction that follows
the normal force, and a wet/dry change of the plate (a scale on the true mu) shows as a change
of the offset.

How: the velocity innovation along the motion, as the force-disturbance estimator uses it. The
last plan predicted the state ``x_pred`` for now with the offset ``dmu_prev``; the capsule's
estimated velocity ``v`` differs from the predicted one by ``dv = (v - v_pred) . u`` along the
motion ``u``, which over one frame is the friction force the plan got wrong, ``m dv / dt =
-(dmu - dmu_prev) phi`` with ``phi = F_N s`` at ``x_pred`` (``s = |v_pred| / sqrt(|v_pred|^2 +
eps^2)``, the OCP's smoothed friction direction). That gives one scalar regression per frame::

    y = dmu_prev phi - m dv / dt  =  dmu * phi

which :class:`FrictionOffsetRLS` fits by recursive least squares with exponential forgetting:
a scalar Kalman filter of a drifting ``dmu`` (the forgetting factor ``exp(-dt / tau)`` inflates
the covariance as a random walk would).

Why this one (measured, lab plant, plain rectangle, seeds 0-3, tracking RMS mean; the legacy
``off`` estimator 1.40 mm): a force-balance regression (``y`` from the model's force at the
measured lead and the measured acceleration, a moving-horizon fit in one step) gave 2.4-2.7 mm
for tau 0.3-3 s -- it explains the lead but not the velocity the plan misses, so it lost the
offset-free tracking; the innovation regression here gave 2.26 mm at tau 0.3 s (3.26 at 1 s,
2.04 with a 2 mm/s gate). An EKF on the augmented state would carry the same scalar through the
same innovation (with the step's Jacobian in place of ``phi``); RLS is its exact least-squares
form at a few flops per frame. Moving-horizon estimation would solve an NLP per frame for this
linear fit. Against the legacy estimate (``compare --runs 10 --controllers mpc``, lab plant,
seeds 0-9; tracking RMS mean +- sd, worst): plain rectangle off 1.44 +- 0.64 mm (2.72), rls
2.16 +- 0.69 (3.19); configs/friction_step.yaml off 2.13 +- 0.90 (3.52), rls 2.42 +- 0.70
(3.43); the final error at rest is smaller with rls (worst 1.01 / 1.08 mm against 1.29 / 1.28).
rls tracks worse on the plain rectangle (the legacy estimate learns from every frame faster than
2 mm/s, stuck ones included, which is also how it winds up), so ``mpc.adaptation.mode``
stays ``off`` by default.

No wind-up: a stuck capsule is held by static friction, which says nothing about the sliding
friction, so a frame updates the estimate only if the capsule slides by every sign the
controller has (:meth:`FrictionOffsetRLS.sliding`): the reference moves, the estimated speed is
at least ``mpc.adaptation.min_speed_mps`` on this frame and the one before, and so is
the speed of a straight line fitted to the estimated positions of the last
:data:`SPEED_WINDOW_S`. The Kalman filter's velocity alone is noise of a few mm/s on a capsule
at rest: on the lab rectangle a speed gate alone let ~10 frames of the stuck start and of the
stuck end update the estimate, which dragged it from 0.059 to 0.006 after the capsule stopped;
a displacement over 0.25 s still let 6 stuck frames of the start through. On any other frame
neither the estimate nor its covariance changes. The estimate is clipped to
``[mpc.adaptation.offset_min, mpc.adaptation.offset_max]`` and the covariance is capped at the
prior's, so forgetting without data cannot blow it up.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from ..config import AdaptationConfig
from ..dynamics import CapsuleModel
from ..estimation import fit_window

__all__ = ["FORCE_NOISE_STD_N", "SPEED_WINDOW_S", "FrictionOffsetRLS", "friction_regression"]

#: Window of the line fit of the speed gate, s. Over 0.5 s (15 frames at 30 Hz) the fitted speed
#: of a capsule at rest has a standard deviation of sigma / (dt sqrt(sum k^2)) = 0.45 mm / 0.55 s
#: = 0.8 mm/s per axis (camera noise 0.3-0.5 mm, k = -7..7), so the default 3 mm/s gate is ~4
#: standard deviations, and the fit of a capsule that slides at the pipe's 5 mm/s clears it.
SPEED_WINDOW_S = 0.5

#: Standard deviation of the regression's force residual y on one frame, N (the RLS's measurement
#: noise): the mass times the velocity innovation's noise over one frame. Measured on the lab
#: rectangle (seeds 0-2, adaptation on, frames that update): y / phi about its 1 s moving average
#: has an sd of 0.03-0.06 (phi ~1.25 N), i.e. y of 0.03-0.07 N.
FORCE_NOISE_STD_N = 0.05


def friction_regression(
    model: CapsuleModel,
    predicted_state: np.ndarray,
    velocity_mps: np.ndarray,
    offset: float,
    dt_s: float,
) -> tuple[float, float]:
    """One frame's regression ``y = dmu * phi`` of the friction-coefficient offset.

    The last plan predicted ``predicted_state`` for now with the offset ``offset``; the velocity
    it missed along the motion, ``dv = (v - v_pred) . u``, is the friction force it got wrong,
    ``m dv / dt = -(dmu - offset) phi``, so ``y = offset phi - m dv / dt``.

    Parameters
    ----------
    model : CapsuleModel
        The controller's model (the one the OCP is built from).
    predicted_state : numpy.ndarray (7,)
        The state the last plan predicted for now ``(p (2), v (2), e (2), h)``, m and m/s.
    velocity_mps : numpy.ndarray (2,)
        The estimated capsule velocity now, m/s.
    offset : float
        The offset the plan was computed with.
    dt_s : float
        The frame period, s.

    Returns
    -------
    y_n, phi_n : float
        The friction force along the motion that explains the velocity, N, and the regressor
        ``F_N s`` (N) at the predicted state.
    """
    x = np.asarray(predicted_state, dtype=float)
    vel = np.asarray(velocity_mps, dtype=float)
    speed = float(np.linalg.norm(vel))
    unit = vel / speed
    eps = model.scenario.friction.smoothing_eps_mps
    mass = model.scenario.capsule.mass_kg
    _lead, _force, f_n, _mu = model.outputs(x)
    pred_speed = float(np.linalg.norm(x[2:4]))
    phi = max(float(f_n), 0.0) * pred_speed / math.sqrt(pred_speed**2 + eps**2)
    missed = float((vel - x[2:4]) @ unit)
    return offset * phi - mass * missed / dt_s, phi


class FrictionOffsetRLS:
    """Recursive least squares with exponential forgetting of the friction-coefficient offset.

    Parameters
    ----------
    cfg : AdaptationConfig
        ``mpc.adaptation``: ``time_s`` (forgetting), ``offset_min`` / ``offset_max`` (bounds),
        ``offset_prior_std`` (initial and largest standard deviation) and ``min_speed_mps`` (the
        stuck gate).
    dt_s : float
        The controller's frame period, s (> 0).
    noise_std_n : float
        Standard deviation of one frame's force residual, N (> 0).

    Attributes
    ----------
    offset : float
        The estimate ``dmu`` (dimensionless), within the bounds; 0 before any data.
    variance : float
        Its variance, in ``(0, prior_std^2]``.
    updates : int
        Frames that updated the estimate.
    """

    def __init__(self, cfg: AdaptationConfig, dt_s: float, noise_std_n: float = FORCE_NOISE_STD_N) -> None:
        if not dt_s > 0:
            raise ValueError(f"dt_s: must be > 0, got {dt_s}")
        if not noise_std_n > 0:
            raise ValueError(f"noise_std_n: must be > 0, got {noise_std_n}")
        self.forgetting = math.exp(-dt_s / cfg.time_s)
        self.bounds = (float(cfg.offset_min), float(cfg.offset_max))
        self.prior_variance = float(cfg.offset_prior_std) ** 2
        self.min_speed_mps = float(cfg.min_speed_mps)
        self.noise_variance = float(noise_std_n) ** 2
        self.offset = 0.0
        self.variance = self.prior_variance
        self.updates = 0
        self._was_moving = False
        self._positions: deque[tuple[float, np.ndarray]] = deque()

    def sliding(
        self, t_s: float, position_m: np.ndarray, velocity_mps: np.ndarray, ref_speed_mps: float
    ) -> bool:
        """Whether the frame at ``t_s`` may update the estimate, and record it for the next calls.

        Parameters
        ----------
        t_s : float
            Time of the frame, s (increasing from call to call).
        position_m, velocity_mps : numpy.ndarray (2,)
            The estimated capsule position (m) and velocity (m/s).
        ref_speed_mps : float
            The reference's speed now, m/s.

        Returns
        -------
        bool
            True if the reference moves, the speed is at least the minimum on this frame and the
            one before, and so is the speed of the least-squares line through the positions of
            the frames since ``t_s - SPEED_WINDOW_S`` (which must span the window).
        """
        v_min = self.min_speed_mps
        moving = bool(np.linalg.norm(velocity_mps) >= v_min)
        speeds_ok = moving and self._was_moving
        self._was_moving = moving
        history = self._positions
        history.append((t_s, np.asarray(position_m, dtype=float).copy()))
        while len(history) > 1 and history[1][0] <= t_s - SPEED_WINDOW_S:
            history.popleft()
        if not (ref_speed_mps >= v_min and speeds_ok and t_s - history[0][0] >= SPEED_WINDOW_S):
            return False
        fit = fit_window(history, t_s, t_s - history[0][0])
        return fit is not None and bool(np.linalg.norm(fit.velocity_mps) >= v_min)

    def update(self, y_n: float, phi_n: float) -> None:
        """Fuse one frame's regression ``y = offset * phi`` (``y``, ``phi`` in N; finite).

        A non-finite or non-positive regressor (no normal force) leaves everything unchanged.
        """
        if not (math.isfinite(y_n) and math.isfinite(phi_n)) or phi_n <= 0:
            return
        p = min(self.variance / self.forgetting, self.prior_variance)
        gain = p * phi_n / (self.noise_variance + phi_n * phi_n * p)
        self.offset = float(np.clip(self.offset + gain * (y_n - phi_n * self.offset), *self.bounds))
        self.variance = (1.0 - gain * phi_n) * p
        self.updates += 1

    def as_stats(self) -> dict[str, float]:
        """The estimate for ``StepStats.extra``: offset, its standard deviation and update count."""
        return {
            "friction_offset": self.offset,
            "friction_offset_std": math.sqrt(self.variance),
            "friction_offset_updates": float(self.updates),
        }
