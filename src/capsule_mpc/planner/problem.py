"""The planner's whole-path optimal-control problems, as CasADi NLPs for IPOPT.

Multiple shooting on a uniform grid ``t_k = k dt`` (k = 0..N) with the implicit
Euler step of the controller's model kept as equality constraints,
``X_k - X_{k-1} - dt f(X_k, U_{k-1}) = 0`` (the model is stiff: explicit RK4
at these steps diverges, see :mod:`capsule_mpc.dynamics`), exactly as in the
MPC (:mod:`capsule_mpc.mpc.problem`), whose variable scales and slack layout are
reused. Decision vector (scaled) ``w = (X_0..X_N, U_0..U_{N-1}, S_1..S_N[, sigma_0..sigma_N, T])``.

Constraints, the MPC's: EPM speed per axis (bounds on U), acceleration as the
velocity change per step (``|U_k - U_{k-1}| <= a dt``, from rest), EPM workspace
(bounds on X), coupling ``|lead - lead_eq|^2 <= max_lead^2 (1 + s_0)`` and the
normal-force band ``F_N,min - s_1 <= F_N <= F_N,max + s_1`` with non-negative
slacks penalised linearly (exact penalty). Start: capsule at rest at the path's
start, EPM at start + lead_eq. End: capsule at rest at the path's end and the
EPM standing still.

* ``fixed`` -- the time-parameterised reference at the nominal speed (plus a tail
  at the end point), tracked with the MPC's path-frame cost: cross-track error
  weighted by ``mpc.lateral_tol_m``, along-track by ``mpc.position_tol_m``.
* ``min_time`` -- the final time T is free (``dt = T / N``); a progress variable
  sigma_k (arc length, non-decreasing from 0 to the path length) keeps every
  predicted capsule position within a tube of radius ``tube_m`` around the
  path point ``gamma(sigma_k)`` (the polyline with slightly rounded vertices, the
  tube narrowed to match); the cost is T plus small smoothness and tube-centring
  terms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import casadi as ca
import numpy as np

from ..config import Scenario
from ..dynamics import FN_SCALE, S_SCALE, TANGENT_EPS_MPS, U_SCALE, X_SCALE, CapsuleModel, n_slacks
from ..paths import ReferencePath
from ..plan_options import PlannerOptions

__all__ = [
    "PlanNLP",
    "PlannerOptions",
    "build_fixed_nlp",
    "build_min_time_nlp",
    "path_point_expr",
]

#: Scale of the progress variable sigma (arc length), m: the NLP works in mm.
SIGMA_SCALE = 1e-3


@dataclass(frozen=True)
class PlanNLP:
    """A built whole-path NLP with its bounds, initial guess and layout.

    Attributes
    ----------
    variant : {'fixed', 'min_time'}
        Which problem.
    nlp : dict
        ``{'x', 'f', 'g'}`` CasADi expressions for ``nlpsol``.
    lbw, ubw, lbg, ubg, w0 : numpy.ndarray
        Variable and constraint bounds and the initial guess (scaled).
    n_steps : int
        N.
    dt_s : float
        The step (fixed variant), or the initial guess T0 / N (minimum time), s.
    t_scale_s : float
        The scale of T in the minimum-time problem (its initial guess), s; the fixed-time
        problem's duration.
    lead_eq_m : numpy.ndarray (2,)
        The model's equilibrium lead, m.
    expanded : bool
        Whether the NLP was expanded to SX (possible with the dipole model).
    """

    variant: Literal["fixed", "min_time"]
    nlp: dict
    lbw: np.ndarray
    ubw: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    w0: np.ndarray
    n_steps: int
    dt_s: float
    t_scale_s: float
    lead_eq_m: np.ndarray
    expanded: bool

    def unpack(self, w: np.ndarray) -> dict[str, np.ndarray | float]:
        """Physical ``X (7, N+1)``, ``U (3, N)``, ``S (2, N)``, ``sigma (N+1)`` (m) and ``T`` (s)."""
        n, nx, nu = self.n_steps, len(X_SCALE), len(U_SCALE)
        w = np.asarray(w, dtype=float).ravel()
        i = 0
        xs = w[i : i + nx * (n + 1)].reshape(nx, n + 1, order="F") * X_SCALE[:, None]
        i += nx * (n + 1)
        us = w[i : i + nu * n].reshape(nu, n, order="F") * U_SCALE[:, None]
        i += nu * n
        ss = w[i : i + n_slacks * n].reshape(n_slacks, n, order="F") * S_SCALE[:, None]
        i += n_slacks * n
        out: dict[str, np.ndarray | float] = {"X": xs, "U": us, "S": ss}
        if self.variant == "min_time":
            out["sigma"] = w[i : i + n + 1] * SIGMA_SCALE
            out["T"] = float(w[i + n + 1]) * self.t_scale_s
        else:
            out["T"] = self.n_steps * self.dt_s
        return out


def path_point_expr(path: ReferencePath, sigma_m: ca.SX | ca.MX, smoothing_m: float = 0.0) -> ca.SX | ca.MX:
    """The path point at arc length ``sigma_m`` (m) as a CasADi expression (2,), m.

    The polyline is ``v_0 + sum_i d_i clip(sigma - s_i, 0, l_i)`` (d_i the unit direction,
    s_i the start arc and l_i the length of segment i): exact, and piecewise linear in sigma.
    With ``smoothing_m = delta > 0`` the clip is smooth, ``sp(z) - sp(z - l)`` with
    ``sp(z) = (z + sqrt(z^2 + delta^2)) / 2``: the point then rounds each vertex, at most about
    ``delta / 2`` off the polyline, and its derivatives are continuous (IPOPT converges without
    chattering at the vertices).
    """
    if not smoothing_m >= 0:
        raise ValueError(f"smoothing_m: must be >= 0, got {smoothing_m}")
    verts = path.vertices_m
    seg = np.diff(verts, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])

    def clip(z: ca.SX | ca.MX, length: float) -> ca.SX | ca.MX:
        if smoothing_m == 0:
            return ca.fmin(ca.fmax(z, 0.0), length)
        d2 = smoothing_m**2
        return 0.5 * (ca.sqrt(z**2 + d2) - ca.sqrt((z - length) ** 2 + d2) + length)

    terms = [
        ca.DM(d) * clip(sigma_m - float(s0), float(length))
        for d, s0, length in zip(seg / lengths[:, None], starts, lengths)
    ]
    return ca.DM(verts[0]) + ca.sum2(ca.horzcat(*terms))


def _stage_function(model: CapsuleModel, lead_eq_m: np.ndarray) -> tuple[ca.Function, bool]:
    """One shooting interval: dynamics defect, path constraints and the input change.

    ``(x_prev, x, u, u_prev, s, dt) -> (g_dyn (7, scaled), coupling (1), F_N - s_1 and
    F_N + s_1 (2, in FN_SCALE units), du (3, m/s))``. Expanded to SX when the model allows.
    """
    sc = model.scenario
    x_prev = ca.MX.sym("x_prev", model.n_x)
    x = ca.MX.sym("x", model.n_x)
    u = ca.MX.sym("u", model.n_u)
    u_prev = ca.MX.sym("u_prev", model.n_u)
    s = ca.MX.sym("s", n_slacks)
    dt = ca.MX.sym("dt")
    g_dyn = (x - x_prev - dt * model.ode(x, u)) / X_SCALE
    lead, _force, f_n, _mu = model.outputs(x)
    coupling = ca.sumsqr(lead - ca.DM(lead_eq_m)) / sc.limits.max_lead_m**2 - 1 - s[0]
    fn = ca.vertcat(f_n + s[1], f_n - s[1]) / FN_SCALE
    fn_ = ca.Function(
        "plan_stage",
        [x_prev, x, u, u_prev, s, dt],
        [g_dyn, coupling, fn, u - u_prev],
        ["x_prev", "x", "u", "u_prev", "s", "dt"],
        ["g_dyn", "coupling", "fn", "du"],
    )
    try:
        return fn_.expand(), True
    except RuntimeError:  # a B-spline lookup cannot be expanded to SX
        return fn_, False


def _tracking_function(scenario: Scenario) -> ca.Function:
    """The MPC's path-frame tracking residuals of one stage (fixed-time plan).

    ``(p, v, u, du, ref (4: position, velocity)) -> r``: cross-track error / lateral_tol,
    along-track / position_tol (the whole error where the reference stands still),
    velocity, input feed-forward deviation and input change, each over its tolerance.
    """
    cfg = scenario.mpc
    p, v, ref_p, ref_v = (ca.SX.sym(n, 2) for n in ("p", "v", "ref_p", "ref_v"))
    u, du = ca.SX.sym("u", 3), ca.SX.sym("du", 3)
    err = p - ref_p
    tan = ref_v / ca.sqrt(ca.sumsqr(ref_v) + TANGENT_EPS_MPS**2)
    nrm = ca.vertcat(-tan[1], tan[0])
    still = 1 - ca.sumsqr(tan)
    r = ca.vertcat(
        ca.dot(nrm, err) / cfg.lateral_tol_m,
        ca.dot(tan, err) / cfg.position_tol_m,
        still * err / cfg.position_tol_m,
        (v - ref_v) / cfg.velocity_tol_mps,
        (u[0:2] - ref_v) / cfg.input_tol_mps,
        du / cfg.input_rate_tol_mps,
    )
    return ca.Function("plan_tracking", [p, v, u, du, ref_p, ref_v], [r])


def _initial_state(scenario: Scenario, path: ReferencePath, lead_eq_m: np.ndarray) -> np.ndarray:
    start = path.start_m
    return np.array([*start, 0.0, 0.0, *(start + lead_eq_m), scenario.plate.epm_height_m])


def _bounds(
    scenario: Scenario, path: ReferencePath, lead_eq_m: np.ndarray, n: int, end_tol_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Scaled bounds of ``(X, U, S)``: start state fixed, end at rest in a box, workspace, speed."""
    lim = scenario.limits
    inf = np.inf
    x_lo = np.tile(np.array([-inf, -inf, -inf, -inf, *lim.workspace_min_m])[:, None], (1, n + 1))
    x_hi = np.tile(np.array([inf, inf, inf, inf, *lim.workspace_max_m])[:, None], (1, n + 1))
    x0 = _initial_state(scenario, path, lead_eq_m)
    x_lo[:, 0] = x_hi[:, 0] = x0
    end = path.end_m
    x_lo[0:4, n] = [end[0] - end_tol_m, end[1] - end_tol_m, 0.0, 0.0]
    x_hi[0:4, n] = [end[0] + end_tol_m, end[1] + end_tol_m, 0.0, 0.0]
    speed = lim.speed_mps
    vz = speed if scenario.mpc.height_control else 0.0
    u_lo = np.tile(np.array([-speed, -speed, -vz])[:, None], (1, n))
    u_hi = -u_lo
    u_lo[:, -1] = u_hi[:, -1] = 0.0  # the EPM stands still at the end
    s_lo, s_hi = np.zeros(n_slacks * n), np.full(n_slacks * n, inf)
    lbw = np.concatenate(
        [np.ravel(x_lo / X_SCALE[:, None], order="F"), np.ravel(u_lo / U_SCALE[:, None], order="F"), s_lo]
    )
    ubw = np.concatenate(
        [np.ravel(x_hi / X_SCALE[:, None], order="F"), np.ravel(u_hi / U_SCALE[:, None], order="F"), s_hi]
    )
    return lbw, ubw


