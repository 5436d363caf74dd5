"""Ruckig jerk-limited smoothing of EPM Cartesian setpoints (camera rate -> arm rate).

Two interfaces, both with per-axis velocity, acceleration and jerk limits
(``ArmConfig.cartesian_limits``):

* :class:`VelocitySmoother` -- online, for the MPC: each camera frame sets a target
  EPM velocity (Ruckig's velocity control interface) and every arm tick makes one
  ``Ruckig.update``.
* :func:`smooth_waypoints` -- a whole plan: the plan's positions are streamed to
  Ruckig one target at a time, each as a state-to-state motion whose minimum
  duration is the plan's time to that waypoint, and sampled on the arm-rate grid.
  (Ruckig's community edition sends *intermediate* waypoints to a cloud service and
  fails offline, so they are never passed at once.)

Between targets the state (position, velocity, acceleration) is carried over
exactly, so the setpoints are continuous up to acceleration and their jerk is
bounded by the limit.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, field

import numpy as np
import ruckig

from ..config import Scenario
from .errors import SmoothingError

__all__ = [
    "DEFAULT_LOOKAHEAD_S",
    "CartesianLimits",
    "CartesianTrajectory",
    "SmoothingStats",
    "VelocitySmoother",
    "smooth_waypoints",
]

#: Ruckig results that mean a valid trajectory was computed.
_OK = (ruckig.Result.Working, ruckig.Result.Finished)
#: Ruckig's error results in words (its Python binding does not name all of them: it raises
#: ``ValueError("-101 is not a valid Result.")`` instead).
_RUCKIG_ERRORS = {
    -1: "an unclassified error",
    -100: "an input it cannot use (a non-finite value or a target beyond the limits)",
    -101: "a motion that would last longer than its numerical limit (about 7600 s)",
    -102: "a target beyond its position limits",
    -104: "a zero limit",
    -110: "no solution for the motion's duration (numerical failure)",
    -111: "no solution for the axes' synchronisation (numerical failure)",
}
#: Target states are kept this fraction inside the limits, so Ruckig's input check never trips
#: on rounding (dimensionless).
_TARGET_MARGIN = 1.0 - 1e-9
#: Below this largest difference between current and target state (m, m/s, m/s^2) a motion is
#: treated as done: Ruckig can fail on a zero-length motion left by rounding.
_NEGLIGIBLE_STATE_GAP = 1e-9
#: Differences of position (m), velocity (m/s) and acceleration (m/s^2) that are floating-point
#: rounding, not motion.
_ROUNDING = (1e-12, 1e-12, 1e-9)
#: A waypoint reached within this of its plan time counts as on time, s.
_ON_TIME_S = 1e-9
#: A motion Ruckig fails on is tried again with its target velocity and acceleration pulled this
#: much further inside the limits (relative): Ruckig's synchronisation step can fail numerically
#: on a target within rounding of a limit, and a millionth of the limit is no motion.
_RETRY_SHRINK = (1e-6, 1e-4)
#: Default look-ahead of plan targets, s (6 camera frames): on a rectangle at 0.02 and 0.045 m/s
#: and a circle, with the default limits, 0.15-0.2 s gave the smallest deviation from the plan
#: among 0-0.3 s (0.2 s: max 1.2 / 4.1 / 1.4 mm).
DEFAULT_LOOKAHEAD_S = 0.2


def _as_vec3(value: object, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ValueError(f"{name}: must be 3 finite values > 0 (x, y, z), got {value!r}")
    return arr


@dataclass(frozen=True)
class CartesianLimits:
    """Per-axis limits of the EPM motion.

    Attributes
    ----------
    velocity_mps : numpy.ndarray (3,)
        Maximum |velocity| per axis (x, y, z), m/s.
    acceleration_mps2 : numpy.ndarray (3,)
        Maximum |acceleration| per axis, m/s^2.
    jerk_mps3 : numpy.ndarray (3,)
        Maximum |jerk| per axis, m/s^3.
    """

    velocity_mps: np.ndarray
    acceleration_mps2: np.ndarray
    jerk_mps3: np.ndarray

    def __post_init__(self) -> None:
        for name in ("velocity_mps", "acceleration_mps2", "jerk_mps3"):
            object.__setattr__(self, name, _as_vec3(getattr(self, name), name))

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> CartesianLimits:
        """The arm's limits of ``scenario`` (``arm.max_*``, defaulting to ``limits.*``)."""
        vel, acc, jerk = scenario.arm.cartesian_limits(scenario.limits)
        return cls(np.array(vel), np.array(acc), np.array(jerk))

    def apply(self, inp: ruckig.InputParameter) -> None:
        """Write the limits into a Ruckig input."""
        inp.max_velocity = self.velocity_mps.tolist()
        inp.max_acceleration = self.acceleration_mps2.tolist()
        inp.max_jerk = self.jerk_mps3.tolist()


