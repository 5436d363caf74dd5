"""The safety layer every computed EPM command passes: speed, acceleration and workspace limits.

It sits left of the controllers that use it (the MPC and the plan replay), so neither imports
the other for it.
"""

from __future__ import annotations

import numpy as np

from .config import Scenario

__all__ = ["safe_command"]


def safe_command(
    u: np.ndarray,
    u_prev: np.ndarray,
    epm_position_m: np.ndarray,
    scenario: Scenario,
    dt_s: float,
) -> tuple[np.ndarray, bool]:
    """Enforce speed, acceleration and workspace limits on a command; returns (command, clipped).

    A non-finite command becomes the braking command. Acceleration is limited relative to
    ``u_prev`` per axis; near a workspace face the velocity toward it is reduced so the
    EPM stops on the face (within the acceleration limit when possible).
    """
    lim = scenario.limits
    u = np.asarray(u, dtype=float).copy()
    u_prev = np.asarray(u_prev, dtype=float)
    if not np.all(np.isfinite(u)):
        u = np.zeros(3)
    if not scenario.mpc.height_control:
        u[2] = 0.0
    target = u.copy()
    da = lim.accel_mps2 * dt_s
    u = np.clip(u, u_prev - da, u_prev + da)
    u = np.clip(u, -lim.speed_mps, lim.speed_mps)
    if not scenario.mpc.height_control:
        u[2] = 0.0
    lo, hi = np.asarray(lim.workspace_min_m), np.asarray(lim.workspace_max_m)
    pos = np.asarray(epm_position_m, dtype=float)
    nxt = pos + u * dt_s
    over = (nxt > hi) & (u > 0) | (nxt < lo) & (u < 0)
    u[over] = np.clip((np.where(u > 0, hi, lo) - pos)[over] / dt_s, -lim.speed_mps, lim.speed_mps)
    return u, bool(np.any(np.abs(u - target) > 1e-12))
