"""The safety layer every computed EPM command passes: speed, acceleration and workspace limits.

It sits left of the controllers that use it (the MPC and the plan replay), so neither imports
the other for it.

What it guarantees, per axis, for any input (NaN, inf, huge values included): the command is
finite, within ``+-limits.speed_mps``, and within ``limits.accel_mps2 * dt_s`` of the previous
command (no jump) -- a non-finite previous command counts as 0. Toward a workspace face the speed
is capped by the braking envelope: the speed from which braking at the acceleration limit, one
command per ``dt_s``, stops the EPM on the face. A command inside the envelope stays inside it
at the next step, so the EPM never has to stop harder than the acceleration limit; only an EPM
that is already faster than its envelope (started too close to a face) brakes at that limit
and may reach the face, where the arm holds it. The height command is 0 unless
``mpc.height_control``. Jerk (``limits.jerk_mps3``) is the arm's limit between commands (the
Ruckig arm enforces it); it is not enforced here.
"""

from __future__ import annotations

import numpy as np

from .config import Scenario

__all__ = ["braking_speed_mps", "safe_command"]


def braking_speed_mps(distance_m: np.ndarray, accel_mps2: float, dt_s: float) -> np.ndarray:
    """The highest speed toward a face ``distance_m`` away from which braking stops on it.

    Braking by ``accel_mps2 * dt_s`` per command of length ``dt_s`` from speed ``v`` covers about
    ``v^2 / (2 a) + v dt / 2``; the speed returned makes that equal to the distance (0 at or past
    the face).
    """
    d = np.maximum(np.asarray(distance_m, dtype=float), 0.0)
    return accel_mps2 * (np.sqrt(0.25 * dt_s * dt_s + 2.0 * d / accel_mps2) - 0.5 * dt_s)


def safe_command(
    u: np.ndarray,
    u_prev: np.ndarray,
    epm_position_m: np.ndarray,
    scenario: Scenario,
    dt_s: float,
) -> tuple[np.ndarray, bool]:
    """Enforce speed, acceleration and workspace limits on a command; returns (command, clipped).

    Parameters
    ----------
    u : numpy.ndarray (3,)
        The command wanted, m/s; a non-finite entry makes the whole command a braking one (0).
    u_prev : numpy.ndarray (3,)
        The previous command sent, m/s (non-finite entries count as 0).
    epm_position_m : numpy.ndarray (3,)
        The EPM's position, m; with a non-finite entry the workspace is not known, and the
        command brakes (toward 0 within the acceleration limit).
    scenario : Scenario
        ``limits`` and ``mpc.height_control``.
    dt_s : float
        Command period, s (> 0).

    Returns
    -------
    tuple of numpy.ndarray (3,) and bool
        The command (see the module docstring for its guarantees) and whether it differs from
        ``u``.
    """
    lim = scenario.limits
    target = np.asarray(u, dtype=float).ravel().copy()
    u_prev = np.asarray(u_prev, dtype=float).ravel()
    u_prev = np.clip(np.where(np.isfinite(u_prev), u_prev, 0.0), -lim.speed_mps, lim.speed_mps)
    pos = np.asarray(epm_position_m, dtype=float).ravel()
    finite = bool(np.all(np.isfinite(target))) and bool(np.all(np.isfinite(pos)))
    u = target.copy() if finite else np.zeros(3)
    if not scenario.mpc.height_control:
        u[2] = 0.0
    u = np.clip(u, -lim.speed_mps, lim.speed_mps)
    if finite:
        lo, hi = np.asarray(lim.workspace_min_m), np.asarray(lim.workspace_max_m)
        v_up = braking_speed_mps(hi - pos, lim.accel_mps2, dt_s)
        v_down = braking_speed_mps(pos - lo, lim.accel_mps2, dt_s)
        u = np.clip(u, -v_down, v_up)
    da = lim.accel_mps2 * dt_s
    u = np.clip(u, u_prev - da, u_prev + da)
    if not scenario.mpc.height_control and abs(u_prev[2]) <= da:
        u[2] = 0.0
    return u, bool(not finite or np.any(np.abs(u - target) > 1e-12))
