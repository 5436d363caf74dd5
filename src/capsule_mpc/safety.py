"""The safety layer every computed EPM command passes: speed, acceleration, jerk and workspace limits.

It sits left of the controllers that use it (the MPC and the plan replay), so neither imports
the other for it.

What it guarantees, per axis, for any input (NaN, inf, huge values included): the command is
finite, within ``+-limits.speed_mps``, and within ``limits.accel_mps2 * dt_s`` of the previous
command (no jump) -- a non-finite previous command counts as 0 -- and one step at it does not
leave the workspace. Toward a workspace face the speed is capped by the braking envelope
(:func:`braking_speed_mps`): the speed from which braking at the acceleration limit, one command
per ``dt_s``, stops the EPM on the face. A command inside the envelope leaves the next one inside
it (braking by ``accel * dt`` exactly keeps pace with the shrinking distance), so the EPM never
has to stop harder than the acceleration limit. Only an EPM already faster than its envelope
(e.g. started next to a face at speed) can need more: then the workspace wins, and the command
is cut to the speed that stops on the face in one step (the one case of a larger change, as the
arm's own clamp would do). The height command is 0 unless ``mpc.height_control``.

Jerk (``limits.jerk_mps3``): given the previous command's slope (its change over its frame),
the command's change stays within ``limits.jerk_mps3 * dt_s**2`` of that slope's, so the stream
of commands is one the jerk-limited arm can follow; the speed limit is approached with the change
shrinking within that bound (it never has to stop growing at once). Priority when the limits
conflict: workspace, then speed and the braking envelope, then acceleration, then jerk -- a
command that must brake harder than the jerk limit allows (an EPM fast toward a face, a braking
command after a fault) keeps the acceleration bound and is reported as clipped.
"""

from __future__ import annotations

import math

import numpy as np

from .config import Scenario

__all__ = ["SafetyFilter", "braking_speed_mps", "safe_command"]

#: A reported EPM position this far from the origin (m) is not a position but a broken reading
#: (it would overflow the envelope's arithmetic): the command brakes as for a NaN position.
_FAR_M = 1e6


def braking_speed_mps(distance_m: np.ndarray, accel_mps2: float, dt_s: float) -> np.ndarray:
    """The highest speed toward a face ``distance_m`` away from which braking stops on it.

    Braking lowers the speed by ``da = accel_mps2 * dt_s`` per command of length ``dt_s``: from
    ``v`` it covers ``D(v) = dt (v + (v - da) + ... )`` over the positive terms, so
    ``D(n da) = dt da n (n + 1) / 2`` and ``D`` is linear in between. The speed returned solves
    ``D(v) = distance`` (0 at or past the face). ``D(v) = v dt + D(v - da)`` is what keeps a
    command inside this envelope inside it at the next step.
    """
    d = np.maximum(np.asarray(distance_m, dtype=float), 0.0)
    da = accel_mps2 * dt_s
    n = np.floor((np.sqrt(1.0 + 8.0 * d / (dt_s * da)) - 1.0) / 2.0)  # whole braking steps
    return (d / dt_s + da * n * (n + 1.0) / 2.0) / (n + 1.0)


