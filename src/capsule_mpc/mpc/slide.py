"""The sliding MPC: one receding-horizon step per frame, and the phases it commands.

:func:`solve_step` is the step as a pure function of the estimated state, the reference window,
the parameters (the command being applied and its slope, the disturbance) and the warm start: it
solves the NLP warm-started from the shifted previous plan (the first frame, or one after the plan
ran out, is solved to convergence by IPOPT); if the fast step failed it is accepted anyway while the
rig holds the EPM (its command is 0 whatever the plan), else recovered by a few SQP iterations with
line search on the same structure (``mpc.recovery_sqp_iter``).

:class:`SlideProducer` keeps the plan between frames: it takes the first command of a plan solved
in time, or -- on a failed, non-finite or late solve -- the shifted previous plan's, or else a
braking command (a recovery that ran out of iterations leaves its last iterate as the next frame's
warm start). Each frame it first folds the velocity the plan predicted for now into the estimator's
disturbance. :class:`SettleProducer` runs the same step before t = 0 and sends 0.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..config import MPCConfig
from ..interfaces import StepOutcome, StepStats
from .estimator import StateEstimator
from .phases import FrameContext, PhaseOutput
from .problem import OCP
from .reference import SlideReference
from .solver import MPCSolver, SolveResult

__all__ = ["Plan", "SettleProducer", "SlideProducer", "solve_step"]

#: Time the controller's step takes besides the solve (estimation, reference, safety layer), ms:
#: the SQP recovery of a paced loop leaves it free (measured ~0.3 ms at N = 20, 0.5 with margin).
_REST_OF_STEP_MS = 0.5


@dataclass
class Plan:
    """A solved plan and how many frames ago it was solved.

    ``xs`` (7 x N, stages 1..N) and ``us`` (3 x N) stay as solved, on the OCP's stage times
    ``times`` (0..N, s); ``w`` is the warm start, shifted frame by frame (:meth:`OCP.shift`).
    """

    w: np.ndarray
    lam_x: np.ndarray | None
    lam_g: np.ndarray | None
    xs: np.ndarray
    us: np.ndarray
    times: np.ndarray
    age: int = 0

    def command(self, t_s: float) -> np.ndarray:
        """The command the plan sends for the frame that ends ``t_s`` after it was solved: its
        velocity command at that time, linear over each stage (the command's slope is constant
        over a stage, so a frame inside a longer stage sends the ramp's point), held after the
        last stage."""
        times = self.times[1:]
        return np.array([np.interp(t_s, times, row) for row in self.us])

    def state(self, t_s: float) -> np.ndarray:
        """The model state the plan predicts ``t_s`` (>= the first stage's end) after it was
        solved: a stage's own where ``t_s`` is one (within 1 ns), else interpolated linearly."""
        times = self.times[1:]
        k = int(np.searchsorted(times, t_s - 1e-9))
        if k < len(times) and abs(times[k] - t_s) <= 1e-9:
            return self.xs[:, k]
        return np.array([np.interp(t_s, times, row) for row in self.xs])


def solve_step(
    solver: MPCSolver,
    ocp: OCP,
    x0: np.ndarray,
    ref: np.ndarray,
    params: tuple[np.ndarray, np.ndarray, np.ndarray],
    plan: Plan | None,
    held: bool,
    recovery: tuple[int, float | None],
) -> tuple[SolveResult, StepOutcome]:
    """One frame's solve and what it came to if it succeeds (solved, recovered or held).

    Parameters
    ----------
    solver, ocp : MPCSolver, OCP
        The built solver and its problem.
    x0 : numpy.ndarray (7,)
        The estimated state: capsule position and velocity, EPM position (m, m/s).
    ref : numpy.ndarray (7 x N)
        The reference window (:meth:`SlideReference.window`).
    params : tuple of numpy.ndarray
        The command being applied (3, m/s), its slope (3, m/s^2) and the disturbance (3, N).
    plan : Plan or None
        The previous plan (its shifted ``w`` and multipliers warm-start the step); None: solve to
        convergence from everything standing still.
    held : bool
        The rig holds the EPM (t < 0): a failed step is kept as the next frame's warm start.
    recovery : tuple of int and float or None
        ``mpc.recovery_sqp_iter`` and the frame's deadline, ms (None: not enforced).
    """
    u_prev, slope_prev, dist = params
    p = ocp.pack_parameters(x0, ref, u_prev, dist, slope_prev)
    if plan is None:
        n = ocp.horizon
        held_u = np.tile(u_prev[:, None], (1, n))
        guess = ocp.pack_variables(np.tile(x0[:, None], (1, n)), held_u, np.zeros((2, n)), x0, u_prev)
        return solver.solve_converged(p, guess), StepOutcome.SOLVED
    guess = ocp.shift(plan.w)
    res = solver.solve(p, guess, plan.lam_x, plan.lam_g)
    if res.success or solver.scheme == "ipopt":
        return res, StepOutcome.SOLVED
    if held and np.all(np.isfinite(res.w)):
        # The command is 0 whatever the plan says: the step only warm-starts the next frame, and
        # the next frames absorb its violation (typically the friction's sign change of a capsule
        # at rest).
        return replace(res, success=True, status=f"held ({res.status})"), StepOutcome.HELD
    iterations, deadline_ms = recovery
    if iterations == 0 or solver.scheme != "rti":
        return res, StepOutcome.SOLVED
    # The RTI step failed: a few SQP iterations with line search from the same guess (counted in
    # the time). Paced by the wall clock they stop in time for the frame's deadline.
    budget = None if deadline_ms is None else deadline_ms - res.solve_ms - _REST_OF_STEP_MS
    rec = solver.sqp(p, guess, iterations, budget)
    status = f"recovered ({res.status})" if rec.success else f"{res.status}; {rec.status}"
    return replace(
        rec, status=status, iterations=res.iterations + rec.iterations, solve_ms=res.solve_ms + rec.solve_ms
    ), StepOutcome.RECOVERED


class SlideProducer:
    """The sliding MPC of one run: the ``SLIDE`` phase's producer (see the module docstring).

    Parameters
    ----------
    solver, ocp : MPCSolver, OCP
        The built solver (possibly wrapped, e.g. by fault injection) and its problem.
    cfg : MPCConfig
        The ``mpc`` section (recovery and deadline).
    estimator : StateEstimator
        The run's estimator (its disturbance is updated here).
    reference : SlideReference
        The run's reference.
    dt_s : float
        The frame period, s.
    """

    def __init__(
        self,
        solver: MPCSolver,
        ocp: OCP,
        cfg: MPCConfig,
        estimator: StateEstimator,
        reference: SlideReference,
        dt_s: float,
    ) -> None:
        self.solver, self.ocp, self.cfg = solver, ocp, cfg
        self.estimator, self.reference, self.dt_s = estimator, reference, dt_s
        self.deadline_ms = cfg.deadline_ms if cfg.deadline_ms is not None else 1e3 * dt_s
        self.plan: Plan | None = None
        self.last_prediction: np.ndarray | None = None
        #: Frames that fell back on the previous plan or a stop, and solves later than the deadline.
        self.counts = {"fallback": 0, "deadline_misses": 0}

    def observe(self, ctx: FrameContext) -> None:
        """Nothing to keep (the plan is kept by :meth:`produce`)."""

    def drop_plan(self) -> None:
        """Forget the plan (another phase commands the EPM; the next solve starts from scratch)."""
        self.plan = None
        self.last_prediction = None

    def _solve(self, ctx: FrameContext) -> tuple[SolveResult, StepOutcome]:
        x0 = np.concatenate([ctx.position_m, ctx.velocity_mps, ctx.epm_m])
        drag = self.reference.drag_growth_n(ctx.t_s)
        plan = self.plan
        # A dropped or rejected frame teaches nothing, and nor does the settle phase: the rig holds
        # the EPM, so the plan's commands were replaced by 0 and its predicted motion never had a
        # chance (the rest calibration learns from it instead).
        if ctx.measured and plan is not None and ctx.t_s >= 0:
            v_pred = plan.state((plan.age + 1) * self.dt_s)[2:4]
            self.estimator.update_disturbance(ctx.velocity_mps, v_pred)
        # The model's drag grows with the tether paid out: its growth so far joins the estimated
        # extra friction (both oppose the motion), a feed-forward the estimator need not learn.
        dist = self.estimator.disturbance_n + np.array([0.0, 0.0, drag])
        deadline = self.deadline_ms if self.cfg.enforce_deadline else None
        params = (ctx.u_prev_mps, ctx.slope_prev_mps2, dist)
        recovery = (self.cfg.recovery_sqp_iter, deadline)
        ref = self.reference.window(ctx.t_s)
        return solve_step(self.solver, self.ocp, x0, ref, params, plan, ctx.t_s < 0, recovery)

    def produce(self, ctx: FrameContext) -> PhaseOutput:
        """Solve, then send the new plan's first command, or fall back (see the module docstring)."""
        res, outcome = self._solve(ctx)
        if res.success and not np.all(np.isfinite(res.w)):  # a solver that says so is not trusted
            res = replace(res, success=False, status=f"non-finite solution ({res.status})")
        late = res.solve_ms > self.deadline_ms and self.plan is not None
        self.counts["deadline_misses"] += int(late)
        late = late and self.cfg.enforce_deadline
        d = self.estimator.disturbance_n
        stats = StepStats(
            solve_ms=res.solve_ms,
            status=res.status,
            iterations=res.iterations,
            outcome=outcome,
            extra={
                "disturbance_x_n": float(d[0]),
                "disturbance_y_n": float(d[1]),
                "disturbance_friction_n": float(d[2]),
            },
        )
        if not res.success:
            stats.failed, stats.outcome, stats.status = True, StepOutcome.FAILED, "failed: " + res.status
            u = self._fallback_command()
            if res.solver == "sqp" and self.plan is not None and np.all(np.isfinite(res.w)):
                # A recovery that ran out of iterations: its iterate (each line search lowered the
                # merit from the shifted plan's) warm-starts the next frame, whose step goes on
                # with the repair; restarting from the shifted plan would repeat the failed step.
                self.plan.w = res.w
            return PhaseOutput(u, stats)
        xs, us, _ = self.ocp.unpack(res.w)
        new_plan = Plan(res.w, res.lam_x, res.lam_g, xs, us, self.ocp.node_times_s)
        if not late:
            self.plan = new_plan
            self.last_prediction = xs[0:2].T.copy()
            return PhaseOutput(us[:, 0], stats)
        # Late: this frame's command comes from the previous plan (the new one arrived too late to
        # be sent), but the new solution is the better warm start for the next frame -- dropping
        # it makes the next step start cold and be late again.
        stats.failed, stats.outcome, stats.status = True, StepOutcome.LATE, "late: " + res.status
        u = self._fallback_command()
        self.plan = new_plan
        return PhaseOutput(u, stats)

    def _fallback_command(self) -> np.ndarray:
        """The previous plan's command for now while the plan lasts (it predicts the next frame),
        else brake. The warm start is shifted by the frame that passed (the plan's command for it
        was applied), so it stays aligned with time for the next solve."""
        self.counts["fallback"] += 1
        plan = self.plan
        if plan is not None and (plan.age + 2) * self.dt_s < plan.times[-1] + 1e-9:
            plan.age += 1
            plan.w = self.ocp.shift(plan.w)
            plan.lam_x = plan.lam_g = None
            return plan.command((plan.age + 1) * self.dt_s)
        self.plan = None
        return np.zeros(3)  # braking target; the safety layer limits the deceleration


class SettleProducer:
    """The ``SETTLE`` phase (t < 0): the rig holds the EPM, so the command is 0; the sliding MPC
    solves anyway (to stay at the start), so its plan is warm at t = 0."""

    def __init__(self, slide: SlideProducer) -> None:
        self.slide = slide

    def observe(self, ctx: FrameContext) -> None:
        """Nothing to keep."""

    def produce(self, ctx: FrameContext) -> PhaseOutput:
        """The MPC's step with its command replaced by 0."""
        out = self.slide.produce(ctx)
        return replace(out, command=np.zeros(3))
