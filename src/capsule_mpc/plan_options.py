"""The offline planner's settings, apart from the planner so that costing a plan (:mod:`.budget`)
needs neither CasADi nor the planner's imports."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["PlannerOptions"]


@dataclass(frozen=True)
class PlannerOptions:
    """Settings of the offline planner (the tracking weights are the MPC's, ``scenario.mpc``).

    Attributes
    ----------
    tail_s : float
        Extra time after the nominal duration in the fixed-time plan, s (default 1.5): the
        reference rests at the end point while the capsule comes to rest there.
    min_time_dt_s : float
        Step of the minimum-time grid at the initial guess of T, s (default 1/30): N =
        ceil(T0 / this); the solution's step is T / N.
    min_time_guess_speed_fraction : float
        The initial guess of T is the path length over this fraction of ``limits.speed_mps``
        (default 0.5), whatever the nominal speed; T is scaled by it in the NLP.
    tube_m : float
        Cross-track tube radius of the minimum-time plan, m (default 0.5 mm).
    path_smoothing_m : float
        Smoothing length of the path's vertices in the minimum-time tube, m (default 0.2 mm,
        < 2 tube_m; see :func:`path_point_expr`); the tube around the smoothed path is narrowed
        by half of it, so the capsule stays within ``tube_m`` of the true polyline.
    tube_centering_weight : float
        Weight of the squared tube residual ``|p - gamma(sigma)|^2 / tube^2`` per knot in the
        minimum-time cost (default 0.1): it pins each progress variable to the capsule's
        closest path point (otherwise free inside the tube, a singular direction that made
        IPOPT chatter near the optimum); at most ~N/20 cost units against ``time_weight``.
    time_weight : float
        Weight of T / T0 in the minimum-time cost (default 1e3; T0 the initial guess, which
        depends on the path and the limits only, so the plan does not depend on the nominal
        speed); the smoothness term, ``(dU / mpc.input_rate_tol_mps)^2 / 2`` per step, has weight 1.
    end_tol_m : float
        Half-width of the box around the path's end the capsule must stop in, m (default 0.1 mm).
    max_iter : int
        IPOPT iteration cap (default 500).
    tol : float
        IPOPT convergence tolerance (default 1e-7).
    """

    tail_s: float = 1.5
    min_time_dt_s: float = 1.0 / 30.0
    min_time_guess_speed_fraction: float = 0.5
    tube_m: float = 5e-4
    path_smoothing_m: float = 2e-4
    tube_centering_weight: float = 0.1
    time_weight: float = 1e3
    end_tol_m: float = 1e-4
    max_iter: int = 500
    tol: float = 1e-7

    def __post_init__(self) -> None:
        checks = {
            "tail_s": (self.tail_s >= 0, ">= 0"),
            "min_time_dt_s": (self.min_time_dt_s > 0, "> 0"),
            "min_time_guess_speed_fraction": (0 < self.min_time_guess_speed_fraction <= 1, "in (0, 1]"),
            "tube_m": (self.tube_m > 0, "> 0"),
            "path_smoothing_m": (0 <= self.path_smoothing_m < 2 * self.tube_m, "in [0, 2 tube_m)"),
            "time_weight": (self.time_weight > 0, "> 0"),
            "tube_centering_weight": (self.tube_centering_weight >= 0, ">= 0"),
            "end_tol_m": (self.end_tol_m > 0, "> 0"),
            "max_iter": (self.max_iter >= 1, ">= 1"),
            "tol": (self.tol > 0, "> 0"),
        }
        for name, (ok, bound) in checks.items():
            value = getattr(self, name)
            if not (ok and math.isfinite(value)):
                raise ValueError(f"PlannerOptions.{name}: must be finite and {bound}, got {value}")