def safe_command(
    u: np.ndarray,
    u_prev: np.ndarray,
    epm_position_m: np.ndarray,
    scenario: Scenario,
    dt_s: float,
    slope_prev_mps2: np.ndarray | None = None,
) -> tuple[np.ndarray, bool]:
    """Enforce speed, acceleration, jerk and workspace limits on a command; returns (command, clipped).

    Parameters
    ----------
    u : numpy.ndarray (3,)
        The command wanted, m/s; a non-finite entry makes the whole command a braking one (0).
    u_prev : numpy.ndarray (3,)
        The previous command sent, m/s (non-finite entries count as 0, and the height's without
        ``mpc.height_control``).
    epm_position_m : numpy.ndarray (3,)
        The EPM's position, m; with a non-finite entry (or one farther than 1000 km) the
        workspace is not known, and the command brakes (toward 0 within the acceleration limit).
    scenario : Scenario
        ``limits`` and ``mpc.height_control``.
    dt_s : float
        Command period, s (> 0).
    slope_prev_mps2 : numpy.ndarray (3,), optional
        The previous command's change over its frame divided by ``dt_s``, m/s^2 (non-finite
        entries count as 0); None leaves jerk unbounded (acceleration and speed still hold).

    Returns
    -------
    tuple of numpy.ndarray (3,) and bool
        The command (see the module docstring for its guarantees) and whether it differs from
        ``u``.
    """
    # np.minimum/np.maximum instead of np.clip and math.isfinite on the three floats instead of
    # np.isfinite: the same arithmetic, at a fraction of the call overhead on 3-vectors (this runs
    # every frame; it was a tenth of the MPC's step time).
    lim = scenario.limits
    speed = lim.speed_mps
    target = np.array(u, dtype=float).ravel()
    prev = np.array(u_prev, dtype=float).ravel()
    prev[~np.isfinite(prev)] = 0.0
    prev = np.minimum(np.maximum(prev, -speed), speed)
    pos = np.asarray(epm_position_m, dtype=float).ravel()
    known = all(abs(p) < _FAR_M for p in pos.tolist())  # where the EPM is (False for NaN): else brake
    finite = known and all(math.isfinite(v) for v in target.tolist())
    u = target.copy() if finite else np.zeros(3)
    if not scenario.mpc.height_control:  # the height is held: its command is and was 0
        u[2] = prev[2] = 0.0
    u = np.minimum(np.maximum(u, -speed), speed)
    lo, hi = np.asarray(lim.workspace_min_m, dtype=float), np.asarray(lim.workspace_max_m, dtype=float)
    if known:
        envelope = braking_speed_mps(np.concatenate([hi - pos, pos - lo]), lim.accel_mps2, dt_s)
        u = np.minimum(np.maximum(u, -envelope[3:]), envelope[:3])
    da = lim.accel_mps2 * dt_s
    if slope_prev_mps2 is not None:  # jerk: the change stays near the previous change
        slope = np.array(slope_prev_mps2, dtype=float).ravel()
        slope[~np.isfinite(slope)] = 0.0
        if not scenario.mpc.height_control:
            slope[2] = 0.0
        step = np.minimum(np.maximum(slope * dt_s, -da), da)
        dj = lim.jerk_mps3 * dt_s * dt_s
        lo_j, hi_j = prev + step - dj, prev + step + dj
        # Within the speed limit and the braking envelope where the two overlap; else the
        # nearer edge of the jerk band (the acceleration bound below still holds).
        u = np.minimum(np.maximum(u, lo_j), hi_j)
        if known:
            u = np.minimum(np.maximum(u, -envelope[3:]), envelope[:3])
        # The speed limit approached within the jerk limit: a change s per frame, shrinking by dj
        # each frame, still adds at most s^2 / (2 dj) before it has stopped growing, so the change
        # is kept to the s with u + s^2 / (2 dj) <= speed (each frame then leaves the next one room).
        room_hi, room_lo = np.maximum(speed - prev, 0.0), np.maximum(speed + prev, 0.0)
        u = np.minimum(u, prev + dj * (np.sqrt(1.0 + 2.0 * room_hi / dj) - 1.0))
        u = np.maximum(u, prev - dj * (np.sqrt(1.0 + 2.0 * room_lo / dj) - 1.0))
        u = np.minimum(np.maximum(u, -speed), speed)
    u = np.minimum(np.maximum(u, prev - da), prev + da)
    if known:  # outside the envelope already: stop on the face rather than cross it
        u = np.minimum(np.maximum(u, np.minimum((lo - pos) / dt_s, 0.0)), np.maximum((hi - pos) / dt_s, 0.0))
    return u, bool(not finite or float(np.max(np.abs(u - target))) > 1e-12)


class SafetyFilter:
    """:func:`safe_command` on a stream of commands: it keeps the command sent and its slope (the
    jerk bound's memory) and counts the commands it clipped.

    Parameters
    ----------
    scenario : Scenario
        ``limits`` and ``mpc.height_control``.
    dt_s : float
        Command period, s (> 0).
    """

    def __init__(self, scenario: Scenario, dt_s: float) -> None:
        self.scenario = scenario
        self.dt_s = dt_s
        #: The last command sent (m/s) and its change over its frame (m/s^2).
        self.u_prev = np.zeros(3)
        self.slope_prev = np.zeros(3)
        #: Commands that were clipped so far.
        self.clipped = 0

    def apply(self, u: np.ndarray, epm_position_m: np.ndarray) -> tuple[np.ndarray, bool]:
        """The command to send for ``u`` (m/s) with the EPM at ``epm_position_m`` (m), and whether
        it was clipped; it becomes the previous command of the next call."""
        cmd, clipped = safe_command(u, self.u_prev, epm_position_m, self.scenario, self.dt_s, self.slope_prev)
        self.clipped += int(clipped)
        self.slope_prev = (cmd - self.u_prev) / self.dt_s
        self.u_prev = cmd
        return cmd, clipped
