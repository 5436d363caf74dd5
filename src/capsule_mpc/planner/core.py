"""Solve the whole-path problems and check the result: :func:`plan_path`, :class:`Plan`.

The plan is computed on the controller's model (``capsule_model``: the configured
force model and the learned friction law if configured, with c(v)'s range clamped
smoothly, :data:`~capsule_mpc.friction.C_RANGE_SMOOTHING_MPS`), never the plant.
Every solve reports status, iterations and wall time; a failed solve is a
:class:`Plan` with ``success = False``, not an exception. Two independent
checks come with it:

* :func:`dynamics_residual` -- re-solves every step's implicit Euler equation from the
  step's start state (Newton root finding, independently of the NLP) and compares with the
  planned next state; it never raises;
* :func:`constraint_report` -- the planned speeds, accelerations, workspace
  margins, coupling, normal forces and path errors, to compare with the limits.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import casadi as ca
import numpy as np
from tqdm import tqdm

from ..config import Scenario
from ..dynamics import N_INPUTS, N_STATES, capsule_model
from ..errors import PlanError
from ..friction import C_RANGE_SMOOTHING_MPS
from ..interrupt import interrupted, interruptible, raise_if_interrupted, run_interruptibly, solver_call
from ..magnetics import model_equilibrium_lead
from ..paths import ReferencePath
from .problem import PlannerOptions, PlanNLP, build_fixed_nlp, build_min_time_nlp

__all__ = [
    "VARIANTS",
    "Plan",
    "PlanError",
    "PlanResidual",
    "cached_plan",
    "constraint_report",
    "dynamics_residual",
    "model_equilibrium_lead",
    "plan_path",
]

#: The planner's problem variants.
VARIANTS = ("fixed", "min_time")
#: IPOPT return statuses that give a converged plan.
_IPOPT_OK = {"Solve_Succeeded", "Solved_To_Acceptable_Level"}
#: Scales of the residual's dimensionless maximum: 1 mm for positions, 1 cm/s for velocities.
_RESIDUAL_POSITION_SCALE_M = 1e-3
_RESIDUAL_VELOCITY_SCALE_MPS = 1e-2
#: Newton's absolute tolerance on a step's equation, and the defect above which a step counts
#: as not solved (physical units of the state: m, m/s).
_ROOT_TOL = 1e-12
_ROOT_DEFECT_TOL = 1e-9
#: The progress bar: IPOPT's iterations so far (the total is not known in advance).
_BAR_FORMAT = "{desc}: {n_fmt} iterations [{elapsed}{postfix}]"
#: Redraw period of the progress bar, s.
_TICK_S = 0.5


@dataclass(frozen=True)
class PlanResidual:
    """Largest difference between the plan and an independent integration of each step.

    Attributes
    ----------
    position_m : float
        Capsule position, m.
    velocity_mps : float
        Capsule velocity, m/s.
    epm_m : float
        EPM position (x, y, height), m.
    reseeded_steps : int
        Steps whose root finding did not converge from the step's start state and was solved
        again from the plan's own next state (the check then says whether that state solves the
        step's equation, not whether it is the root nearest the start).
    unsolved_steps : int
        Steps whose equation no root finding solved; their difference is to the best iterate.
    """

    position_m: float
    velocity_mps: float
    epm_m: float
    reseeded_steps: int = 0
    unsolved_steps: int = 0

    @property
    def scaled(self) -> float:
        """The largest of the three in units of 1 mm and 1 cm/s (dimensionless)."""
        return max(
            self.position_m / _RESIDUAL_POSITION_SCALE_M,
            self.velocity_mps / _RESIDUAL_VELOCITY_SCALE_MPS,
            self.epm_m / _RESIDUAL_POSITION_SCALE_M,
        )


@dataclass(frozen=True)
class Plan:
    """A planned EPM trajectory and the capsule motion the model predicts for it.

    Knot k is at ``t_s[k] = k dt_s``; the EPM velocity ``epm_velocity_mps[k]`` is applied over
    ``[t_k, t_{k+1})`` (zero after the last knot: the EPM ends at rest).

    Attributes
    ----------
    variant : {'fixed', 'min_time'}
        Which problem was solved.
    t_s : numpy.ndarray (N+1,)
        Knot times from the start of the motion, s.
    epm_position_m : numpy.ndarray (N+1, 3)
        EPM (x, y, height), m.
    epm_velocity_mps : numpy.ndarray (N, 3)
        EPM velocity per step, m/s.
    capsule_position_m, capsule_velocity_mps : numpy.ndarray (N+1, 2)
        Predicted capsule position (m) and velocity (m/s).
    slack : numpy.ndarray (N, 2)
        Coupling (fraction of max_lead^2) and normal-force (N) slacks; zero when the
        constraints hold exactly.
    progress_m : numpy.ndarray (N+1,) or None
        Arc-length progress variable of the minimum-time plan, m.
    dt_s : float
        Step, s.
    nominal_duration_s : float
        The path's length over its nominal speed, s.
    lead_eq_m : numpy.ndarray (2,)
        The model's equilibrium lead (the coupling constraint's centre), m.
    force_model : str
        The controller model's force model ('dipole' or 'lookup').
    success : bool
        Whether IPOPT converged to a finite solution.
    status : str
        IPOPT's return status.
    iterations : int
        IPOPT iterations.
    build_s, solve_s : float
        Wall time to build the NLP and solver, and to solve it, s.
    residual : PlanResidual or None
        :func:`dynamics_residual` of the plan (None if not checked).
    """

    variant: str
    t_s: np.ndarray
    epm_position_m: np.ndarray
    epm_velocity_mps: np.ndarray
    capsule_position_m: np.ndarray
    capsule_velocity_mps: np.ndarray
    slack: np.ndarray
    progress_m: np.ndarray | None
    dt_s: float
    nominal_duration_s: float
    lead_eq_m: np.ndarray
    force_model: str
    success: bool
    status: str
    iterations: int
    build_s: float
    solve_s: float
    residual: PlanResidual | None = field(default=None)

    @property
    def n_steps(self) -> int:
        """N, the number of steps."""
        return int(self.epm_velocity_mps.shape[0])

    @property
    def duration_s(self) -> float:
        """The plan's end time T, s."""
        return float(self.t_s[-1])

    @property
    def max_residual(self) -> float:
        """:attr:`PlanResidual.scaled` (1 mm / 1 cm/s units); NaN if not checked."""
        return math.nan if self.residual is None else self.residual.scaled

    @property
    def failure(self) -> str:
        """Why the solve failed, in words ("" if it succeeded)."""
        if self.success:
            return ""
        return (
            f"the {self.variant} plan did not converge: IPOPT returned {self.status} after "
            f"{self.iterations} iterations ({self.solve_s:.1f} s, {self.n_steps} steps)"
        )

    def states(self) -> np.ndarray:
        """The model's states ``(p, v, e_xy, h)`` at every knot, (7, N+1)."""
        return np.vstack([self.capsule_position_m.T, self.capsule_velocity_mps.T, self.epm_position_m.T])

    def epm_position_at(self, t_s: float | np.ndarray) -> np.ndarray:
        """EPM position at time(s) ``t_s`` (linear between knots, held outside), m; (3,) or (M, 3)."""
        t = np.asarray(t_s, dtype=float)
        cols = [np.interp(t, self.t_s, self.epm_position_m[:, i]) for i in range(3)]
        return np.stack(cols, axis=-1)

    def epm_velocity_at(self, t_s: float) -> np.ndarray:
        """Planned EPM velocity at ``t_s`` (zero outside the plan), m/s (3,)."""
        if not 0.0 <= t_s < self.duration_s:
            return np.zeros(3)
        k = min(int(t_s / self.dt_s), self.n_steps - 1)
        return np.asarray(self.epm_velocity_mps[k], dtype=float).copy()


