"""Errors of the arm side: each names the time and the EPM position it happened at (a refused plan:
the data row and field)."""

from __future__ import annotations

import numpy as np

from ..errors import CapsuleMPCError

__all__ = ["ArmError", "EPMTrajectoryError", "ExportCheckError", "SmoothingError", "UnreachableTargetError"]


class ArmError(CapsuleMPCError, ValueError):
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


class EPMTrajectoryError(ArmError):
    """An EPM trajectory refused before anything is computed or written (``reason``), naming the data row
    (1-based, counted after the header; None for the plan as a whole) and the field.

    Parameters
    ----------
    reason : str
        What is wrong and the allowed range.
    row : int, optional
        The 1-based data row (the first row after the header is 1).
    field : str, optional
        The column (``t_s``, ``epm_x_m``, ``epm_y_m``, ``epm_z_m``).
    t_s : float, optional
        The row's time, s (NaN when unknown).
    position_m : array_like (3,), optional
        The row's EPM position, m (NaN when unknown).
    """

    def __init__(
        self,
        reason: str,
        *,
        row: int | None = None,
        field: str | None = None,
        t_s: float = float("nan"),
        position_m: np.ndarray | None = None,
    ) -> None:
        self.row = row
        self.field = field
        super().__init__(t_s, np.full(3, np.nan) if position_m is None else position_m, reason)

    def _message(self) -> str:
        where = []
        if self.row is not None:
            where.append(f"data row {self.row}" + (f" (t_s = {self.t_s:g})" if np.isfinite(self.t_s) else ""))
        if self.field is not None:
            where.append(self.field)
        return f"{', '.join(where)}: {self.reason}" if where else self.reason


class ExportCheckError(ArmError):
    """The computed arm trajectory failed its final check (``reason``: which check, by how much, and
    the tolerance): it deviates from the plan, leaves the workspace or a joint limit. Raised before
    anything is written."""

    def _message(self) -> str:
        return (
            f"the arm trajectory fails its check at t = {self.t_s:.4f} s, EPM {self._where()}: {self.reason}"
        )
