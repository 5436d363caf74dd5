"""Errors of the arm side: each names the time and the EPM position it happened at."""

from __future__ import annotations

import numpy as np

__all__ = ["ArmError", "SmoothingError", "UnreachableTargetError"]


class ArmError(ValueError):
    """Something the arm cannot do; raised before any joint command of the offending run is sent."""


class SmoothingError(ArmError):
    """Ruckig could not compute a jerk-limited trajectory to a target.

    Parameters
    ----------
    t_s : float
        Time of the target, s.
    position_m : array_like (3,)
        The target EPM position (x, y, z), m.
    reason : str
        What went wrong (the Ruckig result).
    """

    def __init__(self, t_s: float, position_m: np.ndarray, reason: str) -> None:
        self.t_s = float(t_s)
        self.position_m = np.asarray(position_m, dtype=float).copy()
        self.reason = reason
        p = self.position_m
        super().__init__(
            f"Ruckig failed at t = {self.t_s:.4f} s, EPM target ({p[0]:+.4f}, {p[1]:+.4f}, {p[2]:+.4f}) m: "
            f"{reason}"
        )


class UnreachableTargetError(ArmError):
    """The arm cannot put the EPM at a point (with its fixed orientation) within its joint limits.

    Parameters
    ----------
    t_s : float
        Time of the point along the trajectory, s.
    position_m : array_like (3,)
        The EPM centre position (x, y, z) in the world, m.
    reason : str
        Why: no IK convergence, or which joint leaves its position or velocity limit.
    """

    def __init__(self, t_s: float, position_m: np.ndarray, reason: str) -> None:
        self.t_s = float(t_s)
        self.position_m = np.asarray(position_m, dtype=float).copy()
        self.reason = reason
        p = self.position_m
        super().__init__(
            f"EPM position ({p[0]:+.4f}, {p[1]:+.4f}, {p[2]:+.4f}) m at t = {self.t_s:.4f} s is not "
            f"reachable by the arm: {reason}. No joint command was sent."
        )