class _IterationMonitor(ca.Callback):
    """IPOPT iteration callback: stops the solve on Ctrl-C (IPOPT returns ``User_Requested_Stop``,
    and :func:`~capsule_mpc.interrupt.solver_call` raises), and ticks the progress bar once per
    iteration with the objective and the iterate's largest constraint violation (scaled NLP units).
    """

    def __init__(self, pnlp: PlanNLP, bar: Any) -> None:
        ca.Callback.__init__(self)
        self.bar = bar
        self.started = False  # the first call is IPOPT's iteration 0, the initial point
        self.lbg, self.ubg = pnlp.lbg, pnlp.ubg
        self.nx, self.ng = int(pnlp.w0.size), int(pnlp.lbg.size)
        self.construct("plan_progress", {})

    def get_n_in(self) -> int:
        return int(ca.nlpsol_n_out())

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return str(ca.nlpsol_out(i))

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        size = {"f": 1, "x": self.nx, "lam_x": self.nx, "g": self.ng, "lam_g": self.ng}
        n = size.get(str(ca.nlpsol_out(i)), 0)
        return ca.Sparsity.dense(n, 1) if n else ca.Sparsity(0, 0)

    def eval(self, arg: Sequence[ca.DM]) -> list[int]:
        if interrupted():
            return [1]  # nonzero: IPOPT stops after this iteration
        if self.bar.disable:
            return [0]
        out = dict(zip(ca.nlpsol_out(), arg, strict=True))
        g = np.asarray(out["g"]).ravel()
        violation = max(float(np.max(self.lbg - g, initial=0.0)), float(np.max(g - self.ubg, initial=0.0)))
        self.bar.set_postfix_str(f"objective {float(out['f']):.4g}, violation {violation:.1e}", refresh=False)
        self.bar.update(1 if self.started else 0)
        self.started = True
        return [0]