@dataclass(frozen=True)
class SmoothingStats:
    """What the smoothing of a plan reports.

    Attributes
    ----------
    n_waypoints : int
        Plan waypoints (including the start).
    n_setpoints : int
        Arm-rate setpoints produced.
    ruckig_calls : int
        Trajectories computed (one or two per waypoint interval).
    max_deviation_m : float
        Worst distance between a setpoint and the plan (linearly interpolated) at the same time, m.
    rms_deviation_m : float
        Root-mean-square of that distance, m.
    end_lag_s : float
        Delay of the final stop after the plan's last time, s.
    clipped_targets : int
        Waypoint velocity/acceleration targets that had to be clipped to the limits.
    wall_s : float
        Wall time of the smoothing, s.
    """

    n_waypoints: int
    n_setpoints: int
    ruckig_calls: int
    max_deviation_m: float
    rms_deviation_m: float
    end_lag_s: float
    clipped_targets: int
    wall_s: float


@dataclass(frozen=True)
class CartesianTrajectory:
    """EPM setpoints at the arm rate.

    Attributes
    ----------
    t_s : numpy.ndarray (N,)
        Times on a uniform grid, s.
    position_m : numpy.ndarray (N, 3)
        EPM centre (x, y, z) in the world, m.
    velocity_mps : numpy.ndarray (N, 3)
        EPM velocity, m/s.
    acceleration_mps2 : numpy.ndarray (N, 3)
        EPM acceleration, m/s^2.
    stats : SmoothingStats or None
        The smoothing's report (None for trajectories recorded online).
    """

    t_s: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    acceleration_mps2: np.ndarray
    stats: SmoothingStats | None = field(default=None, compare=False)

    def __len__(self) -> int:
        return int(self.t_s.shape[0])


