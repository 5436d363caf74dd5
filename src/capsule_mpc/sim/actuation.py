"""A simple arm model: the EPM follows velocity commands within speed, acceleration and workspace limits.

The interface and the registry are in :mod:`capsule_mpc.interfaces`; this module registers the
model as ``sim.actuator: simple``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..config import Scenario
from ..interfaces import Actuator, register_actuator, servo_time_constant_s

__all__ = ["SimpleArm"]


@register_actuator("simple")
class SimpleArm(Actuator):
    """A Cartesian arm: per-axis speed and acceleration limits, clamped to the workspace box.

    Each step the velocity moves toward its target by at most ``accel * dt`` per
    axis, then the position integrates it; a position that would leave the
    workspace is held on its face and that axis' velocity zeroed (an instant stop,
    the one velocity change not bounded by ``accel * dt``). Jerk is not limited (the
    Ruckig arm does that). Every intervention is counted (:meth:`limit_counts`) and
    surfaced in the run result.

    The target is the (speed-clipped) command itself, or, with a servo bandwidth
    ``f``, the command passed through a first-order low-pass with time constant
    ``tau = 1 / (2 pi f)``, a real servo's lag: each step the filtered command
    moves by ``alpha = 1 - exp(-dt / tau)`` of its distance to the command (the
    exact discretisation for a command held over the step). The acceleration limit
    and the workspace clamp act after the filter, so they are never exceeded (nor
    is the speed limit: the filter averages speed-clipped commands). The filter
    starts at rest (zero) on :meth:`reset`.

    Parameters
    ----------
    scenario : Scenario
        ``limits.speed_mps``, ``limits.accel_mps2``, ``limits.workspace_min_m`` / ``workspace_max_m``.
    servo_bandwidth_hz : float, optional
        Servo bandwidth ``f``, Hz, > 0 and finite; None (the default) tracks the command with no
        lag (only the acceleration limit).

    Raises
    ------
    ValueError
        If ``servo_bandwidth_hz`` is not None and not a finite value > 0.
    """

    def __init__(self, scenario: Scenario, *, servo_bandwidth_hz: float | None = None) -> None:
        if servo_bandwidth_hz is not None and not (
            math.isfinite(servo_bandwidth_hz) and servo_bandwidth_hz > 0
        ):
            raise ValueError(
                f"servo_bandwidth_hz: must be a finite value > 0 or None, got {servo_bandwidth_hz}"
            )
        self.servo_bandwidth_hz = None if servo_bandwidth_hz is None else float(servo_bandwidth_hz)
        self._servo_radps = 0.0 if servo_bandwidth_hz is None else 2.0 * math.pi * float(servo_bandwidth_hz)
        self._alpha_dt_s = math.nan  # the dt_s the cached alpha was computed for
        self._alpha = 1.0
        self._servo_cmd = [0.0, 0.0, 0.0]  # the low-passed command (servo bandwidth set)
        lim = scenario.limits
        self.speed_mps = float(lim.speed_mps)
        self.accel_mps2 = float(lim.accel_mps2)
        self.lo = [float(v) for v in lim.workspace_min_m]
        self.hi = [float(v) for v in lim.workspace_max_m]
        self._pos = [0.0, 0.0, 0.0]
        self._vel = [0.0, 0.0, 0.0]
        self._cmd = [0.0, 0.0, 0.0]
        self._counts = {"speed_clipped_frames": 0, "accel_limited_steps": 0, "workspace_clamped_steps": 0}

    def reset(self, position_m: np.ndarray) -> None:
        """Put the EPM at rest at ``position_m`` (x, y, height), m; must lie in the workspace."""
        pos = [float(v) for v in np.asarray(position_m, dtype=float).ravel()]
        if len(pos) != 3:
            raise ValueError(f"position_m: must have 3 entries (x, y, height), got {len(pos)}")
        for i, (p, lo, hi) in enumerate(zip(pos, self.lo, self.hi)):
            if not lo <= p <= hi:
                raise ValueError(
                    f"position_m[{i}]: must lie in the workspace [{lo}, {hi}] m (limits.workspace_*), got {p}"
                )
        self._pos = pos
        self._vel = [0.0, 0.0, 0.0]
        self._cmd = [0.0, 0.0, 0.0]
        self._servo_cmd = [0.0, 0.0, 0.0]
        self._counts = dict.fromkeys(self._counts, 0)

    def set_velocity_command(self, t_s: float, velocity_mps: np.ndarray) -> None:
        """Command a velocity (3,), m/s; each axis is clipped to +-``limits.speed_mps`` (counted)."""
        v = [float(c) for c in np.asarray(velocity_mps, dtype=float).ravel()]
        if len(v) != 3 or not all(np.isfinite(v)):
            raise ValueError(f"velocity_mps: must be 3 finite values, got {velocity_mps!r}")
        vmax = self.speed_mps
        clipped = [min(max(c, -vmax), vmax) for c in v]
        if clipped != v:
            self._counts["speed_clipped_frames"] += 1
        self._cmd = clipped

    def step_xyz(self, dt_s: float) -> tuple[float, float, float]:
        """Advance by ``dt_s`` (s); returns the new (x, y, height), m, as floats."""
        dv_max = self.accel_mps2 * dt_s
        pos, vel, target = self._pos, self._vel, self._cmd
        if self.servo_bandwidth_hz is not None:
            target = self._low_pass(dt_s)
        for i in range(3):
            dv = target[i] - vel[i]
            if dv > dv_max:
                dv = dv_max
                self._counts["accel_limited_steps"] += 1
            elif dv < -dv_max:
                dv = -dv_max
                self._counts["accel_limited_steps"] += 1
            v = vel[i] + dv
            p = pos[i] + v * dt_s
            if p < self.lo[i] or p > self.hi[i]:
                p = self.lo[i] if p < self.lo[i] else self.hi[i]
                v = 0.0
                self._counts["workspace_clamped_steps"] += 1
            vel[i] = v
            pos[i] = p
        return pos[0], pos[1], pos[2]

    def _low_pass(self, dt_s: float) -> list[float]:
        """Move the filtered command toward the command over ``dt_s`` (s); returns it (3 floats, m/s)."""
        if dt_s != self._alpha_dt_s:  # the plant's step is fixed: one exp per run, not per step
            self._alpha = -math.expm1(-dt_s * self._servo_radps)  # 1 - exp(-dt / tau), accurately
            self._alpha_dt_s = dt_s
        a, f, cmd = self._alpha, self._servo_cmd, self._cmd
        for i in range(3):
            f[i] += a * (cmd[i] - f[i])
        return f

    @property
    def servo_time_constant_s(self) -> float | None:
        """The servo's time constant ``1 / (2 pi servo_bandwidth_hz)``, s; None without a bandwidth."""
        return servo_time_constant_s(self.servo_bandwidth_hz)

    def step(self, dt_s: float) -> np.ndarray:
        """Advance by ``dt_s`` (s); returns the EPM position (x, y, height), m."""
        return np.array(self.step_xyz(dt_s))

    @property
    def position_m(self) -> np.ndarray:
        """Current EPM position (x, y, height), m."""
        return np.array(self._pos)

    @property
    def velocity_mps(self) -> np.ndarray:
        """Current EPM velocity (3,), m/s."""
        return np.array(self._vel)

    def snapshot(self) -> Any:
        """The arm's state, for :meth:`restore` (the loop steps the arm ahead of the plant)."""
        return ([*self._pos], [*self._vel], [*self._cmd], [*self._servo_cmd], dict(self._counts))

    def restore(self, state: Any) -> None:
        """Go back to a :meth:`snapshot`."""
        pos, vel, cmd, servo, counts = state
        self._pos, self._vel, self._cmd, self._servo_cmd = [*pos], [*vel], [*cmd], [*servo]
        self._counts = dict(counts)

    def limit_counts(self) -> dict[str, int]:
        """Frames whose command exceeded the speed limit, and steps limited by acceleration or workspace."""
        return dict(self._counts)