@contextmanager
def _progress_bar(variant: str, enabled: bool) -> Iterator[Any]:
    """The planner's progress bar on stderr (a disabled one if not ``enabled``).

    A thread redraws it every :data:`_TICK_S` so that its elapsed time runs on through the
    NLP's construction and between IPOPT's iterations: both are long CasADi calls, which
    release the GIL (measured: a 0.2 s ticker kept its pace through a 15 s ``nlpsol`` build).
    """
    bar = tqdm(desc=f"plan ({variant})", disable=not enabled, leave=False, bar_format=_BAR_FORMAT)
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(_TICK_S):
            bar.refresh()

    ticker = threading.Thread(target=tick, name="plan-progress", daemon=True)
    if enabled:
        ticker.start()
    try:
        yield bar
    finally:
        stop.set()
        try:  # Ctrl-C may land here (the solve just ended): the bar is still cleared
            if enabled:
                ticker.join()
        finally:
            bar.close()


def _ipopt_solver(pnlp: PlanNLP, options: PlannerOptions, callback: ca.Callback | None = None) -> ca.Function:
    ipopt = {"print_level": 0, "sb": "yes", "max_iter": options.max_iter, "tol": options.tol}
    opts: dict[str, Any] = {"print_time": False, "error_on_fail": False, "ipopt": ipopt}
    if callback is not None:
        opts["iteration_callback"] = callback
        opts["iteration_callback_ignore_errors"] = False
    # Built in a worker thread: expanding a long path's NLP takes tens of seconds in C++, which
    # would hold Ctrl-C until it ends.
    try:  # SX expansion: ~3x faster evaluations; a model that cannot be expanded stays MX
        return run_interruptibly(ca.nlpsol, "plan", "ipopt", pnlp.nlp, opts | {"expand": True})
    except RuntimeError:
        raise_if_interrupted()
        return run_interruptibly(ca.nlpsol, "plan", "ipopt", pnlp.nlp, opts)


