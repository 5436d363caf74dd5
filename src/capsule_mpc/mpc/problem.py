"""The MPC's optimal-control problem, built once as a parametric CasADi NLP.

Decision variables ``w = (X_1..X_N, U_0..U_{N-1}, S_0..S_{N-1})``: predicted
states (7 each), EPM velocities (3 each) and two non-negative slacks per stage
(coupling, normal force). Parameters ``p = (x_0, ref, u_prev, d)``: the
estimated current state, the reference window (capsule position and velocity at
stages 1..N, and the EPM velocity feed-forward for inputs 0..N-1: the path's
velocity, or an offline plan's EPM velocity), the command being applied, and the estimated force disturbance
``d = (d_x, d_y, d_fric)``: a constant force (N) plus an extra friction force
(N) that opposes the capsule's motion -- the model's friction is the part of the
mismatch that turns with the motion, so it must not be a fixed vector.

Dynamics: implicit Euler kept as equality constraints,
``X_k - X_{k-1} - dt (f(X_k, U_{k-1}) + d/m) = 0`` (the model is stiff; see
:mod:`capsule_mpc.dynamics`). The objective is a sum of squares ``0.5 |R(w, p)|^2``
plus a linear slack penalty, so its Gauss-Newton Hessian ``J_R^T J_R`` is
exact for the objective and cheap; it is passed to the SQP solver as ``hess_lag``.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..config import Scenario
from ..dynamics import CapsuleModel

__all__ = ["N_DIST", "N_REF", "OCP", "TANGENT_EPS_MPS", "build_ocp", "n_slacks"]

#: Slacks per stage: coupling (lead), normal force (both bounds).
n_slacks = 2
#: Speed below which the reference counts as standing still, m/s (smooths the path frame).
TANGENT_EPS_MPS = 1e-4
#: Reference rows per stage: capsule position (2), capsule velocity (2), EPM velocity feed-forward (2).
N_REF = 6
#: Disturbance parameters: constant force (x, y) and extra friction magnitude, N.
N_DIST = 3
#: Variable scales: the NLP works in mm, cm/s and unit-order slacks, so the QP (an active-set
#: method) sees a well-conditioned problem. Physical value = scale * NLP value.
X_SCALE = np.array([1e-3, 1e-3, 1e-2, 1e-2, 1e-3, 1e-3, 1e-3])
U_SCALE = np.array([1e-2, 1e-2, 1e-2])
#: Slack scales: coupling slack in units of max_lead^2 (dimensionless), normal-force slack in N.
S_SCALE = np.array([1.0, 0.1])
#: Normal-force constraint scale, N.
FN_SCALE = 0.1


@dataclass(frozen=True)
class OCP:
    """A built NLP and everything needed to fill in its bounds and parameters.

    Attributes
    ----------
    nlp : dict
        ``{'x', 'p', 'f', 'g'}`` CasADi expressions for ``nlpsol``.
    hess_lag : casadi.Function
        Gauss-Newton Hessian of the Lagrangian ``(x, p, lam_f, lam_g) -> H``.
    lbw, ubw, lbg, ubg : numpy.ndarray
        Variable and constraint bounds.
    horizon, dt_s : int, float
        N and the step.
    lead_eq_m : numpy.ndarray
        The model's equilibrium lead (coupling constraint centre), m.
    """

    nlp: dict
    hess_lag: ca.Function
    lbw: np.ndarray
    ubw: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    horizon: int
    dt_s: float
    lead_eq_m: np.ndarray
    n_w: int
    n_p: int
    n_x: int
    n_u: int

    def unpack(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Scaled ``w -> `` physical ``(X (7 x N), U (3 x N), S (2 x N))``."""
        n, nx, nu = self.horizon, self.n_x, self.n_u
        w = np.asarray(w, dtype=float).ravel()
        xs = w[: nx * n].reshape(nx, n, order="F") * X_SCALE[:, None]
        us = w[nx * n : (nx + nu) * n].reshape(nu, n, order="F") * U_SCALE[:, None]
        ss = w[(nx + nu) * n :].reshape(n_slacks, n, order="F") * S_SCALE[:, None]
        return xs, us, ss

    def pack_parameters(
        self, x0: np.ndarray, ref: np.ndarray, u_prev: np.ndarray, disturbance_n: np.ndarray
    ) -> np.ndarray:
        """Parameter vector from the current state (7), reference (6 x N), command (3), d (3)."""
        return np.concatenate(
            [np.ravel(x0), np.ravel(ref, order="F"), np.ravel(u_prev), np.ravel(disturbance_n)]
        )

    def pack_variables(self, xs: np.ndarray, us: np.ndarray, ss: np.ndarray) -> np.ndarray:
        """Decision vector (scaled) from physical X (7 x N), U (3 x N), S (2 x N)."""
        return np.concatenate(
            [
                np.ravel(np.asarray(xs) / X_SCALE[:, None], order="F"),
                np.ravel(np.asarray(us) / U_SCALE[:, None], order="F"),
                np.ravel(np.asarray(ss) / S_SCALE[:, None], order="F"),
            ]
        )