class VelocitySmoother:
    """Online jerk-limited EPM setpoints from velocity commands (Ruckig velocity interface).

    Each axis approaches its commanded velocity time-optimally under its own limits
    (``Synchronization.No``). With a workspace box, a guard keeps every setpoint inside it:
    a tick is accepted only if, from the new state, braking to rest under the limits stops
    inside the box; otherwise the axes that would not stop in time are commanded to zero
    velocity for that tick (counted in :attr:`braking_ticks`). Since every accepted state can
    brake inside the box, the setpoints never leave it, and jerk stays limited.

    Parameters
    ----------
    limits : CartesianLimits
        Per-axis limits.
    rate_hz : float
        Arm rate, Hz: each :meth:`step` advances one period.
    workspace_m : tuple of array_like (3,), optional
        Lower and upper corners of the box the EPM centre must stay in, m.

    Notes
    -----
    A commanded velocity beyond the per-axis limit is clipped to it (counted in
    :attr:`clipped_commands`): the arm cannot go faster, and Ruckig rejects such targets.
    """

    def __init__(
        self,
        limits: CartesianLimits,
        rate_hz: float,
        workspace_m: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise ValueError(f"rate_hz: must be a finite number > 0, got {rate_hz}")
        self.limits = limits
        self.dt_s = 1.0 / rate_hz
        self._otg = ruckig.Ruckig(3, self.dt_s)
        self._inp = self._velocity_input(limits)
        self._out = ruckig.OutputParameter(3)
        self._brake_otg = ruckig.Ruckig(3)
        self._brake_inp = self._velocity_input(limits)
        self._brake_traj = ruckig.Trajectory(3)
        self.workspace_m: tuple[np.ndarray, np.ndarray] | None = None
        if workspace_m is not None:
            lo, hi = (np.asarray(c, dtype=float) for c in workspace_m)
            if lo.shape != (3,) or hi.shape != (3,) or not np.all(lo < hi):
                raise ValueError(
                    f"workspace_m: must be two (3,) corners with lower < upper, got {workspace_m!r}"
                )
            self.workspace_m = (lo, hi)
        self._a_list = limits.acceleration_mps2.tolist()
        self._j_list = limits.jerk_mps3.tolist()
        self._box = (
            ([0.0] * 3, [0.0] * 3)
            if self.workspace_m is None
            else tuple(c.tolist() for c in self.workspace_m)
        )
        self._target = np.zeros(3)
        self.clipped_commands = 0
        self.braking_ticks = 0
        self.reset(
            np.zeros(3) if self.workspace_m is None else (self.workspace_m[0] + self.workspace_m[1]) / 2
        )

    @staticmethod
    def _velocity_input(limits: CartesianLimits) -> ruckig.InputParameter:
        inp = ruckig.InputParameter(3)
        inp.control_interface = ruckig.ControlInterface.Velocity
        inp.synchronization = ruckig.Synchronization.No
        limits.apply(inp)
        return inp

    def reset(self, position_m: np.ndarray) -> None:
        """Start at rest at ``position_m`` (3,), m (inside the workspace, if any); target 0; t = 0."""
        p = np.asarray(position_m, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"position_m: must be 3 finite values, got {position_m!r}")
        if self.workspace_m is not None:
            lo, hi = self.workspace_m
            bad = np.flatnonzero((p < lo) | (p > hi))
            if bad.size:
                i = int(bad[0])
                raise ValueError(
                    f"position_m[{i}]: must lie in the workspace [{lo[i]}, {hi[i]}] m "
                    f"(limits.workspace_*), got {p[i]}"
                )
        self._inp.current_position = p.tolist()
        self._inp.current_velocity = [0.0, 0.0, 0.0]
        self._inp.current_acceleration = [0.0, 0.0, 0.0]
        self._inp.target_velocity = [0.0, 0.0, 0.0]
        self._inp.target_acceleration = [0.0, 0.0, 0.0]
        self._target = np.zeros(3)
        self._position = p.copy()
        self._velocity = np.zeros(3)
        self._acceleration = np.zeros(3)
        self.t_s = 0.0

    def set_target_velocity(self, velocity_mps: np.ndarray) -> np.ndarray:
        """Set the velocity to reach (3,), m/s; returns the target actually used (clipped to limits)."""
        v = np.asarray(velocity_mps, dtype=float)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ValueError(f"velocity_mps: must be 3 finite values, got {velocity_mps!r}")
        cap = self.limits.velocity_mps * _TARGET_MARGIN
        clipped = np.clip(v, -cap, cap)
        if np.any(clipped != v):
            self.clipped_commands += 1
        self._target = clipped
        return clipped.copy()

    def _update(self, target: list[float]) -> None:
        self._inp.target_velocity = target
        res = self._otg.update(self._inp, self._out)
        if res not in _OK:
            raise SmoothingError(self.t_s + self.dt_s, self._position, f"Ruckig update returned {res}")

    def _overrun_axes(self, pos: list[float], vel: list[float], acc: list[float]) -> list[int]:
        """Axes that, braking to rest from this state under the limits, would stop outside the box."""
        lo, hi = self._box
        # Generous bound of the braking distance: peak speed while the acceleration is removed,
        # held for the longest braking time. Only near a face is the exact check needed (plain
        # floats: this runs every arm tick).
        near = []
        for i in range(3):
            v, a, j, a_max = abs(vel[i]), abs(acc[i]), self._j_list[i], self._a_list[i]
            v_peak = v + a * a / (2.0 * j)
            reach = v_peak * (a / j + v_peak / a_max + a_max / j)
            if min(pos[i] - lo[i], hi[i] - pos[i]) <= reach + 1e-12:
                near.append(i)
        if not near:
            return []
        bi = self._brake_inp
        bi.current_position, bi.current_velocity, bi.current_acceleration = pos, vel, acc
        bi.target_velocity = [0.0, 0.0, 0.0]
        bi.target_acceleration = [0.0, 0.0, 0.0]
        res = self._brake_otg.calculate(bi, self._brake_traj)
        if res not in _OK:
            raise SmoothingError(self.t_s, np.array(pos), f"Ruckig braking check returned {res}")
        ext = self._brake_traj.position_extrema
        return [i for i in near if ext[i].min < lo[i] or ext[i].max > hi[i]]

    def step(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance one arm period with one Ruckig update (two when the workspace guard brakes).

        Returns
        -------
        position_m, velocity_mps, acceleration_mps2 : numpy.ndarray (3,)
            The new setpoint, m, m/s, m/s^2.

        Raises
        ------
        SmoothingError
            If Ruckig returns an error (the state is left unchanged).
        """
        target = self._target.tolist()
        self._update(target)
        out = self._out
        if self.workspace_m is not None:
            axes = self._overrun_axes(out.new_position, out.new_velocity, out.new_acceleration)
            if axes:
                for i in axes:
                    target[i] = 0.0
                self.braking_ticks += 1
                self._update(target)
        out.pass_to_input(self._inp)
        self._position = np.array(out.new_position)
        self._velocity = np.array(out.new_velocity)
        self._acceleration = np.array(out.new_acceleration)
        self.t_s += self.dt_s
        return self._position, self._velocity, self._acceleration

    @property
    def position_m(self) -> np.ndarray:
        """Current setpoint position (3,), m."""
        return self._position.copy()

    @property
    def velocity_mps(self) -> np.ndarray:
        """Current setpoint velocity (3,), m/s."""
        return self._velocity.copy()

    @property
    def acceleration_mps2(self) -> np.ndarray:
        """Current setpoint acceleration (3,), m/s^2."""
        return self._acceleration.copy()

    @property
    def target_velocity_mps(self) -> np.ndarray:
        """The commanded velocity being approached (3,), m/s (after clipping)."""
        return self._target.copy()


def _validate_waypoints(t_s: np.ndarray, positions_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t_s, dtype=float)
    p = np.asarray(positions_m, dtype=float)
    if t.ndim != 1 or t.shape[0] < 1:
        raise ValueError(f"t_s: must be a 1-D array of >= 1 times, got shape {t.shape}")
    if p.shape != (t.shape[0], 3):
        raise ValueError(f"positions_m: must have shape ({t.shape[0]}, 3) to match t_s, got {p.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise ValueError(f"t_s[{bad[0]}]: must be finite, got {t[bad[0]]}")
    bad = np.flatnonzero(~np.all(np.isfinite(p), axis=1))
    if bad.size:
        raise ValueError(f"positions_m[{bad[0]}]: must be finite, got {p[bad[0]].tolist()}")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise ValueError(f"t_s[{i}]: must be > t_s[{i - 1}] = {t[i - 1]} (strictly increasing), got {t[i]}")
    return t, p


def _waypoint_targets(
    t: np.ndarray, p: np.ndarray, limits: CartesianLimits
) -> tuple[np.ndarray, np.ndarray, int]:
    """Velocity and acceleration to pass each waypoint with, clipped to be valid Ruckig targets.

    Central differences of the plan; the first and last waypoints are at rest. A target acceleration
    is also limited so that the velocity it carries does not overshoot the velocity limit
    (|v + a |a| / (2 j)| <= v_max), which Ruckig requires.
    """
    n = t.shape[0]
    if n < 3:
        return np.zeros((n, 3)), np.zeros((n, 3)), 0
    v = np.gradient(p, t, axis=0)
    v[0] = v[-1] = 0.0
    a = np.gradient(v, t, axis=0)
    a[0] = a[-1] = 0.0
    v_cap = limits.velocity_mps * _TARGET_MARGIN
    a_cap = limits.acceleration_mps2 * _TARGET_MARGIN
    v_new = np.clip(v, -v_cap, v_cap)
    a_new = np.clip(a, -a_cap, a_cap)
    # A jerk-limited motion arriving with acceleration a had velocity v - a|a|/(2j) just before
    # (and would reach v + a|a|/(2j) just after): keep both within the limit.
    room = v_cap - np.abs(v_new)
    a_room = np.sqrt(2.0 * limits.jerk_mps3 * np.maximum(room, 0.0)) * _TARGET_MARGIN
    a_new = np.clip(a_new, -a_room, a_room)
    clipped = int(np.count_nonzero(np.any((v_new != v) | (a_new != a), axis=1)))
    # Differences of a constant (a still axis) are not exactly 0 on a non-uniform time grid.
    v_new[np.abs(v_new) < _ROUNDING[1]] = 0.0
    a_new[np.abs(a_new) < _ROUNDING[2]] = 0.0
    return v_new, a_new, clipped


class _Sampler:
    """Collects arm-rate samples of consecutive Ruckig trajectories on the grid ``t0 + k dt``."""

    def __init__(self, t0: float, dt: float) -> None:
        self.t0, self.dt, self.k = t0, dt, 0
        self.t: list[float] = []
        self.p: list[list[float]] = []
        self.v: list[list[float]] = []
        self.a: list[list[float]] = []

    def next_time(self) -> float:
        return self.t0 + self.k * self.dt

    def sample(self, traj: ruckig.Trajectory, start_s: float, end_s: float) -> None:
        """Sample ``traj`` (started at ``start_s``) at every grid time in [start_s, end_s)."""
        g = self.next_time()
        while g < end_s:
            pos, vel, acc = traj.at_time(g - start_s)
            self.append(g, pos, vel, acc)
            g = self.next_time()

    def append(self, g: float, pos: list[float], vel: list[float], acc: list[float]) -> None:
        self.t.append(g)
        self.p.append(pos)
        self.v.append(vel)
        self.a.append(acc)
        self.k += 1


def _plan_segment(
    otg: ruckig.Ruckig,
    inp: ruckig.InputParameter,
    traj: ruckig.Trajectory,
    state: tuple[list[float], list[float], list[float]],
    target: tuple[list[float], list[float], list[float]],
    min_duration_s: float,
    t_target_s: float,
    rows: tuple[int, int] | None = None,
) -> bool:
    """One state-to-state Ruckig trajectory into ``traj``; False if the motion is negligible.

    ``rows`` (the 1-based plan rows the motion goes from and to) are named if Ruckig fails.

    An axis whose current state equals the target up to rounding is set exactly to it: with a
    time-synchronised duration, Ruckig would otherwise turn a 1e-15 mismatch into a jerk-limited
    excursion of micrometres.
    """
    cur = [list(x) for x in state]
    for ax in range(3):
        if all(abs(cur[k][ax] - target[k][ax]) < _ROUNDING[k] for k in range(3)):
            for k in range(3):
                cur[k][ax] = target[k][ax]
    inp.current_position, inp.current_velocity, inp.current_acceleration = cur
    inp.target_position, inp.target_velocity, inp.target_acceleration = target
    inp.minimum_duration = min_duration_s if min_duration_s > 0 else None
    res = _calculate(otg, inp, traj)
    if res in _OK:
        return True
    gap = np.abs(np.subtract(state, target)).max()
    if gap < _NEGLIGIBLE_STATE_GAP:
        return False  # already there up to rounding: Ruckig may fail on a zero-length motion
    for shrink in _RETRY_SHRINK:
        inp.target_velocity = [x * (1.0 - shrink) for x in target[1]]
        inp.target_acceleration = [x * (1.0 - shrink) for x in target[2]]
        if _calculate(otg, inp, traj) in _OK:
            return True
    motion = f"the motion from data row {rows[0]} to data row {rows[1]}" if rows else "the motion"
    raise SmoothingError(
        t_target_s,
        np.array(target[0]),
        f"cannot plan {motion} ({min_duration_s:.4g} s at least): {_ruckig_reason(res)}",
    )


def _calculate(otg: ruckig.Ruckig, inp: ruckig.InputParameter, traj: ruckig.Trajectory) -> object:
    """Ruckig's result for ``inp`` (into ``traj``), or the exception it raised instead."""
    try:
        return otg.calculate(inp, traj)
    except (ruckig.RuckigError, ValueError) as exc:  # ValueError: a result the binding cannot name
        return exc


def _ruckig_reason(res: object) -> str:
    """What a failed Ruckig calculation returned or raised, in words, with Ruckig's own code."""
    if isinstance(res, ruckig.Result):
        code = int(res.value)
    else:
        found = re.match(r"\s*(-?\d+) is not a valid Result", str(res))
        if found is None:
            return f"Ruckig failed: {' '.join(str(res).split())}"
        code = int(found.group(1))
    return f"Ruckig reports {_RUCKIG_ERRORS.get(code, 'an unknown error')} (result {code})"


def smooth_waypoints(
    t_s: np.ndarray,
    positions_m: np.ndarray,
    limits: CartesianLimits,
    rate_hz: float,
    lookahead_s: float = DEFAULT_LOOKAHEAD_S,
    rows: np.ndarray | None = None,
) -> CartesianTrajectory:
    """Jerk-limited arm-rate setpoints along a plan's waypoints (Ruckig position interface).

    The EPM starts at rest at the first waypoint at ``t_s[0]`` and ends at rest at the last.
    At each waypoint time the target is updated (streamed, one at a time): the next waypoint --
    its position, and its velocity and acceleration from central differences, clipped to the
    limits -- to be reached exactly at its plan time, if Ruckig can; otherwise the plan's state
    ``lookahead_s`` ahead, to be reached no earlier than its plan time. The trajectory is followed
    until the next waypoint time, then re-targeted from the exact current state. So a feasible
    plan is reproduced (through every waypoint on time), and where it is not (a corner taken at
    speed, a velocity step) the setpoints round it within the limits instead of falling behind
    the plan's clock. After the last waypoint time the final target (rest) is reached.

    Parameters
    ----------
    t_s : array_like (M,)
        Plan times, s, strictly increasing.
    positions_m : array_like (M, 3)
        EPM centre positions (x, y, z) at those times, m.
    limits : CartesianLimits
        Per-axis velocity, acceleration and jerk limits.
    rate_hz : float
        Arm rate, Hz; the output grid is ``t_s[0] + k / rate_hz``.
    lookahead_s : float, optional
        How far ahead on the plan the target is when the next waypoint cannot be reached on time,
        s, >= 0 (0: always the next waypoint). Default 0.2 s.
    rows : array_like of int (M,), optional
        The waypoints' 1-based rows in the plan they were taken from, named if Ruckig fails
        (default 1..M).

    Returns
    -------
    CartesianTrajectory
        Setpoints up to and including the first grid time at which the EPM has stopped at the
        last waypoint.

    Raises
    ------
    ValueError
        Malformed input (the message names the row).
    SmoothingError
        Ruckig failed on a target (names its time and position).
    """
    wall0 = time.perf_counter()
    t, p = _validate_waypoints(t_s, positions_m)
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise ValueError(f"rate_hz: must be a finite number > 0, got {rate_hz}")
    if not (lookahead_s >= 0 and math.isfinite(lookahead_s)):
        raise ValueError(f"lookahead_s: must be a finite number >= 0, got {lookahead_s}")
    v_tgt, a_tgt, clipped = _waypoint_targets(t, p, limits)
    n = t.shape[0]
    row = np.arange(1, n + 1) if rows is None else np.asarray(rows, dtype=int)
    # Index of the target of each waypoint interval: the first waypoint lookahead_s ahead.
    ahead = np.searchsorted(t, t + lookahead_s - 1e-12, side="left")
    ahead = np.clip(np.maximum(ahead, np.arange(n) + 1), 0, n - 1)

    otg = ruckig.Ruckig(3)
    inp = ruckig.InputParameter(3)
    limits.apply(inp)
    traj = ruckig.Trajectory(3)
    sampler = _Sampler(float(t[0]), 1.0 / rate_hz)
    state: tuple[list[float], list[float], list[float]] = (p[0].tolist(), [0.0] * 3, [0.0] * 3)
    tau = float(t[0])  # time of ``state``
    calls = 0
    moving = False
    for j in range(n - 1):
        t_next = float(t[j + 1])
        # The next waypoint if it can be reached on time (a feasible plan is reproduced exactly),
        # else the plan's state lookahead_s ahead (rounds what the limits cannot follow).
        i = j + 1
        target = (p[i].tolist(), v_tgt[i].tolist(), a_tgt[i].tolist())
        moving = _plan_segment(otg, inp, traj, state, target, t_next - tau, t_next, (row[j], row[i]))
        calls += 1
        late = moving and tau + traj.duration > t_next + _ON_TIME_S
        if late and ahead[j] > i:
            i = int(ahead[j])
            target = (p[i].tolist(), v_tgt[i].tolist(), a_tgt[i].tolist())
            moving = _plan_segment(
                otg, inp, traj, state, target, float(t[i]) - tau, float(t[i]), (row[j], row[i])
            )
            calls += 1
        if not moving:
            state = target
            while sampler.next_time() < t_next:
                sampler.append(sampler.next_time(), *state)
        elif j < n - 2:
            sampler.sample(traj, tau, t_next)
            pos, vel, acc = traj.at_time(t_next - tau)
            state = (pos, vel, acc)
        else:  # the last interval targets the final rest state: follow it to the end
            t_end = max(tau + traj.duration, t_next)
            sampler.sample(traj, tau, t_end)
            pos, _vel, _acc = traj.at_time(traj.duration)
            state, t_next = (pos, [0.0] * 3, [0.0] * 3), t_end
        tau = t_next
    # The final state, at rest, at the first grid time not before it. It is where Ruckig's last
    # trajectory ends -- within Ruckig's precision (~1e-8 m) of the last waypoint -- and not the
    # waypoint itself: snapping those nanometres onto the 2 ms grid breaks the jerk limit.
    final = (list(state[0]), [0.0] * 3, [0.0] * 3)
    sampler.append(sampler.next_time(), *final)
    return _trajectory(sampler, t, p, calls, max(tau - float(t[-1]), 0.0), clipped, wall0)


def _trajectory(
    sampler: _Sampler, t: np.ndarray, p: np.ndarray, calls: int, end_lag_s: float, clipped: int, wall0: float
) -> CartesianTrajectory:
    """The sampled setpoints as a :class:`CartesianTrajectory`, with their deviation from the plan
    (``t``, ``p``: the waypoints) and the smoothing's statistics."""
    out_t = np.array(sampler.t)
    out_p = np.array(sampler.p, dtype=float).reshape(-1, 3)
    plan_p = np.column_stack([np.interp(out_t, t, p[:, ax]) for ax in range(3)])
    dev = np.linalg.norm(out_p - plan_p, axis=1)
    stats = SmoothingStats(
        n_waypoints=int(t.shape[0]),
        n_setpoints=int(out_t.shape[0]),
        ruckig_calls=calls,
        max_deviation_m=float(dev.max()),
        rms_deviation_m=float(np.sqrt(np.mean(dev**2))),
        end_lag_s=end_lag_s,
        clipped_targets=clipped,
        wall_s=time.perf_counter() - wall0,
    )
    return CartesianTrajectory(
        t_s=out_t,
        position_m=out_p,
        velocity_mps=np.array(sampler.v, dtype=float).reshape(-1, 3),
        acceleration_mps2=np.array(sampler.a, dtype=float).reshape(-1, 3),
        stats=stats,
    )