def _reference_guess(
    scenario: Scenario, path: ReferencePath, lead_eq_m: np.ndarray, t_s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A feasible-looking guess: the capsule on the reference, the EPM at its equilibrium lead."""
    pos = path.position(t_s)
    vel = path.velocity(t_s)
    xs = np.vstack([pos.T, vel.T, (pos + lead_eq_m).T, np.full(len(t_s), scenario.plate.epm_height_m)])
    xs[:, 0] = _initial_state(scenario, path, lead_eq_m)
    xs[2:4, -1] = 0.0
    us = np.vstack([np.diff(xs[4:7], axis=1) / np.diff(t_s)])
    return xs, us


def _pack(xs: np.ndarray, us: np.ndarray, ss: np.ndarray) -> np.ndarray:
    return np.concatenate(
        [
            np.ravel(xs / X_SCALE[:, None], order="F"),
            np.ravel(us / U_SCALE[:, None], order="F"),
            np.ravel(ss / S_SCALE[:, None], order="F"),
        ]
    )


def _symbols(n: int, nx: int, nu: int, extra: int) -> tuple[ca.MX, ca.MX, ca.MX, ca.MX, ca.MX]:
    """The decision vector and its physical views ``X (nx, N+1)``, ``U``, ``S`` and the rest."""
    n_w = nx * (n + 1) + (nu + n_slacks) * n + extra
    w = ca.MX.sym("w", n_w)
    i = nx * (n + 1)
    xs = ca.diag(ca.DM(X_SCALE)) @ ca.reshape(w[0:i], nx, n + 1)
    us = ca.diag(ca.DM(U_SCALE)) @ ca.reshape(w[i : i + nu * n], nu, n)
    i += nu * n
    ss = ca.diag(ca.DM(S_SCALE)) @ ca.reshape(w[i : i + n_slacks * n], n_slacks, n)
    return w, xs, us, ss, w[i + n_slacks * n :]


def _stage_constraints(
    stage: ca.Function, xs: ca.MX, us: ca.MX, ss: ca.MX, dt: ca.MX | float, n: int
) -> tuple[ca.MX, ca.MX, ca.MX, ca.MX, ca.MX]:
    """Mapped stage outputs for all N intervals (U_{-1} = 0: the EPM starts at rest)."""
    u_prev = ca.horzcat(ca.DM.zeros(us.shape[0], 1), us[:, : n - 1])
    dts = ca.repmat(dt, 1, n) if isinstance(dt, ca.MX) else ca.DM.ones(1, n) * dt
    g_dyn, coupling, fn, du = stage.map(n)(xs[:, :n], xs[:, 1:], us, u_prev, ss, dts)
    return g_dyn, coupling, fn, du, u_prev


def _slack_penalty(scenario: Scenario, ss: ca.MX, n: int) -> ca.MX:
    return scenario.mpc.slack_weight * ca.sum1(ca.vec(ss) / np.tile(S_SCALE, n))


def build_fixed_nlp(
    model: CapsuleModel,
    path: ReferencePath,
    lead_eq_m: np.ndarray,
    dt_s: float,
    options: PlannerOptions,
) -> PlanNLP:
    """The fixed-time NLP: track ``path`` at its nominal speed, then stop at its end.

    Parameters
    ----------
    model : CapsuleModel
        The controller's model (never the plant).
    path : ReferencePath
        The reference at its nominal speed.
    lead_eq_m : numpy.ndarray (2,)
        The model's equilibrium lead, m.
    dt_s : float
        Step, s (the camera period).
    options : PlannerOptions
        ``tail_s`` and ``end_tol_m`` are used.
    """
    sc = model.scenario
    lim = sc.limits
    n = math.ceil((path.duration_s + options.tail_s) / dt_s - 1e-9)
    nx, nu = model.n_x, model.n_u
    t = dt_s * np.arange(n + 1)
    stage, expanded = _stage_function(model, lead_eq_m)
    w, xs, us, ss, _ = _symbols(n, nx, nu, 0)
    g_dyn, coupling, fn, du, _ = _stage_constraints(stage, xs, us, ss, dt_s, n)
    ref_p, ref_v = ca.DM(path.position(t[1:]).T), ca.DM(path.velocity(t[1:]).T)
    res = _tracking_function(sc).map(n)(xs[0:2, 1:], xs[2:4, 1:], us, du, ref_p, ref_v)
    f = 0.5 * ca.sumsqr(res) + _slack_penalty(sc, ss, n)
    g = ca.vertcat(ca.vec(g_dyn), ca.vec(coupling), ca.vec(fn), ca.vec(du) / U_SCALE[0])
    da = lim.accel_mps2 * dt_s / U_SCALE[0]
    lbg = np.concatenate(
        [
            np.zeros(nx * n),
            np.full(n, -np.inf),
            np.tile([lim.normal_force_min_n / FN_SCALE, -np.inf], n),
            np.full(nu * n, -da),
        ]
    )
    ubg = np.concatenate(
        [
            np.zeros(nx * n),
            np.zeros(n),
            np.tile([np.inf, lim.normal_force_max_n / FN_SCALE], n),
            np.full(nu * n, da),
        ]
    )
    lbw, ubw = _bounds(sc, path, lead_eq_m, n, options.end_tol_m)
    x_guess, u_guess = _reference_guess(sc, path, lead_eq_m, t)
    w0 = np.clip(_pack(x_guess, u_guess, np.zeros((n_slacks, n))), lbw, ubw)
    return PlanNLP(
        "fixed",
        {"x": w, "f": f, "g": g},
        lbw,
        ubw,
        lbg,
        ubg,
        w0,
        n,
        dt_s,
        path.duration_s,
        np.asarray(lead_eq_m, dtype=float),
        expanded,
    )


def build_min_time_nlp(
    model: CapsuleModel,
    path: ReferencePath,
    lead_eq_m: np.ndarray,
    options: PlannerOptions,
) -> PlanNLP:
    """The minimum-time NLP: free T, capsule within ``options.tube_m`` of the path, stop at its end.

    Parameters
    ----------
    model : CapsuleModel
        The controller's model.
    path : ReferencePath
        The path (its nominal speed plays no part: the guess of T is the length over
        ``min_time_guess_speed_fraction * limits.speed_mps``, and N = ceil(T0 / min_time_dt_s)).
    lead_eq_m : numpy.ndarray (2,)
        The model's equilibrium lead, m.
    options : PlannerOptions
        The ``min_time_*``, ``tube_*``, ``path_smoothing_m``, ``time_weight`` and ``end_tol_m``
        settings are used.
    """
    sc = model.scenario
    lim = sc.limits
    t0 = path.length_m / (options.min_time_guess_speed_fraction * lim.speed_mps)
    n = max(2, math.ceil(t0 / options.min_time_dt_s - 1e-9))
    nx, nu = model.n_x, model.n_u
    stage, expanded = _stage_function(model, lead_eq_m)
    w, xs, us, ss, rest = _symbols(n, nx, nu, n + 2)
    sigma = rest[0 : n + 1] * SIGMA_SCALE
    dt = rest[n + 1] * t0 / n
    g_dyn, coupling, fn, du, _ = _stage_constraints(stage, xs, us, ss, dt, n)
    s_sym = ca.SX.sym("sigma")
    smoothing = options.path_smoothing_m
    gamma = ca.Function("path_point", [s_sym], [path_point_expr(path, s_sym, smoothing)]).map(n)
    # The smoothed path rounds the vertices by up to smoothing / 2: the tube is narrowed by it.
    tube = ca.sum1((xs[0:2, 1:] - gamma(sigma[1:].T)) ** 2) / (options.tube_m - smoothing / 2) ** 2
    da = lim.accel_mps2 * dt
    acc = ca.vertcat(ca.vec(du) - da, ca.vec(du) + da) / U_SCALE[0]
    progress = (sigma[1:] - sigma[:-1]) / SIGMA_SCALE
    smooth = ca.vec(du) / sc.mpc.input_rate_tol_mps
    f = (
        options.time_weight * rest[n + 1]
        + 0.5 * ca.sumsqr(smooth)
        + 0.5 * options.tube_centering_weight * ca.sum2(tube)
        + _slack_penalty(sc, ss, n)
    )
    g = ca.vertcat(ca.vec(g_dyn), ca.vec(coupling), ca.vec(fn), acc, ca.vec(tube), progress)
    lbg = np.concatenate(
        [
            np.zeros(nx * n),
            np.full(n, -np.inf),
            np.tile([lim.normal_force_min_n / FN_SCALE, -np.inf], n),
            np.full(nu * n, -np.inf),
            np.zeros(nu * n),
            np.full(n, -np.inf),
            np.zeros(n),
        ]
    )
    ubg = np.concatenate(
        [
            np.zeros(nx * n),
            np.zeros(n),
            np.tile([np.inf, lim.normal_force_max_n / FN_SCALE], n),
            np.zeros(nu * n),
            np.full(nu * n, np.inf),
            np.ones(n),
            np.full(n, np.inf),
        ]
    )
    lbw, ubw = _bounds(sc, path, lead_eq_m, n, options.end_tol_m)
    s_lo = np.zeros(n + 1)
    s_hi = np.full(n + 1, path.length_m / SIGMA_SCALE)
    s_hi[0] = 0.0
    s_lo[-1] = s_hi[-1]
    lbw = np.concatenate([lbw, s_lo, [1e-3]])
    ubw = np.concatenate([ubw, s_hi, [np.inf]])
    t_guess = np.linspace(0.0, t0, n + 1)
    x_guess, u_guess = _reference_guess(sc, path.with_speed(path.length_m / t0), lead_eq_m, t_guess)
    arc = np.linspace(0.0, path.length_m, n + 1)
    w0 = np.concatenate([_pack(x_guess, u_guess, np.zeros((n_slacks, n))), arc / SIGMA_SCALE, [1.0]])
    w0 = np.clip(w0, lbw, ubw)
    return PlanNLP(
        "min_time",
        {"x": w, "f": f, "g": g},
        lbw,
        ubw,
        lbg,
        ubg,
        w0,
        n,
        t0 / n,
        t0,
        np.asarray(lead_eq_m, dtype=float),
        expanded,
    )
