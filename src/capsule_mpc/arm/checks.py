"""Checks of an EPM plan before the arm is asked to follow it, and of the arm trajectory before it is written.

An exported trajectory is what a user sends to a real arm, so both ends are checked and a failure
stops the export before any file is written.

Every row of the plan (:func:`check_epm_plan`, before anything is computed), first failure wins,
named by its 1-based data row (the first row after a CSV header is 1) and field:

* at least two rows; every value finite;
* ``t_s`` strictly increasing (no duplicate time), and no row more than
  :data:`capsule_mpc.budget.MAX_SIM_TIME_S` after the first (the arm's smoother plans each
  step between rows as one motion, which cannot last much longer);
* each step between consecutive rows within the per-axis speed limit at that time step
  (|dp| <= v_max dt, plus :data:`ROUNDING_M`): no arm can be faster;
* each change of the plan's speed within the acceleration limit, the plan's rows allowed
  ``max_deviation_m`` of slack (the arm starts at rest at the first row): with less slack no
  trajectory within the limits passes within that tolerance of the rows (:func:`_accel_bound`);
* every position inside the EPM workspace box ``limits.workspace_min_m`` .. ``workspace_max_m``.

The arm trajectory (:func:`verify_arm_trajectory`, after smoothing and IK, before writing):

* forward kinematics of the joint positions (an independent model) within the IK tolerances
  (``arm.ik_position_tolerance_m``, ``arm.ik_orientation_tolerance_rad``) of the setpoints;
* joint positions within the enforced limits, joint velocities within the allowed ones;
* Cartesian setpoint velocities, accelerations and jerks within the arm's limits;
* the EPM (forward kinematics) inside the workspace box;
* the EPM within ``max_deviation_m`` of the plan (linearly interpolated at the same time; the
  last row held after the plan ends).

The tolerance ``max_deviation_m`` defaults to :data:`PLAN_DEVIATION_FRACTION` of the coupling
limit ``limits.max_lead_m`` (5 mm by default): a deviation of the EPM from its plan adds directly
to the lead error that limit bounds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from ..budget import MAX_SIM_TIME_S
from ..config import Scenario
from .errors import EPMTrajectoryError, ExportCheckError
from .kinematics import ArmKinematics, JointTrajectory
from .smoothing import CartesianLimits, CartesianTrajectory

__all__ = [
    "PLAN_DEVIATION_FRACTION",
    "PLAN_FIELDS",
    "ROUNDING_M",
    "ExportCheck",
    "check_epm_plan",
    "default_max_deviation_m",
    "verify_arm_trajectory",
]

#: Column names of a plan row, in the order of (t, x, y, z); errors name these.
PLAN_FIELDS = ("t_s", "epm_x_m", "epm_y_m", "epm_z_m")
#: Default tolerance on the EPM's deviation from the plan, as a fraction of ``limits.max_lead_m``
#: (0.2 x 25 mm = 5 mm). The arm may use a fifth of the coupling budget. Measured deviations of
#: plans the arm follows (``configs/rectangle.yaml``, ideal plant): the planner's plan 1.0 mm (its
#: first frame starts at 12 mm/s, the arm at rest), ``simulate`` logs at 0.02 m/s 0.9 mm (follow)
#: and 1.5 mm (mpc), the notebook's follow plan with velocity steps at the corners 1.2 mm; at
#: 0.05-0.06 m/s, where the simulated EPM (not jerk-limited) runs at the speed limit, 6.6-7.7 mm.
PLAN_DEVIATION_FRACTION = 0.2
#: Positions this far beyond a limit are rounding, not motion, m: the planner's constraint
#: tolerance, Ruckig's precision (~1e-8 m), text round trips.
ROUNDING_M = 1e-6
#: Relative rounding of Ruckig's analytic velocities and accelerations against their limits.
_LIMIT_ROUNDING = 1e-9
#: Relative rounding of a jerk computed from consecutive setpoint accelerations (their times are
#: sums of the arm period: a few ulps of the tick).
_JERK_ROUNDING = 1e-6
#: Absolute rounding of the forward-kinematics check against the IK tolerances (m, rad).
_FK_ROUNDING = 1e-12


def default_max_deviation_m(scenario: Scenario) -> float:
    """The default tolerance on the EPM's deviation from a plan, m: :data:`PLAN_DEVIATION_FRACTION`
    of ``limits.max_lead_m``."""
    return PLAN_DEVIATION_FRACTION * scenario.limits.max_lead_m


@dataclass(frozen=True, order=True)
class _Failure:
    """The first failing row of one check (ordered by row, then by the check's priority)."""

    index: int
    priority: int
    axis: int
    reason: str


def _first(mask: npt.ArrayLike) -> int | None:
    """Index of the first True of a 1-D mask, or None."""
    hits = np.flatnonzero(np.asarray(mask))
    return int(hits[0]) if hits.size else None


def _finite_failure(t: np.ndarray, p: np.ndarray) -> _Failure | None:
    values = np.column_stack([t, p])
    k = _first(~np.all(np.isfinite(values), axis=1))
    if k is None:
        return None
    col = int(np.argmax(~np.isfinite(values[k])))
    return _Failure(k, 0, col, f"must be a finite number, got {values[k, col]}")


def _time_failure(t: np.ndarray) -> _Failure | None:
    k = _first(np.diff(t) <= 0)
    if k is None:
        return None
    k += 1
    kind = "a duplicate time" if t[k] == t[k - 1] else "an earlier time"
    return _Failure(
        k,
        1,
        0,
        f"must be > {t[k - 1]:g} s of data row {k} (times strictly increasing), got {t[k]:g} ({kind})",
    )


def _span_failure(t: np.ndarray) -> _Failure | None:
    with np.errstate(invalid="ignore"):
        k = _first(t - t[0] > MAX_SIM_TIME_S)
    if k is None:
        return None
    return _Failure(
        k,
        1,
        0,
        f"is {t[k] - t[0]:.3g} s after data row 1 (t_s = {t[0]:g}); a plan spans at most "
        f"{MAX_SIM_TIME_S:g} s (capsule_mpc.budget.MAX_SIM_TIME_S)",
    )


def _speed_failure(t: np.ndarray, p: np.ndarray, v_max: np.ndarray) -> _Failure | None:
    dt = np.diff(t)[:, None]
    dp = np.diff(p, axis=0)
    over = np.abs(dp) > v_max * dt + ROUNDING_M
    k = _first(over.any(axis=1))
    if k is None:
        return None
    ax = int(np.argmax(over[k]))
    step, h = dp[k, ax], dt[k, 0]
    return _Failure(
        k + 1,
        2,
        ax + 1,
        f"moves {step * 1e3:+.2f} mm from data row {k + 1} in {h * 1e3:.1f} ms ({step / h:+.3f} m/s); "
        f"the arm may move at most {v_max[ax] * h * 1e3:.2f} mm in that time (per-axis speed limit "
        f"{v_max[ax]:g} m/s)",
    )


def _accel_bound(
    dt_before: np.ndarray, dt_after: np.ndarray, a_max: np.ndarray, tolerance_m: float
) -> np.ndarray:
    """Largest change of the mean speed between two consecutive intervals of a plan that a
    trajectory within the acceleration limit can show while passing within ``tolerance_m`` of the
    rows, m/s.

    Within |a| <= a_max the mean speeds of two adjacent intervals differ by at most
    a_max (dt_before + dt_after) / 2, and moving each row by up to ``tolerance_m`` changes an
    interval's mean speed by up to 2 tolerance / dt. Columns: axes; rows: the row between the
    intervals.
    """
    return a_max * (dt_before + dt_after) / 2 + 2 * tolerance_m / dt_before + 2 * tolerance_m / dt_after


def _accel_failure(t: np.ndarray, p: np.ndarray, a_max: np.ndarray, tolerance_m: float) -> _Failure | None:
    dt = np.diff(t)[:, None]
    v = np.diff(p, axis=0) / dt
    # From rest at the first row (which the arm starts at exactly): the mean speed over the first
    # interval is at most a_max dt / 2, the second row may be off by the tolerance.
    first = (np.abs(v[0]) > a_max * dt[0] / 2 + tolerance_m / dt[0]) & (dt[0] > 0)
    failures = []
    if first.any():
        ax = int(np.argmax(first))
        step, h = p[1, ax] - p[0, ax], dt[0, 0]
        reach = a_max[ax] * h**2 / 2 + tolerance_m
        failures.append(
            _Failure(
                1,
                3,
                ax + 1,
                f"moves {step * 1e3:+.2f} mm from data row 1 in {h * 1e3:.1f} ms; starting at rest there, "
                f"the arm can move at most {reach * 1e3:.2f} mm (acceleration limit {a_max[ax]:g} m/s^2 "
                f"and the {tolerance_m * 1e3:.1f} mm tolerance on the plan)",
            )
        )
    if v.shape[0] >= 2:
        bound = _accel_bound(dt[:-1], dt[1:], a_max, tolerance_m)
        over = (np.abs(np.diff(v, axis=0)) > bound) & (dt[:-1] > 0) & (dt[1:] > 0)
        k = _first(over.any(axis=1))
        if k is not None:
            ax = int(np.argmax(over[k]))
            failures.append(
                _Failure(
                    k + 2,
                    3,
                    ax + 1,
                    f"reaching it needs the plan's speed to change from {v[k, ax]:+.4f} m/s (data rows "
                    f"{k + 1} -> {k + 2}) to {v[k + 1, ax]:+.4f} m/s (data rows {k + 2} -> {k + 3}); the "
                    f"arm can change it by at most {bound[k, ax]:.4f} m/s there (acceleration limit "
                    f"{a_max[ax]:g} m/s^2 and the {tolerance_m * 1e3:.1f} mm tolerance on the plan)",
                )
            )
    return min(failures) if failures else None


def _workspace_failure(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> _Failure | None:
    out = (p < lo - ROUNDING_M) | (p > hi + ROUNDING_M)
    k = _first(out.any(axis=1))
    if k is None:
        return None
    ax = int(np.argmax(out[k]))
    return _Failure(
        k,
        4,
        ax + 1,
        f"must be in the EPM workspace [{lo[ax]:g}, {hi[ax]:g}] m (limits.workspace_min_m[{ax}] .. "
        f"limits.workspace_max_m[{ax}]), got {p[k, ax]:g}",
    )


def _workspace(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    lim = scenario.limits
    return np.asarray(lim.workspace_min_m, dtype=float), np.asarray(lim.workspace_max_m, dtype=float)


def check_epm_plan(
    scenario: Scenario, t_s: np.ndarray, positions_m: np.ndarray, max_deviation_m: float
) -> None:
    """Refuse a plan with a row the arm must not be sent (see the module docstring for the checks).

    Parameters
    ----------
    scenario : Scenario
        ``limits`` (workspace) and ``arm`` (per-axis speed and acceleration limits).
    t_s : array_like (N,)
        Plan times, s.
    positions_m : array_like (N, 3)
        EPM centre (x, y, z) in the world, m.
    max_deviation_m : float
        Tolerance on the EPM's deviation from the plan, m (slack of the acceleration check).

    Raises
    ------
    EPMTrajectoryError
        At the first failing row (1-based data row and field named, with the allowed range), or
        for fewer than two rows or mismatched shapes.
    """
    t = np.asarray(t_s, dtype=float)
    p = np.asarray(positions_m, dtype=float)
    if t.ndim != 1 or p.shape != (t.shape[0], 3):
        raise EPMTrajectoryError(
            f"positions: must have shape ({t.shape[0]}, 3) to match the times, got {p.shape}"
        )
    if t.shape[0] < 2:
        got = "no data rows" if t.shape[0] == 0 else "1 data row"
        raise EPMTrajectoryError(f"the plan needs at least 2 data rows (a start and an end), got {got}")
    limits = CartesianLimits.from_scenario(scenario)
    # Non-finite values and zero time steps are reported by the first two checks; the later ones
    # must not warn about them on the way.
    with np.errstate(divide="ignore", invalid="ignore"):
        failures = [
            _finite_failure(t, p),
            _time_failure(t),
            _span_failure(t),
            _speed_failure(t, p, limits.velocity_mps),
            _accel_failure(t, p, limits.acceleration_mps2, max_deviation_m),
            _workspace_failure(p, *_workspace(scenario)),
        ]
    found = [f for f in failures if f is not None]
    if not found:
        return
    first = min(found)
    k = first.index
    raise EPMTrajectoryError(
        first.reason, row=k + 1, field=PLAN_FIELDS[first.axis], t_s=float(t[k]), position_m=p[k]
    )


@dataclass(frozen=True)
class ExportCheck:
    """What :func:`verify_arm_trajectory` measured (all within their tolerances when returned).

    Attributes
    ----------
    max_deviation_m : float
        Worst distance of the EPM (forward kinematics) from the plan at the same time, m.
    tolerance_m : float
        The tolerance it was checked against, m.
    max_fk_error_m : float
        Worst distance between the forward kinematics and the setpoints, m.
    max_fk_orientation_error_rad : float
        Worst orientation error of the EPM frame, rad.
    min_workspace_margin_m : float
        Smallest distance of the EPM inside a workspace face, m (negative: outside by rounding).
    """

    max_deviation_m: float
    tolerance_m: float
    max_fk_error_m: float
    max_fk_orientation_error_rad: float
    min_workspace_margin_m: float


def _forward_kinematics(kin: ArmKinematics, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """EPM positions (N, 3) and orientation errors (N,) of joint positions q (N, 6), from a fresh
    model and data (independent of the IK's)."""
    model = pin.Model(kin.model)
    data = model.createData()
    positions = np.empty((q.shape[0], 3))
    rot_err = np.empty(q.shape[0])
    for k in range(q.shape[0]):
        pin.forwardKinematics(model, data, q[k])
        placement = pin.updateFramePlacement(model, data, kin.frame_id)
        positions[k] = placement.translation
        rot_err[k] = np.linalg.norm(pin.log3(kin.epm_rotation @ placement.rotation.T))
    return positions, rot_err


def _between_rows(t_plan: np.ndarray, t: float) -> str:
    """Which plan rows (1-based) a time falls between."""
    n = t_plan.shape[0]
    i = int(np.searchsorted(t_plan, t, side="right"))
    if i >= n:
        return f"after the last data row {n} (t_s = {t_plan[-1]:g})"
    if i == 0:
        return f"before data row 1 (t_s = {t_plan[0]:g})"
    return f"between data rows {i} and {i + 1} (t_s = {t_plan[i - 1]:g} .. {t_plan[i]:g})"


def _cartesian_checks(
    cart: CartesianTrajectory, limits: CartesianLimits
) -> list[tuple[np.ndarray, Callable[[int], str]]]:
    """The setpoints' per-axis velocity, acceleration and jerk against the arm's Cartesian limits:
    (rows over a limit, the message of a row)."""
    t = cart.t_s
    v_over = np.abs(cart.velocity_mps) > limits.velocity_mps * (1 + _LIMIT_ROUNDING)
    a_over = np.abs(cart.acceleration_mps2) > limits.acceleration_mps2 * (1 + _LIMIT_ROUNDING)
    # Jerk between consecutive setpoints (Ruckig keeps it within the limit on its uniform grid).
    jerk = np.zeros_like(cart.acceleration_mps2)
    if t.shape[0] > 1:
        jerk[1:] = np.diff(cart.acceleration_mps2, axis=0) / np.diff(t)[:, None]
    j_over = np.abs(jerk) > limits.jerk_mps3 * (1 + _JERK_ROUNDING)
    return [
        (
            v_over.any(axis=1),
            lambda k: (
                f"setpoint velocity {cart.velocity_mps[k].round(5).tolist()} m/s beyond the per-axis "
                f"limit {limits.velocity_mps.tolist()} m/s"
            ),
        ),
        (
            a_over.any(axis=1),
            lambda k: (
                f"setpoint acceleration {cart.acceleration_mps2[k].round(4).tolist()} m/s^2 beyond the "
                f"per-axis limit {limits.acceleration_mps2.tolist()} m/s^2"
            ),
        ),
        (
            j_over.any(axis=1),
            lambda k: (
                f"setpoint jerk {jerk[k].round(3).tolist()} m/s^3 beyond the per-axis limit "
                f"{limits.jerk_mps3.tolist()} m/s^3"
            ),
        ),
    ]


def verify_arm_trajectory(
    scenario: Scenario,
    kin: ArmKinematics,
    t_plan: np.ndarray,
    p_plan: np.ndarray,
    cart: CartesianTrajectory,
    joints: JointTrajectory,
    max_deviation_m: float,
) -> ExportCheck:
    """Check the arm trajectory against the plan and every limit before it is written.

    Parameters
    ----------
    scenario : Scenario
        ``limits`` (workspace), ``arm`` (Cartesian limits, IK tolerances).
    kin : ArmKinematics
        The arm (its model is copied: the check does not share the IK's data).
    t_plan, p_plan : numpy.ndarray (M,), (M, 3)
        The plan (every row, not only those smoothed), s and m.
    cart : CartesianTrajectory
        The setpoints at the arm rate.
    joints : JointTrajectory
        The joint commands for them.
    max_deviation_m : float
        Tolerance on the EPM's distance from the plan, m.

    Returns
    -------
    ExportCheck
        The figures measured.

    Raises
    ------
    ExportCheckError
        At the first time a check fails (time, EPM position, the check, the value and its
        tolerance named).
    """
    arm = scenario.arm
    t, q, dq, sp = cart.t_s, joints.q_rad, joints.dq_radps, cart.position_m
    values = np.column_stack([q, dq, sp, cart.velocity_mps, cart.acceleration_mps2])
    k = _first(~np.all(np.isfinite(values), axis=1))
    if k is not None:
        raise ExportCheckError(t[k], sp[k], "a setpoint or joint command is not finite")
    fk, rot_err = _forward_kinematics(kin, q)
    fk_err = np.linalg.norm(fk - sp, axis=1)
    lo, hi = _workspace(scenario)
    margin = np.minimum(fk - lo, hi - fk).min(axis=1)
    plan_at_t = np.column_stack([np.interp(t, t_plan, p_plan[:, ax]) for ax in range(3)])
    deviation = np.linalg.norm(fk - plan_at_t, axis=1)
    checks = (
        (
            fk_err > arm.ik_position_tolerance_m + _FK_ROUNDING,
            lambda k: (
                f"forward kinematics of the joint positions is {fk_err[k]:.3g} m from the setpoint, "
                f"beyond the IK tolerance arm.ik_position_tolerance_m = {arm.ik_position_tolerance_m:g} m"
            ),
        ),
        (
            rot_err > arm.ik_orientation_tolerance_rad + _FK_ROUNDING,
            lambda k: (
                f"the EPM orientation is {rot_err[k]:.3g} rad off, beyond the IK tolerance "
                f"arm.ik_orientation_tolerance_rad = {arm.ik_orientation_tolerance_rad:g} rad"
            ),
        ),
        (
            np.any((q < kin.lower_rad) | (q > kin.upper_rad), axis=1),
            lambda k: str(kin.limit_violation(q[k])),
        ),
        (
            np.any(np.abs(dq) > kin.velocity_limit_radps, axis=1),
            lambda k: str(kin.velocity_violation(dq[k])),
        ),
        *_cartesian_checks(cart, CartesianLimits.from_scenario(scenario)),
        (
            margin < -ROUNDING_M,
            lambda k: (
                f"the EPM would be {-margin[k] * 1e3:.3f} mm outside the workspace "
                f"[{lo.tolist()}, {hi.tolist()}] m (limits.workspace_min_m, workspace_max_m), "
                f"{_between_rows(t_plan, float(t[k]))} of the plan"
            ),
        ),
        (
            deviation > max_deviation_m,
            lambda k: (
                f"the EPM would be {deviation[k] * 1e3:.2f} mm from the plan, "
                f"{_between_rows(t_plan, float(t[k]))}, and up to {deviation.max() * 1e3:.2f} mm at t = "
                f"{t[np.argmax(deviation)]:.4f} s; the tolerance is {max_deviation_m * 1e3:.2f} mm: the plan "
                "asks for more than the arm's speed, acceleration and jerk limits allow there"
            ),
        ),
    )
    for mask, reason in checks:
        k = _first(mask)
        if k is not None:
            raise ExportCheckError(t[k], fk[k], reason(k))
    return ExportCheck(
        max_deviation_m=float(deviation.max()),
        tolerance_m=float(max_deviation_m),
        max_fk_error_m=float(fk_err.max()),
        max_fk_orientation_error_rad=float(rot_err.max()),
        min_workspace_margin_m=float(margin.min()),
    )
