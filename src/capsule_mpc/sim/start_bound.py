"""The earliest a capsule at rest can break loose at the start: the arm-limited bound of a draw.

At t = 0 the capsule rests where the start left it, its friction healed; the EPM rests at its start.
The bound is the time the EPM needs, from rest and within ``limits.jerk_mps3``,
``limits.accel_mps2`` and ``limits.speed_mps`` (per axis, along the path's first direction), to
reach the first lead at which the plant's lateral force passes its breakaway friction plus the
tether drag (:meth:`~capsule_mpc.sim.plant.CapsulePlant.holding_ratio` reaches 1). It is computed
from the plant's truth, for scoring: no controller is given it. The arm's servo lag and the
camera's latency come on top of it, so no controller reaches it exactly.
"""

from __future__ import annotations

import math

import numpy as np
import ruckig
from scipy.optimize import brentq

from ..config import Scenario
from .plant import CapsulePlant

__all__ = ["breakaway_bound_s", "breakaway_distance_m"]

#: Step of the scan for the first lead that breaks the capsule loose, m.
_SCAN_M = 2e-4


def breakaway_distance_m(
    plant: CapsulePlant, epm_m: np.ndarray, capsule_m: np.ndarray, theta_s: float, direction: np.ndarray
) -> float:
    """How far the EPM must move along ``direction`` (unit, 2) from ``epm_m`` for the capsule resting
    at ``capsule_m`` with friction state ``theta_s`` to break loose, m; inf if it does not within
    the coupling limit."""
    height = float(epm_m[2])
    lead0 = np.asarray(epm_m[:2], dtype=float) - np.asarray(capsule_m, dtype=float)
    where = (float(capsule_m[0]), float(capsule_m[1]))

    def excess(s: float) -> float:
        lead = lead0 + s * direction
        return plant.holding_ratio(float(lead[0]), float(lead[1]), height, theta_s, where) - 1.0

    if excess(0.0) >= 0:
        return 0.0
    limit = plant.scenario.sim.decouple_lead_m
    s = 0.0
    while s < limit:  # the first crossing: the ratio need not be monotone over the whole range
        nxt = s + _SCAN_M
        if math.isfinite(excess(nxt)) and excess(nxt) >= 0:
            return float(brentq(excess, s, nxt, xtol=1e-7))
        s = nxt
    return math.inf


def _time_to_cover_s(scenario: Scenario, distance_m: float) -> float:
    """The least time one axis needs from rest to cover ``distance_m`` within the limits, s:
    Ruckig's velocity control to the speed limit (the fastest run-up), cruising beyond it."""
    lim = scenario.limits
    inp = ruckig.InputParameter(1)
    inp.control_interface = ruckig.ControlInterface.Velocity
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_velocity, inp.target_acceleration = [lim.speed_mps], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [lim.speed_mps], [lim.accel_mps2], [lim.jerk_mps3]
    traj = ruckig.Trajectory(1)
    ruckig.Ruckig(1).calculate(inp, traj)
    run_up = float(traj.at_time(traj.duration)[0][0])
    if distance_m >= run_up:
        return traj.duration + (distance_m - run_up) / lim.speed_mps
    return float(brentq(lambda t: traj.at_time(t)[0][0] - distance_m, 0.0, traj.duration, xtol=1e-6))


def breakaway_bound_s(
    plant: CapsulePlant, epm_m: np.ndarray, capsule_m: np.ndarray, theta_s: float, direction: np.ndarray
) -> float:
    """The arm-limited bound (module docstring), s; inf if the capsule cannot break loose along
    ``direction`` within the coupling limit."""
    distance = breakaway_distance_m(plant, epm_m, capsule_m, theta_s, direction)
    return _time_to_cover_s(plant.scenario, distance) if math.isfinite(distance) else math.inf
