"""Errors of the arm side: each names the time and the EPM position it happened at."""

from __future__ import annotations

import numpy as np

__all__ = ["ArmError", "SmoothingError", "UnreachableTargetError"]


class ArmError(ValueError):
    """Something the arm cannot do at a time and EPM position; raised before any joint command
    of the offending run is sent.

    Parameters
    ----------
    t_s : float
        Time along the trajectory, s.
    position_m : array_like (3,)
        The EPM centre position (x, y, z) in the world, m.
    reason : str
        What went wrong.
    """

    def __init__(self, t_s: float, position_m: np.ndarray, reason: str) -> None:
        self.t_s = float(t_s)
        self.position_m = np.asarray(position_m, dtype=float).copy()
        self.reason = reason
        super().__init__(self._message())

    def _where(self) -> str:
        p = self.position_m
        return f"({p[0]:+.4f}, {p[1]:+.4f}, {p[2]:+.4f}) m"

    def _message(self) -> str:
        return f"at t = {self.t_s:.4f} s, EPM {self._where()}: {self.reason}"


class SmoothingError(ArmError):
    """Ruckig could not compute a jerk-limited trajectory to a target (``reason``: its result)."""

    def _message(self) -> str:
        return f"Ruckig failed at t = {self.t_s:.4f} s, EPM target {self._where()}: {self.reason}"


class UnreachableTargetError(ArmError):
    """The arm cannot put the EPM at a point (with its fixed orientation) within its joint limits
    (``reason``: no IK convergence, or which joint leaves its position or velocity limit)."""

    def _message(self) -> str:
        return (
            f"EPM position {self._where()} at t = {self.t_s:.4f} s is not reachable by the arm: "
            f"{self.reason}. No joint command was sent."
        )