def plan_path(
    scenario: Scenario,
    path: ReferencePath,
    variant: Literal["fixed", "min_time"] = "fixed",
    options: PlannerOptions | None = None,
    *,
    check: bool = True,
    progress: bool = False,
) -> Plan:
    """Plan the EPM trajectory for the whole path as one optimal-control problem (IPOPT).

    Parameters
    ----------
    scenario : Scenario
        Model (``force_model``, friction via :meth:`Scenario.controller_friction`), limits,
        camera rate (the fixed-time step is ``1 / camera.rate_hz``), tracking weights
        (``mpc.*_tol_*``, ``mpc.slack_weight``) and ``mpc.height_control``.
    path : ReferencePath
        The path at its nominal speed; the capsule starts at rest at its start.
    variant : {'fixed', 'min_time'}
        'fixed': track the time-parameterised reference, then stop at the end
        (duration = nominal + ``options.tail_s``). 'min_time': free final time within a
        cross-track tube of ``options.tube_m``.
    options : PlannerOptions, optional
        Planner settings (defaults: :class:`PlannerOptions`).
    check : bool
        Compute :func:`dynamics_residual` of the solution (a few ms per 100 steps).
    progress : bool
        Show a progress bar on stderr while the NLP is built and solved: IPOPT's iterations, the
        elapsed time, the objective and the largest constraint violation of the iterate.

    Returns
    -------
    Plan
        With ``success``, ``status``, ``iterations`` and the wall times; a failed solve still
        returns the last iterate (check ``success``).

    Raises
    ------
    ValueError
        An unknown variant.
    KeyboardInterrupt
        On Ctrl-C during the solve, even though IPOPT (via CasADi) swallows it
        (:func:`capsule_mpc.interrupt.interruptible`): an interrupt is never reported as a failed plan.
    """
    if variant not in VARIANTS:
        raise ValueError(f"variant: must be one of {list(VARIANTS)}, got {variant!r}")
    options = options if options is not None else PlannerOptions()
    with _progress_bar(variant, progress) as bar, interruptible():
        bar.set_postfix_str("building the NLP", refresh=progress)
        t0 = time.perf_counter()
        model = capsule_model(scenario, range_smoothing_mps=C_RANGE_SMOOTHING_MPS)
        lead_eq = model_equilibrium_lead(scenario)
        if variant == "fixed":
            pnlp = build_fixed_nlp(model, path, lead_eq, 1.0 / scenario.camera.rate_hz, options)
        else:
            pnlp = build_min_time_nlp(model, path, lead_eq, options)
        monitor = _IterationMonitor(pnlp, bar)
        raise_if_interrupted()  # CasADi catches a KeyboardInterrupt raised in the callbacks of construct()
        solver = _ipopt_solver(pnlp, options, monitor)
        build_s = time.perf_counter() - t0
        bar.set_postfix_str(f"IPOPT on {pnlp.w0.size} variables, {pnlp.n_steps} steps", refresh=progress)
        t1 = time.perf_counter()
        with solver_call():  # Ctrl-C: KeyboardInterrupt, never a failed plan
            sol = solver(x0=pnlp.w0, lbx=pnlp.lbw, ubx=pnlp.ubw, lbg=pnlp.lbg, ubg=pnlp.ubg)
        solve_s = time.perf_counter() - t1
        stats = solver.stats()
        w = np.asarray(sol["x"]).ravel()
    status = str(stats.get("return_status", "unknown"))
    parts = pnlp.unpack(w)
    xs, us, ss = (np.asarray(parts[k]) for k in ("X", "U", "S"))
    n = pnlp.n_steps
    dt = float(parts["T"]) / n
    plan = Plan(
        variant=variant,
        t_s=dt * np.arange(n + 1),
        epm_position_m=xs[4:7].T.copy(),
        epm_velocity_mps=us.T.copy(),
        capsule_position_m=xs[0:2].T.copy(),
        capsule_velocity_mps=xs[2:4].T.copy(),
        slack=ss.T.copy(),
        progress_m=np.asarray(parts["sigma"]) if "sigma" in parts else None,
        dt_s=dt,
        nominal_duration_s=path.duration_s,
        lead_eq_m=lead_eq,
        force_model=model.force_model,
        success=status in _IPOPT_OK and bool(np.all(np.isfinite(w))),
        status=status,
        iterations=int(stats.get("iter_count", 0)),
        build_s=build_s,
        solve_s=solve_s,
    )
    if check and np.all(np.isfinite(w)):
        plan = replace(plan, residual=dynamics_residual(scenario, plan))
    return plan


