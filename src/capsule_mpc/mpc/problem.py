"""The MPC's optimal-control problem, built once as a parametric CasADi NLP in a stage-wise layout.

The layout is the one a Riccati-structured QP solver (HPIPM) needs: variables ordered stage by
stage, ``w = (x_0, u_0, x_1, u_1, ..., x_{N-1}, u_{N-1}, x_N)`` (no input at the last stage);
constraint rows ordered ``gap_0, path_0, ..., gap_{N-1}, path_{N-1}`` where ``gap_k`` ties
``x_{k+1}`` (coefficient the identity) to ``(x_k, u_k)``; and every cost term and path row a
function of one stage's ``(x_k, u_k)`` only, so the Gauss-Newton Hessian is block diagonal.

* State ``x_k`` (13): capsule position ``p`` (2) and velocity ``v`` (2), EPM position ``e`` (2)
  and height ``h``, the EPM velocity command ``c`` (3) applied over the step that ends at stage k,
  and its slope ``s`` (3: the command's change over that step per unit time, an acceleration).
  ``x_0`` is fixed by its bounds to the estimated state, the command being applied (``u_prev``)
  and its slope: carrying them in the state makes the acceleration and jerk limits stage-local.
* Input ``u_k`` (8): the command change ``dc`` (3), the capsule velocity at stage k+1 (2; the one
  implicit part of the dynamics), two non-negative slacks (coupling, normal force) and the jerk
  rows' slack.
* Gap rows (13 per stage, linear): ``c_{k+1} = c_k + dc_k``, ``s_{k+1} = dc_k / dt``,
  ``(e, h)_{k+1} = (e, h)_k +`` the arm's displacement (:func:`arm_displacement`: the command
  profile Ruckig ramps between commands, delayed by the nominal servo lag), ``v_{k+1} = `` the
  input, ``p_{k+1} = p_k + dt v_{k+1}``: implicit Euler of ``p' = v``.
* Path rows (11 per stage): implicit Euler of the capsule's velocity, ``v_{k+1} - v_k - dt (a(x_{k+1})
  + d/m) = 0`` (2 rows; ``x_{k+1}`` written through the gap's explicit expressions: the model is
  stiff, see :mod:`capsule_mpc.dynamics`), coupling ``|lead - lead_eq|^2 <= max_lead^2 (1 + s_0)``
  and the normal-force band ``F_N,min - s_1 <= F_N <= F_N,max + s_1`` at ``x_{k+1}``, and the
  slope's change within the jerk limit (3 lower, 3 upper, softened by the jerk slack).
* Bounds: EPM speed on ``c_{k+1}``, acceleration on ``dc_k`` (``|dc| <= a dt``), workspace on
  ``(e, h)_{k+1}``, slacks >= 0.
* Stage grid: stage 0 lasts one camera frame (its command is the one sent, held for a frame),
  stages 1..N-1 last ``dt`` (``mpc.dt_s``; one frame when unset). A step longer than the frame
  stretches the horizon at the same N (e.g. 20 ms stages in a 100 Hz loop); ``dt`` above is the
  stage's own step.

Parameters ``p = (x_0, ref, u_prev, s_prev, d)``: the estimated current state (7), the reference
window (capsule position and velocity at stages 1..N, and the EPM velocity feed-forward for inputs
0..N-1: the path's velocity, or an offline plan's EPM velocity), the command being applied (3) and
its slope (3), and the estimated force disturbance ``d = (d_x, d_y, d_fric)``: a constant force (N)
plus an extra friction force (N) that opposes the capsule's motion -- the model's friction is the
part of the mismatch that turns with the motion, so it must not be a fixed vector.

The objective is a sum of squares ``0.5 |R(w, p)|^2`` plus a linear slack penalty; stage k's
residuals weigh the state ``x_{k+1}`` against the reference at stage k+1, the command ``c_{k+1}``
against the feed-forward, ``dc_k`` (times ``sqrt(dt / h_k)`` on a stage of step ``h_k``: the
squared acceleration per unit time) and the slacks. Its Gauss-Newton Hessian ``J_R^T J_R`` is
exact for the objective and cheap; the SQP steps use it (:mod:`capsule_mpc.mpc.solver`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar, TypeVar

import casadi as ca
import numpy as np

from ..config import Scenario
from ..dynamics import FN_SCALE, S_SCALE, TANGENT_EPS_MPS, U_SCALE, X_SCALE, CapsuleModel, n_slacks
from ..interfaces import servo_time_constant_s
from .grid import stage_end_times_s

__all__ = [
    "A_SCALE",
    "FN_SCALE",
    "INPUT_SCALE",
    "N_DIST",
    "N_INPUT",
    "N_PATH",
    "N_REF",
    "N_STATE",
    "OCP",
    "STATE_SCALE",
    "S_SCALE",
    "TANGENT_EPS_MPS",
    "TERMINAL_FACTOR",
    "U_SCALE",
    "X_SCALE",
    "build_ocp",
    "n_slacks",
]

#: Reference rows per stage: capsule position (2), capsule velocity (2), EPM velocity feed-forward (2),
#: the factor of the jerk cost's weight (1).
N_REF = 7
#: Disturbance parameters: constant force (x, y) and extra friction magnitude, N.
N_DIST = 3
#: Model state (p, v, e, h) and EPM velocity sizes (see :mod:`capsule_mpc.dynamics`).
_NX_MODEL, _NU_MODEL = 7, 3
#: Stage state: the model state, the command applied and its slope (13); stage input: dc, v_next,
#: slacks (7).
N_STATE = _NX_MODEL + 2 * _NU_MODEL
N_INPUT = _NU_MODEL + 2 + n_slacks + 1
#: Path rows per stage: implicit velocity (2), coupling, normal force (2), jerk (3 lower, 3 upper).
N_PATH = 11
#: Stage-state columns of the command's slope (the EPM acceleration of the step that ends there).
_SLOPE = slice(_NX_MODEL + _NU_MODEL, N_STATE)
#: Factor on the last stage's tracking weights (the terminal cost): a plan that ends on the
#: reference is preferred to one that is closer earlier, as in an LQR's terminal weight; the value
#: the controller was tuned with on the rectangle.
TERMINAL_FACTOR = 3.0
#: Scale of the command's slope (EPM acceleration), m/s^2, and of the jerk rows, m/s^3.
A_SCALE = np.array([0.1, 0.1, 0.1])
J_SCALE = 1.0
#: Scales of the stage state (model state, command) and input (dc, capsule velocity, slacks).
STATE_SCALE = np.concatenate([X_SCALE, U_SCALE, A_SCALE])
#: Scale of the jerk rows' slack (a slope change beyond the jerk limit), m/s^2.
JERK_SLACK_SCALE = 0.1
INPUT_SCALE = np.concatenate([U_SCALE, X_SCALE[2:4], S_SCALE, [JERK_SLACK_SCALE]])
_STAGE = N_STATE + N_INPUT
#: A CasADi expression or a NumPy array (the arm model is written once for both).
_Expr = TypeVar("_Expr", ca.MX, np.ndarray)
#: Stage-state columns of the capsule's position and velocity, the EPM's position (x, y, height)
#: and its velocity command.
_CAPSULE_P, _CAPSULE_V, _EPM, _CMD = slice(0, 2), slice(2, 4), slice(4, 7), slice(7, 10)


@dataclass(frozen=True)
class OCP:
    """A built NLP in the stage-wise layout, and everything needed to fill in its bounds.

    Attributes
    ----------
    nlp : dict
        ``{'x', 'p', 'f', 'g'}`` CasADi expressions for ``nlpsol``.
    residual : casadi.Function
        ``R(w, p)``: the least-squares residuals (the objective is ``0.5 |R|^2`` plus the linear
        slack penalty ``slack_gradient . w``).
    slack_gradient : numpy.ndarray
        Gradient of the linear slack penalty with respect to ``w``.
    lbw, ubw, lbg, ubg : numpy.ndarray
        Variable and constraint bounds; ``lbw``/``ubw`` of ``x_0`` are placeholders, filled from
        the parameters by :meth:`variable_bounds`.
    horizon, dt_s : int, float
        N and the step of stages 1..N-1, s.
    steps_s : numpy.ndarray (N,)
        Every stage's step, s: the first is the frame (``frame_s``), the others ``dt_s``.
    lead_eq_m : numpy.ndarray
        The model's equilibrium lead (coupling constraint centre), m.
    n_w, n_p : int
        Number of variables and parameters.
    n_x, n_u, n_g : int
        Stage state, input and path-row counts (13, 8, 11).
    lag_s : float
        The nominal arm's servo time constant the prediction delays the EPM by, s.
    """

    nlp: dict
    residual: ca.Function
    slack_gradient: np.ndarray
    lbw: np.ndarray
    ubw: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    horizon: int
    dt_s: float
    lead_eq_m: np.ndarray
    steps_s: np.ndarray
    lag_s: float = 0.0
    n_x: ClassVar[int] = N_STATE
    n_u: ClassVar[int] = N_INPUT
    n_g: ClassVar[int] = N_PATH

    @property
    def n_w(self) -> int:
        """Number of variables."""
        return len(self.lbw)

    @property
    def n_p(self) -> int:
        """Number of parameters."""
        return int(self.nlp["p"].numel())

    @property
    def frame_s(self) -> float:
        """The first stage's step: the frame period the plan advances by, s."""
        return float(self.steps_s[0])

    @cached_property
    def uniform(self) -> bool:
        """Whether every stage lasts one frame (the plan shifts by whole stages)."""
        return bool(np.all(self.steps_s == self.steps_s[0]))

    @cached_property
    def node_times_s(self) -> np.ndarray:
        """Times of stages 0..N from the frame the plan starts at, s."""
        return np.concatenate([[0.0], stage_end_times_s(self.steps_s)])

    # ------------------------------------------------------------------ structure
    @property
    def structure(self) -> dict[str, int | list[int]]:
        """``N``, ``nx``, ``nu``, ``ng`` per stage, as CasADi's HPIPM interface takes them."""
        n = self.horizon
        return {"N": n, "nx": [self.n_x] * (n + 1), "nu": [self.n_u] * n + [0], "ng": [self.n_g] * n + [0]}

    def epm_velocities(
        self, us: np.ndarray, u_prev: np.ndarray, slope_prev: np.ndarray | None = None
    ) -> np.ndarray:
        """The EPM's mean velocity over each step (3 x N), m/s, as the prediction moves it for the
        commands ``us`` (3 x N) after ``u_prev`` (3) changing at ``slope_prev`` (3, m/s^2; default
        0): :func:`arm_displacement` over each stage's step, divided by the step."""
        us = np.asarray(us, dtype=float)
        commands = np.column_stack([np.ravel(u_prev), us])
        slope = np.zeros(_NU_MODEL) if slope_prev is None else np.ravel(slope_prev).astype(float)
        out = np.empty_like(us)
        for k, h in enumerate(self.steps_s):
            dc = commands[:, k + 1] - commands[:, k]
            out[:, k] = arm_displacement(commands[:, k], dc, slope, float(h), self.lag_s) / h
            slope = dc / h
        return out

    def _stages(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scaled ``w`` -> stage states (N+1 x 13) and inputs (N x 8), both scaled."""
        n = self.horizon
        w = np.asarray(w, dtype=float).ravel()
        body = w[: _STAGE * n].reshape(n, _STAGE)
        states = np.vstack([body[:, :N_STATE], w[_STAGE * n :][None, :]])
        return states, body[:, N_STATE:]

    # ------------------------------------------------------------------ packing
    def unpack(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Scaled ``w -> `` physical ``(X (7 x N), U (3 x N), S (2 x N))``: the predicted model
        states at stages 1..N, the EPM velocity commands of steps 0..N-1 and the slacks."""
        w = np.asarray(w, dtype=float).ravel()
        phys = w[self._later_states] * STATE_SCALE  # stages 1..N: one gather (this runs every frame)
        ss = (w[self._slacks] * S_SCALE).T
        return phys[:, :_NX_MODEL].T, phys[:, _NX_MODEL : _NX_MODEL + _NU_MODEL].T, ss

    @cached_property
    def _later_states(self) -> np.ndarray:
        """Indices of ``w``'s stage states 1..N (N x 13)."""
        first = _STAGE * np.arange(1, self.horizon + 1)
        return first[:, None] + np.arange(N_STATE)[None, :]

    @cached_property
    def _slacks(self) -> np.ndarray:
        """Indices of ``w``'s slacks, stages 0..N-1 (N x 2)."""
        first = _STAGE * np.arange(self.horizon) + N_STATE + _NU_MODEL + 2
        return first[:, None] + np.arange(n_slacks)[None, :]

    def pack_parameters(
        self,
        x0: np.ndarray,
        ref: np.ndarray,
        u_prev: np.ndarray,
        disturbance_n: np.ndarray,
        slope_prev: np.ndarray | None = None,
    ) -> np.ndarray:
        """Parameter vector from the current state (7), reference (7 x N), command (3), d (3) and
        the slope of the command being applied (3, m/s^2: its change from the one before, per
        frame; default 0)."""
        if np.shape(ref) != (N_REF, self.horizon):
            raise ValueError(f"reference window: must be {N_REF} x {self.horizon}, got {np.shape(ref)}")
        slope = np.zeros(_NU_MODEL) if slope_prev is None else np.ravel(slope_prev)
        return np.concatenate(
            [np.ravel(x0), np.ravel(ref, order="F"), np.ravel(u_prev), slope, np.ravel(disturbance_n)]
        )

    def pack_variables(
        self,
        xs: np.ndarray,
        us: np.ndarray,
        ss: np.ndarray,
        x0: np.ndarray | None = None,
        u_prev: np.ndarray | None = None,
    ) -> np.ndarray:
        """Scaled ``w`` from physical X (7 x N, stages 1..N), U (3 x N), S (2 x N).

        ``x0`` and ``u_prev`` fill stage 0 (default: the first predicted state and command; the
        solvers overwrite stage 0 with the parameters anyway). The inputs follow from the states:
        ``dc_k = U_k - U_{k-1}`` and the capsule velocity of ``X_{k+1}``.
        """
        xs, us, ss = np.asarray(xs, dtype=float), np.asarray(us, dtype=float), np.asarray(ss, dtype=float)
        x_first = xs[:, 0] if x0 is None else np.ravel(x0)
        c_first = us[:, 0] if u_prev is None else np.ravel(u_prev)
        commands = np.vstack([c_first, us.T])
        slopes = np.vstack([np.zeros(_NU_MODEL), np.diff(commands, axis=0) / self.steps_s[:, None]])
        model = np.vstack([x_first, xs.T])
        states = np.hstack([model, commands, slopes])
        inputs = np.hstack([np.diff(commands, axis=0), xs[2:4].T, ss.T, np.zeros((ss.shape[1], 1))])
        return self._join(states / STATE_SCALE, inputs / INPUT_SCALE)

    def _join(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """Scaled stage states (N+1 x 13) and inputs (N x 8) -> ``w``."""
        return np.concatenate([np.hstack([states[:-1], inputs]).ravel(), states[-1]])

    def shift(self, w: np.ndarray) -> np.ndarray:
        """``w`` advanced by one frame (the warm start of the next frame).

        On a uniform grid stage k+1 becomes stage k, and the last stage repeats with the command
        held (``dc = 0``). On a longer-stepped grid the positions are interpolated at the new
        stage times (continued past the horizon at the last rates) and every rate -- capsule
        velocity, command -- is its position's mean rate over the new stage, so the linear gap
        rows hold as in ``w``; each slack is the one of the old stage the new stage starts in.
        """
        w = np.asarray(w, dtype=float).ravel()
        if not self.uniform:
            return self._shift_interpolated(w)
        # Slices, not per-stage arrays (this runs every frame): stages 1..N move down one stage,
        # then the last input (dc zeroed) and x_N again.
        out = np.concatenate([w[_STAGE:], w[-_STAGE:]])
        out[-_STAGE : -_STAGE + _NU_MODEL] = 0.0
        out[-N_STATE:][_SLOPE] = 0.0  # the held command has no slope
        return out

    def _shift_interpolated(self, w: np.ndarray) -> np.ndarray:
        states, inputs = self._stages(w)  # scaled
        old_t = self.node_times_s
        new_t = self.frame_s + old_t
        phys = np.column_stack([np.interp(new_t, old_t, col) for col in states.T]) * STATE_SCALE
        # The capsule's position is piecewise linear in time: interpolated exactly, continued past
        # the horizon at the last stage's velocity, and each stage's velocity is then the
        # position's mean rate over the new stage, so its gap rows hold as they did in ``w``.
        past = np.maximum(new_t - old_t[-1], 0.0)[:, None]
        phys[:, _CAPSULE_P] += past * states[-1, _CAPSULE_V] * STATE_SCALE[_CAPSULE_V]
        phys[1:, _CAPSULE_V] = np.diff(phys[:, _CAPSULE_P], axis=0) / self.steps_s[:, None]
        # The command profile is piecewise linear between the stage commands (held past the
        # horizon): interpolated exactly; its slopes follow, and the EPM moves over each new stage
        # as the prediction moves it (arm_displacement), so the EPM's gap rows hold too.
        phys[1:, _SLOPE] = np.diff(phys[:, _CMD], axis=0) / self.steps_s[:, None]
        moves = self.steps_s * self.epm_velocities(phys[1:, _CMD].T, phys[0, _CMD], phys[0, _SLOPE])
        phys[1:, _EPM] = phys[0, _EPM] + np.cumsum(moves, axis=1).T
        moved = phys / STATE_SCALE
        stage = np.minimum(np.searchsorted(old_t, new_t[:-1], side="right") - 1, self.horizon - 1)
        new_inputs = np.hstack(
            [
                np.diff(moved[:, _CMD], axis=0),  # dc (the command's scale)
                moved[1:, 2:4],  # capsule velocity at the next stage (the state's scale)
                inputs[stage, _NU_MODEL + 2 :],  # slacks: the old stage the new one starts in
            ]
        )
        return self._join(moved, new_inputs)

    def variable_bounds(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``lbw, ubw`` with ``x_0`` fixed to the parameters' state and command."""
        x0 = self.initial_state(p)
        lbw, ubw = self.lbw.copy(), self.ubw.copy()
        lbw[:N_STATE] = ubw[:N_STATE] = x0
        return lbw, ubw

    def initial_state(self, p: np.ndarray) -> np.ndarray:
        """Scaled stage-0 state from the parameters: the estimated state, ``u_prev`` and its slope."""
        n = self.horizon
        i_u = _NX_MODEL + N_REF * n
        return np.concatenate([p[:_NX_MODEL], p[i_u : i_u + 2 * _NU_MODEL]]) / STATE_SCALE


def arm_displacement(cmd: _Expr, dc: _Expr, slope: _Expr, h: float, lag_s: float) -> _Expr:
    """The EPM's displacement over a step of ``h`` (s) that changes the command from ``cmd`` by
    ``dc``, the command having changed at ``slope`` (m/s^2) over the step before.

    The arm's response as the MPC predicts it: Ruckig (velocity interface) turns each command into
    a jerk-limited ramp that reaches it by the step's end, so a jerk-feasible command sequence
    gives setpoint velocities linear between the commands (the trapezoid rule: half a step behind
    holding each command over its step); the joint servos follow their setpoints with a
    first-order lag of time constant ``lag_s``, which on a ramp is a delay of ``lag_s``. The
    displacement is the integral of the command profile, piecewise linear, delayed by ``lag_s``,
    over the step; the profile before the step's start is the previous step's ramp (``slope``),
    continued where ``lag_s`` reaches further back. Linear in its arguments (stage-local);
    symbolic (CasADi) or numeric (NumPy) alike.
    """
    if lag_s <= h:
        return h * cmd + (h - lag_s) ** 2 / (2.0 * h) * dc - 0.5 * lag_s**2 * slope
    return h * cmd - h * (lag_s - 0.5 * h) * slope


def _next_state(xk: ca.MX, uk: ca.MX, dt_s: float, lag_s: float) -> ca.MX:
    """Physical x_{k+1} from physical (x_k, u_k): implicit Euler of p' = v, the EPM moved as the
    arm moves it (:func:`arm_displacement`); the command's slope is its change over the step."""
    pos, epm, height, cmd = xk[0:2], xk[4:6], xk[6], xk[7:10]
    dc = uk[0:3]
    cmd_next = cmd + dc
    v_next = uk[3:5]
    move = arm_displacement(cmd, dc, xk[_SLOPE], dt_s, lag_s)
    return ca.vertcat(
        pos + dt_s * v_next,
        v_next,
        epm + move[0:2],
        height + move[2],
        cmd_next,
        dc / dt_s,
    )


def _stage_residuals(
    cfg: Any,
    weight: float,
    ref_k: Any,
    m1: Any,
    c1: Any,
    dc: Any,
    sk: Any,
    sj: Any,
    jerk: Any,
    dt_over_h: float,
) -> list[Any]:
    """The least-squares residuals of one stage: tracking in the path frame, velocity, feed-forward,
    EPM acceleration, slacks and (optionally) jerk. ``ref_k`` is the stage's reference column,
    ``dt_over_h`` the grid step over this stage's step."""
    err = m1[0:2] - ref_k[0:2]
    # Path frame from the reference velocity: tangent t, normal n; where the reference
    # stands still (t = 0) the last term weighs the whole error isotropically.
    tan = ref_k[2:4] / ca.sqrt(ca.sumsqr(ref_k[2:4]) + TANGENT_EPS_MPS**2)
    nrm = ca.vertcat(-tan[1], tan[0])
    still = 1 - ca.sumsqr(tan)
    residuals = [
        weight * ca.dot(nrm, err) / cfg.lateral_tol_m,
        weight * ca.dot(tan, err) / cfg.position_tol_m,
        weight * still * err / cfg.position_tol_m,
        (m1[2:4] - ref_k[2:4]) / cfg.velocity_tol_mps,
        (c1[0:2] - ref_k[4:6]) / cfg.input_tol_mps,
        # Per unit time: sum dc_k^2 / h_k approximates the integral of the squared EPM
        # acceleration, so a shorter first stage weighs dc sqrt(dt / h).
        (dc if dt_over_h == 1.0 else dc * np.sqrt(dt_over_h)) / cfg.input_rate_tol_mps,
        np.sqrt(cfg.slack_weight) * sk / S_SCALE,
        np.sqrt(cfg.slack_weight) * sj / JERK_SLACK_SCALE,
    ]
    if cfg.input_jerk_tol_mps2 is not None:
        residuals.append(ref_k[6] * jerk * J_SCALE / cfg.input_jerk_tol_mps2)
    return residuals


def _variable_bounds(sc: Scenario, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the scaled variables: workspace, speed and acceleration of the state, the EPM's
    velocity change per stage, non-negative slacks."""
    cfg, lim, inf = sc.mpc, sc.limits, np.inf
    speed = lim.speed_mps
    c_lo = np.array([-speed, -speed, -speed if cfg.height_control else 0.0])
    a_lo = -lim.accel_mps2 * np.array([1.0, 1.0, 1.0 if cfg.height_control else 0.0])
    x_lo = np.concatenate([[-inf, -inf, -inf, -inf], lim.workspace_min_m, c_lo, a_lo]) / STATE_SCALE
    x_hi = np.concatenate([[inf, inf, inf, inf], lim.workspace_max_m, -c_lo, -a_lo]) / STATE_SCALE

    def input_bounds(h: float) -> tuple[np.ndarray, np.ndarray]:
        da = np.full(_NU_MODEL, lim.accel_mps2 * h)
        u_lo = np.concatenate([-da, [-inf, -inf], np.zeros(n_slacks + 1)]) / INPUT_SCALE
        u_hi = np.concatenate([da, [inf, inf], np.full(n_slacks + 1, inf)]) / INPUT_SCALE
        return u_lo, u_hi

    bounds = [input_bounds(float(h)) for h in steps]
    lbw = np.concatenate([*[np.concatenate([x_lo, lo]) for lo, _ in bounds], x_lo])
    ubw = np.concatenate([*[np.concatenate([x_hi, hi]) for _, hi in bounds], x_hi])
    return lbw, ubw


def _constraint_bounds(sc: Scenario, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the stage rows: gaps and implicit velocity = 0, coupling <= 0, the normal force's
    range, and the jerk rows.

    The jerk rows bound the slope's change at a stage's start by the jerk limit over the time
    between the two steps' midpoints: stage 0's over one frame (the command sent now follows the
    one sent a frame ago, exactly what the safety layer allows), a later stage's over its own and
    the previous stage's half steps (on a uniform grid also one frame).
    """
    lim, inf = sc.limits, np.inf
    gaps = (np.concatenate([[steps[0]], steps[:-1]]) + steps) / 2
    lbg, ubg = [], []
    for k in range(len(steps)):
        dj = np.full(_NU_MODEL, lim.jerk_mps3 * float(gaps[k]) / J_SCALE)
        fixed, free = np.zeros(N_STATE + 2), np.full(_NU_MODEL, inf)
        fn_lo, fn_hi = lim.normal_force_min_n / FN_SCALE, lim.normal_force_max_n / FN_SCALE
        lbg.append(np.concatenate([fixed, [-inf, fn_lo, -inf], -dj, -free]))
        ubg.append(np.concatenate([fixed, [0.0, inf, fn_hi], free, dj]))
    return np.concatenate(lbg), np.concatenate(ubg)


def _stage_rows(
    model: CapsuleModel,
    xk: ca.MX,
    uk: ca.MX,
    x_next_var: ca.MX,
    dist: ca.MX,
    h: float,
    lag: float,
    lead_eq_m: np.ndarray,
) -> tuple[list[ca.MX], tuple[ca.MX, ...]]:
    """One stage's constraint rows (gap, implicit velocity, coupling, normal force, jerk) from the
    physical stage state ``xk`` and input ``uk`` (step ``h``, s), and the stage's parts the residuals
    weigh: the next model state, command, command change, slacks, jerk slack and jerk."""
    sc: Scenario = model.scenario
    x1 = _next_state(xk, uk, h, lag)
    m1, c1, dc, sk = x1[0:_NX_MODEL], x1[_NX_MODEL : _NX_MODEL + _NU_MODEL], uk[0:3], uk[5:7]
    sj, jerk = uk[7], (uk[0:3] / h - xk[_SLOPE]) / J_SCALE
    eps = sc.friction.smoothing_eps_mps
    v_hat = m1[2:4] / ca.sqrt(ca.sumsqr(m1[2:4]) + eps**2)
    acc = model.ode(m1, c1)[2:4] + (dist[0:2] - dist[2] * v_hat) / sc.capsule.mass_kg
    lead, _force, f_n, _mu = model.outputs(m1)
    rows = [
        x_next_var - x1 / ca.DM(STATE_SCALE),  # gap: the coefficient of x_{k+1} is the identity
        (m1[2:4] - xk[2:4] - h * acc) / X_SCALE[2:4],  # implicit Euler of the velocity
        ca.sumsqr(lead - ca.DM(lead_eq_m)) / sc.limits.max_lead_m**2 - 1 - sk[0],  # <= 0: keeps the magnet
        (f_n + sk[1]) / FN_SCALE,  # >= F_N,min: stays on the plate
        (f_n - sk[1]) / FN_SCALE,  # <= F_N,max: tissue-safe
        # The slope's change (the jerk the arm must make) within the jerk limit, softened by one
        # slack so that a start state already past it (after a braking fallback) keeps the QP
        # feasible; the safety layer enforces the limit on the command sent.
        jerk + sj / J_SCALE,  # >= -J frame
        jerk - sj / J_SCALE,  # <= J frame
    ]
    return rows, (m1, c1, dc, sk, sj, jerk)


def build_ocp(model: CapsuleModel, dt_s: float, lead_eq_m: np.ndarray, frame_s: float | None = None) -> OCP:
    """Build the MPC's NLP for ``model`` with step ``dt_s`` in the stage-wise layout.

    Parameters
    ----------
    model : CapsuleModel
        The controller's capsule model (never the plant).
    dt_s : float
        Prediction step of stages 1..N-1, s.
    lead_eq_m : numpy.ndarray (2,)
        The model's equilibrium lead, m: the centre of the coupling constraint.
    frame_s : float, optional
        The first stage's step, s: the frame period (default ``dt_s``).

    Returns
    -------
    OCP
        The NLP, its residual function and bounds.
    """
    sc: Scenario = model.scenario
    cfg = sc.mpc
    n = cfg.horizon
    for name, value in (("dt_s", dt_s), ("frame_s", frame_s)):
        if value is not None and not value > 0:
            raise ValueError(f"{name}: must be > 0 s, got {value}")
    steps = np.full(n, float(dt_s))
    steps[0] = dt_s if frame_s is None else frame_s
    n_w = _STAGE * n + N_STATE
    n_p = _NX_MODEL + N_REF * n + 2 * _NU_MODEL + N_DIST
    w = ca.MX.sym("w", n_w)
    p = ca.MX.sym("p", n_p)
    ref = ca.reshape(p[_NX_MODEL : _NX_MODEL + N_REF * n], N_REF, n)
    i_dist = _NX_MODEL + N_REF * n + 2 * _NU_MODEL
    dist = p[i_dist : i_dist + N_DIST]

    lag = servo_time_constant_s(sc.arm.servo_bandwidth_hz) or 0.0  # no servo lag: 0
    x_scale, u_scale = ca.DM(STATE_SCALE), ca.DM(INPUT_SCALE)
    rows, residuals = [], []
    for k in range(n):
        h = float(steps[k])
        xk = x_scale * w[_STAGE * k : _STAGE * k + N_STATE]
        uk = u_scale * w[_STAGE * k + N_STATE : _STAGE * (k + 1)]
        x_next_var = w[_STAGE * (k + 1) : _STAGE * (k + 1) + N_STATE]
        stage_rows, (m1, c1, dc, sk, sj, jerk) = _stage_rows(
            model, xk, uk, x_next_var, dist, h, lag, lead_eq_m
        )
        rows += stage_rows
        weight = TERMINAL_FACTOR if k == n - 1 else 1.0
        residuals += _stage_residuals(cfg, weight, ref[:, k], m1, c1, dc, sk, sj, jerk, dt_s / h)

    res = ca.vertcat(*residuals)
    # The linear slack penalty, slack_weight per unit slack (scaled slack = physical / S_SCALE).
    slack_gradient = np.zeros(n_w)
    for k in range(n):
        i0 = _STAGE * k + N_STATE + _NU_MODEL + 2
        slack_gradient[i0 : i0 + n_slacks + 1] = cfg.slack_weight  # with the jerk slack
    f = 0.5 * ca.sumsqr(res) + ca.dot(ca.DM(slack_gradient), w)
    g = ca.vertcat(*rows)
    residual = ca.Function("mpc_residual", [w, p], [res], ["w", "p"], ["r"])

    lbw, ubw = _variable_bounds(sc, steps)
    lbg, ubg = _constraint_bounds(sc, steps)
    return OCP(
        nlp={"x": w, "p": p, "f": f, "g": g}, residual=residual, slack_gradient=slack_gradient,
        lbw=lbw, ubw=ubw, lbg=lbg, ubg=ubg, horizon=n, dt_s=dt_s,
        lead_eq_m=np.asarray(lead_eq_m, dtype=float), steps_s=steps, lag_s=lag,
    )  # fmt: skip