def build_ocp(model: CapsuleModel, dt_s: float, lead_eq_m: np.ndarray) -> OCP:
    """Build the MPC's NLP for ``model`` with step ``dt_s``.

    Parameters
    ----------
    model : CapsuleModel
        The controller's capsule model (never the plant).
    dt_s : float
        Prediction step, s.
    lead_eq_m : numpy.ndarray (2,)
        The model's equilibrium lead, m: the centre of the coupling constraint.
    """
    sc: Scenario = model.scenario
    cfg, lim = sc.mpc, sc.limits
    n, nx, nu = cfg.horizon, model.n_x, model.n_u
    # One symbol each for w and p (nlpsol and hess_lag need purely symbolic inputs), sliced.
    n_w = (nx + nu + n_slacks) * n
    n_p = nx + N_REF * n + nu + N_DIST
    w = ca.MX.sym("w", n_w)
    p = ca.MX.sym("p", n_p)
    xs = ca.diag(ca.DM(X_SCALE)) @ ca.reshape(w[0 : nx * n], nx, n)
    us = ca.diag(ca.DM(U_SCALE)) @ ca.reshape(w[nx * n : (nx + nu) * n], nu, n)
    ss = ca.diag(ca.DM(S_SCALE)) @ ca.reshape(w[(nx + nu) * n :], n_slacks, n)
    x0 = p[0:nx]
    ref = ca.reshape(p[nx : nx + N_REF * n], N_REF, n)
    u_prev = p[nx + N_REF * n : nx + N_REF * n + nu]
    dist = p[nx + N_REF * n + nu :]

    mass = sc.capsule.mass_kg
    eps = sc.friction.smoothing_eps_mps
    eq_sq = lim.max_lead_m**2
    lead_eq = ca.DM(lead_eq_m)
    g_dyn, g_path, residuals = [], [], []
    x_prev, u_last = x0, u_prev
    for k in range(n):
        xk, uk, sk = xs[:, k], us[:, k], ss[:, k]
        v_hat = xk[2:4] / ca.sqrt(ca.sumsqr(xk[2:4]) + eps**2)
        xdot = model.ode(xk, uk) + ca.vertcat(0, 0, (dist[0:2] - dist[2] * v_hat) / mass, 0, 0, 0)
        g_dyn.append((xk - x_prev - dt_s * xdot) / X_SCALE)
        lead, _force, f_n, _mu = model.outputs(xk)
        g_path += [
            ca.sumsqr(lead - lead_eq) / eq_sq - 1 - sk[0],  # <= 0: capsule keeps the magnet
            (f_n + sk[1]) / FN_SCALE,  # >= F_N,min: stays on the plate
            (f_n - sk[1]) / FN_SCALE,  # <= F_N,max: tissue-safe
            (uk - u_last) / U_SCALE,  # |du| <= a dt per axis
        ]
        weight = cfg.terminal_factor if k == n - 1 else 1.0
        err = xk[0:2] - ref[0:2, k]
        # Path frame from the reference velocity: tangent t, normal n; where the reference
        # stands still (t = 0) the last term weighs the whole error isotropically.
        tan = ref[2:4, k] / ca.sqrt(ca.sumsqr(ref[2:4, k]) + TANGENT_EPS_MPS**2)
        nrm = ca.vertcat(-tan[1], tan[0])
        still = 1 - ca.sumsqr(tan)
        residuals += [
            weight * ca.dot(nrm, err) / cfg.lateral_tol_m,
            weight * ca.dot(tan, err) / cfg.position_tol_m,
            weight * still * err / cfg.position_tol_m,
            (xk[2:4] - ref[2:4, k]) / cfg.velocity_tol_mps,
            (uk[0:2] - ref[4:6, k]) / cfg.input_tol_mps,
            (uk - u_last) / cfg.input_rate_tol_mps,
            np.sqrt(cfg.slack_weight) * sk / S_SCALE,
        ]
        x_prev, u_last = xk, uk

    res = ca.vertcat(*residuals)
    f = 0.5 * ca.sumsqr(res) + cfg.slack_weight * ca.sum1(ca.vec(ss) / np.tile(S_SCALE, n))
    g = ca.vertcat(*g_dyn, *g_path)

    jac = ca.jacobian(res, w)
    lam_f = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", g.shape[0])
    # Gauss-Newton Hessian plus a tiny diagonal so the QP stays strictly convex in the
    # directions the cost does not see (EPM position states); units are scaled residuals.
    hess = lam_f * ca.mtimes(jac.T, jac)
    hess_lag = ca.Function(
        "nlp_hess_l", [w, p, lam_f, lam_g], [hess],
        ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"],
    )  # fmt: skip

    inf = np.inf
    speed = lim.speed_mps
    u_lo = np.array([-speed, -speed, -speed if cfg.height_control else 0.0])
    x_lo = np.array([-inf, -inf, -inf, -inf, *lim.workspace_min_m])
    x_hi = np.array([inf, inf, inf, inf, *lim.workspace_max_m])
    lbw = np.concatenate([np.tile(x_lo / X_SCALE, n), np.tile(u_lo / U_SCALE, n), np.zeros(n_slacks * n)])
    ubw = np.concatenate(
        [np.tile(x_hi / X_SCALE, n), np.tile(-u_lo / U_SCALE, n), np.full(n_slacks * n, inf)]
    )
    da = lim.accel_mps2 * dt_s / U_SCALE
    stage_lo = np.array([-inf, lim.normal_force_min_n / FN_SCALE, -inf, *(-da)])
    stage_hi = np.array([0.0, inf, lim.normal_force_max_n / FN_SCALE, *da])
    lbg = np.concatenate([np.zeros(nx * n), np.tile(stage_lo, n)])
    ubg = np.concatenate([np.zeros(nx * n), np.tile(stage_hi, n)])
    return OCP(
        nlp={"x": w, "p": p, "f": f, "g": g},
        hess_lag=hess_lag, lbw=lbw, ubw=ubw, lbg=lbg, ubg=ubg, horizon=n, dt_s=dt_s,
        lead_eq_m=np.asarray(lead_eq_m, dtype=float), n_w=n_w, n_p=n_p, n_x=nx, n_u=nu,
    )  # fmt: skip