def dynamics_residual(scenario: Scenario, plan: Plan) -> PlanResidual:
    """Re-solve every step of ``plan`` independently and compare with its next state.

    Each step's implicit Euler equation ``z = x_k + dt f(z, u_k)`` on the planner's model is
    solved for ``z`` by Newton's method (CasADi ``rootfinder``) from the step's start state
    ``x_k``, never from the NLP's solution. Where that does not converge (the smoothed friction
    makes the equation stiff near stick), the step is solved again from the plan's own next
    state; a step that neither start solves is compared with the better iterate. Root-finding
    failures are counted in the result, never raised.

    Parameters
    ----------
    scenario : Scenario
        The scenario the plan was computed for.
    plan : Plan
        The plan to check.

    Returns
    -------
    PlanResidual
        Largest absolute differences of capsule position (m), velocity (m/s) and EPM position
        (m), and how many steps needed the second start or stayed unsolved.
    """
    model = capsule_model(scenario, range_smoothing_mps=C_RANGE_SMOOTHING_MPS)
    z, x, u = ca.MX.sym("z", N_STATES), ca.MX.sym("x", N_STATES), ca.MX.sym("u", N_INPUTS)
    equation = ca.Function("plan_step", [z, x, u], [z - x - plan.dt_s * model.ode(z, u)])
    # Newton on the 7-state step is cheap and, with error_on_fail off, returns its last iterate
    # silently; convergence is judged below from the equation's own defect.
    root = ca.rootfinder(
        "plan_step_root", "newton", equation, {"abstol": _ROOT_TOL, "max_iter": 50, "error_on_fail": False}
    )
    n = plan.n_steps
    xs, us = plan.states(), plan.epm_velocity_mps.T
    start, target = xs[:, :-1], xs[:, 1:]
    defect = equation.map(n)

    def solve(guess: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        with np.errstate(invalid="ignore"):
            z_k = np.asarray(root.map(n)(guess, start, us))
            d_k = np.abs(np.asarray(defect(z_k, start, us))).max(axis=0)
        return z_k, np.where(np.isfinite(d_k), d_k, np.inf)

    nxt, err = solve(start)
    failed = err > _ROOT_DEFECT_TOL
    if failed.any():
        again, err2 = solve(target)
        better = failed & (err2 < err)
        nxt[:, better] = again[:, better]
        err = np.where(better, err2, err)
    unsolved = err > _ROOT_DEFECT_TOL
    diff = np.abs(nxt - target)
    diff[~np.isfinite(diff)] = np.inf
    return PlanResidual(
        position_m=float(diff[0:2].max()),
        velocity_mps=float(diff[2:4].max()),
        epm_m=float(diff[4:7].max()),
        reseeded_steps=int(failed.sum() - unsolved.sum()),
        unsolved_steps=int(unsolved.sum()),
    )


def constraint_report(scenario: Scenario, plan: Plan, path: ReferencePath) -> dict[str, float]:
    """The plan's figures that the limits bound, to compare with ``scenario.limits``.

    Returns
    -------
    dict of str to float
        ``max_speed_mps`` (largest per-axis EPM speed), ``max_accel_mps2`` (largest per-axis
        velocity change per step over dt, from rest at the start and to rest at the end),
        ``workspace_violation_m`` (largest distance outside the workspace box, 0 inside),
        ``max_coupling_m`` (largest ``|lead - lead_eq|``), ``min_normal_force_n``,
        ``max_normal_force_n``, ``max_slack`` (largest slack), ``cross_track_max_m`` and
        ``cross_track_rms_m`` (capsule knots to the path), ``end_error_m`` and
        ``end_speed_mps`` (capsule at the last knot), ``arrival_s`` (first knot from which the
        capsule stays within ``sim.completion_tol_m`` of the path's end, the runner's completion
        tolerance) and ``duration_s``.
    """
    lim = scenario.limits
    u = plan.epm_velocity_mps
    du = np.diff(np.vstack([np.zeros(3), u, np.zeros(3)]), axis=0)
    e = plan.epm_position_m
    lo, hi = np.asarray(lim.workspace_min_m), np.asarray(lim.workspace_max_m)
    outside = np.maximum(np.maximum(lo - e, e - hi), 0.0)
    outputs = capsule_model(scenario, range_smoothing_mps=C_RANGE_SMOOTHING_MPS).outputs.map(plan.n_steps + 1)
    lead, _force, f_n, _mu = (np.asarray(v) for v in outputs(plan.states()))
    coupling = np.linalg.norm(lead - plan.lead_eq_m[:, None], axis=0)
    cross = path.distance_to(plan.capsule_position_m)
    near_end = np.linalg.norm(plan.capsule_position_m - path.end_m, axis=1) <= scenario.sim.completion_tol_m
    away = np.flatnonzero(~near_end)
    if away.size == 0:
        arrival = 0.0
    elif away[-1] == plan.n_steps:  # not at the end at the last knot
        arrival = math.nan
    else:
        arrival = float(plan.t_s[away[-1] + 1])
    return {
        "max_speed_mps": float(np.abs(u).max()),
        "max_accel_mps2": float(np.abs(du).max() / plan.dt_s),
        "workspace_violation_m": float(outside.max()),
        "max_coupling_m": float(coupling.max()),
        "min_normal_force_n": float(f_n.min()),
        "max_normal_force_n": float(f_n.max()),
        "max_slack": float(plan.slack.max()),
        "cross_track_max_m": float(cross.max()),
        "cross_track_rms_m": float(np.sqrt(np.mean(cross**2))),
        "end_error_m": float(np.linalg.norm(plan.capsule_position_m[-1] - path.end_m)),
        "end_speed_mps": float(np.linalg.norm(plan.capsule_velocity_mps[-1])),
        "arrival_s": arrival,
        "duration_s": plan.duration_s,
    }


_CACHE: dict[tuple[Any, ...], Plan] = {}


def cached_plan(
    scenario: Scenario,
    path: ReferencePath,
    variant: Literal["fixed", "min_time"] = "fixed",
    options: PlannerOptions | None = None,
    *,
    progress: bool = False,
) -> Plan:
    """:func:`plan_path`, memoised in this process by scenario, path, variant and options.

    ``progress`` shows :func:`plan_path`'s progress bar when the plan is not cached yet.
    """
    options = options if options is not None else PlannerOptions()
    key = (
        scenario.model_dump_json(exclude={"sim", "name"}),
        path.waypoints_m.tobytes(),
        path.closed,
        path.speed_mps,
        variant,
        options,
    )
    if key not in _CACHE:
        _CACHE[key] = plan_path(scenario, path, variant, options, progress=progress)
    return _CACHE[key]
