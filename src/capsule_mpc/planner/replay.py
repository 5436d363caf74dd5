"""The ``plan`` controller: replays the fixed-time plan open loop.

At ``reset`` the controller computes (or takes from the in-process cache) the
fixed-time plan of the path on its own model; if that solve fails, ``reset``
raises :class:`~capsule_mpc.planner.core.PlanError` (there is no run to score).
At every frame it commands the planned EPM motion over the coming frame,
``(E(t + dt) - E(t)) / dt`` with ``E`` the planned EPM position (linear between
knots), plus a proportional correction of the EPM's *own* position error toward
``E(t)`` -- the robot knows its pose. It never uses the capsule measurement: that is the point of an
open-loop replay, and what the comparison with the feedback controllers shows.

The plan is anchored at the EPM's start pose: the planned positions are shifted
by ``epm_start - E(0)``. The plan assumes the capsule rests at the path's start
under the EPM at the *model's* equilibrium lead; on the rig the EPM starts where
the capsule actually rests under it, and the shift carries that known start
offset through the whole replay.

Before ``t = 0`` (settle phase) and after the plan's end the EPM holds still
(the correction keeps it at the plan's end pose). Every command passes the
MPC's safety layer (:func:`capsule_mpc.safety.safe_command`: speed, acceleration
and workspace limits).
"""

from __future__ import annotations

import math

import numpy as np

from ..baselines import DEFAULT_POSITION_GAIN_PER_S
from ..config import Scenario
from ..interfaces import Command, Controller, Measurement, StepStats, register_controller
from ..paths import ReferencePath
from ..safety import safe_command
from .core import Plan, PlanError, cached_plan
from .problem import PlannerOptions

__all__ = ["PlanReplay"]


class PlanReplay(Controller):
    """Open-loop replay of the planner's EPM trajectory (see the module docstring).

    Parameters
    ----------
    position_gain_per_s : float
        Gain of the EPM position correction, 1/s, >= 0 (default: the baselines' gain).
    variant : {'fixed', 'min_time'}
        Which plan to replay (the ``plan`` controller replays 'fixed').
    anchor_to_start : bool
        Shift the plan by the EPM's start offset from the planned start (default True).
    options : PlannerOptions, optional
        Planner settings.
    """

    name = "plan"

    def __init__(
        self,
        position_gain_per_s: float = DEFAULT_POSITION_GAIN_PER_S,
        variant: str = "fixed",
        anchor_to_start: bool = True,
        options: PlannerOptions | None = None,
    ) -> None:
        if not (math.isfinite(position_gain_per_s) and position_gain_per_s >= 0):
            raise ValueError(f"position_gain_per_s: must be >= 0, got {position_gain_per_s}")
        if variant not in ("fixed", "min_time"):
            raise ValueError(f"variant: must be 'fixed' or 'min_time', got {variant!r}")
        self.position_gain_per_s = float(position_gain_per_s)
        self.variant = variant
        self.anchor_to_start = bool(anchor_to_start)
        self.options = options
        self.plan: Plan | None = None

    def reset(self, scenario: Scenario, path: ReferencePath, epm_position_m: np.ndarray) -> None:
        """Plan the path (or reuse the cached plan) and anchor it at the EPM's start pose.

        Raises
        ------
        PlanError
            If the solve failed: there is nothing to replay, and holding the EPM still for the
            whole run would be scored as if the controller had run.
        """
        self.scenario = scenario
        self.frame_s = 1.0 / scenario.camera.rate_hz
        plan = cached_plan(scenario, path, self.variant, self.options)
        if not plan.success:
            self.plan = None
            raise PlanError(f"plan controller: no plan to replay: {plan.failure}")
        self.plan = plan
        epm0 = np.asarray(epm_position_m, dtype=float)
        self.offset_m = epm0 - self.plan.epm_position_m[0] if self.anchor_to_start else np.zeros(3)
        self.u_prev = np.zeros(3)

    def _emit(self, u: np.ndarray, epm: np.ndarray, stats: StepStats) -> Command:
        cmd, clipped = safe_command(u, self.u_prev, epm, self.scenario, self.frame_s)
        if clipped:
            stats.extra["clipped"] = 1.0
        self.u_prev = cmd
        return Command(cmd, stats)

    def step(self, t_s: float, measurement: Measurement, epm_position_m: np.ndarray) -> Command:
        """The planned EPM motion over the coming frame plus the EPM position correction."""
        epm = np.asarray(epm_position_m, dtype=float)
        plan = self.plan
        if plan is None:
            raise RuntimeError("PlanReplay.step: call reset() first (and it must not have raised)")
        if t_s < 0:
            return self._emit(np.zeros(3), epm, StepStats(status="settle", phase="settle"))
        now = plan.epm_position_at(t_s) + self.offset_m
        ahead = plan.epm_position_at(t_s + self.frame_s) + self.offset_m
        u = (ahead - now) / self.frame_s + self.position_gain_per_s * (now - epm)
        running = t_s < plan.duration_s  # the phases as the MPC's are named
        stats = StepStats(status="replay" if running else "done", phase="slide" if running else "hold")
        return self._emit(u, epm, stats)

    def predicted_capsule_path(self) -> np.ndarray | None:
        """The plan's predicted capsule positions (N+1, 2), m."""
        return None if self.plan is None else self.plan.capsule_position_m.copy()


@register_controller("plan")
def _plan_replay() -> Controller:
    """``plan``: open-loop replay of the fixed-time plan."""
    return PlanReplay()
