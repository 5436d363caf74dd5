"""The MPC controller: estimation, the receding-horizon solve, and a safety layer.

Every frame:

1. fuse the camera frame in the Kalman filter, predict over the latency;
2. update the force-disturbance estimate (offset-free MPC): the velocity the
   last plan predicted for now vs the estimate;
3. solve the NLP warm-started from the shifted previous solution (the first frame, or one
   after the plan ran out, is solved to convergence by IPOPT);
4. if the fast step failed: accept it anyway while the rig holds the EPM (the settle phase:
   the command is 0 whatever the plan), else recover with a few SQP iterations with line
   search on the same structure (``mpc.recovery_sqp_iter``);
5. take the first command, or -- on a failed, non-finite or late solve -- the
   shifted previous plan, or else a braking command (a recovery that ran out of iterations
   leaves its last iterate as the next frame's warm start);
6. pass it through the safety layer: speed, acceleration and workspace limits
   are enforced on the command actually sent (and any clipping is counted).

After the path's nominal end the final approach (:mod:`.approach`) may take over from step 2
on: when the MPC has left the capsule slow and off the final waypoint, it crawls it on below
breakaway, lets go and checks; its commands pass the same safety layer, and the controller is
not :attr:`finished` (the run does not end at rest) until the approach is over.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

from ..config import Scenario
from ..dynamics import CapsuleModel, capsule_model
from ..estimation import CapsuleEstimator
from ..friction import FrictionBelief
from ..interfaces import Command, Controller, Measurement, StepOutcome, StepStats, register_controller
from ..magnetics import cache_directory, capsule_force_function, model_equilibrium_lead
from ..paths import ReferencePath
from ..planner import cached_plan
from ..safety import safe_command
from .approach import FinalApproach
from .contact import RestDetector
from .grid import prediction_steps_s
from .problem import N_DIST, OCP, build_ocp
from .solver import MPCSolver, SolveResult
from .start import StartPreload

__all__ = ["MPCController", "MPCStack", "build_mpc_stack", "model_scenario", "safe_command"]


#: Time the controller's step takes besides the solve (estimation, reference, safety layer), ms:
#: the SQP recovery of a paced loop leaves it free (measured ~0.3 ms at N = 20, 0.5 with margin).
_REST_OF_STEP_MS = 0.5
#: Speed above which the velocity innovation is attributed to friction along the motion, m/s.
_MOVING_MPS = 2e-3


@dataclass
class MPCStack:
    """The built problem and solver, reusable across runs of the same scenario."""

    ocp: OCP
    solver: MPCSolver
    build_s: float
    force: ca.Function
    model: CapsuleModel


_STACKS: dict[str, MPCStack] = {}


def model_scenario(scenario: Scenario) -> Scenario:
    """The scenario the controller's model is built from: ``scenario`` with the friction smoothing
    of ``mpc.friction_smoothing_eps_mps`` (when set)."""
    eps = scenario.mpc.friction_smoothing_eps_mps
    if eps is None or eps == scenario.friction.smoothing_eps_mps:
        return scenario
    friction = scenario.friction.model_copy(update={"smoothing_eps_mps": eps})
    return scenario.model_copy(update={"friction": friction})


def build_mpc_stack(scenario: Scenario) -> MPCStack:
    """Build (or reuse, within the process) the OCP and solver for ``scenario``."""
    # The camera's rate sets the first stage; its noise and latency leave the problem alone.
    key = scenario.model_dump_json(exclude={"sim", "camera", "path", "name", "faults"})
    key += f"|frame {1.0 / scenario.camera.rate_hz!r}"
    if key in _STACKS:
        return _STACKS[key]
    t0 = time.perf_counter()
    cfg = scenario.mpc
    steps = prediction_steps_s(scenario)  # one frame, then mpc.dt_s
    model = capsule_model(model_scenario(scenario))
    force = capsule_force_function(scenario)
    lead_eq = model_equilibrium_lead(scenario)
    ocp = build_ocp(model, float(steps[-1]), lead_eq, float(steps[0]))
    compile_dir = cache_directory(scenario) / "mpc" if cfg.compile_c else None
    try:
        solver = MPCSolver(ocp, cfg.scheme, cfg.max_sqp_iter, cfg.max_ipopt_iter, compile_dir, cfg.qp_solver)
    except (OSError, RuntimeError) as exc:  # no C compiler, or it failed: run uncompiled
        if compile_dir is None:
            raise
        warnings.warn(f"mpc.compile_c: compiling the NLP failed ({exc}); running uncompiled", stacklevel=2)
        solver = MPCSolver(ocp, cfg.scheme, cfg.max_sqp_iter, cfg.max_ipopt_iter, None, cfg.qp_solver)
    stack = MPCStack(ocp, solver, time.perf_counter() - t0, force, model)
    _STACKS[key] = stack
    return stack


@dataclass
class _Plan:
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


@register_controller("mpc")
class MPCController(Controller):
    """Receding-horizon control of the EPM velocity (see the module docstring)."""

    name = "mpc"

    def __init__(self) -> None:
        self.stack: MPCStack | None = None

    def reset(self, scenario: Scenario, path: ReferencePath, epm_position_m: np.ndarray) -> None:
        """Build (or reuse) the problem for ``scenario`` and forget the previous run."""
        self.scenario = scenario
        self.path = path
        self._use_stack(build_mpc_stack(scenario))
        assert self.stack is not None
        cfg = scenario.mpc
        # The frame period: the first stage of the plan, the time between commands.
        self.dt_s = self.stack.ocp.frame_s
        self.deadline_ms = cfg.deadline_ms if cfg.deadline_ms is not None else 1e3 * self.dt_s
        self.estimator = CapsuleEstimator(scenario.camera.noise_std_m, cfg.estimator_accel_std_mps2)
        self.disturbance_n = np.zeros(N_DIST)
        self.friction_belief = FrictionBelief.from_scenario(scenario)
        self._drag_growth_n = 0.0
        self.u_prev = np.zeros(3)
        self.slope_prev = np.zeros(3)  # the last command's change over its frame, m/s^2
        self.plan: _Plan | None = None
        self._offline_plan = None
        if cfg.feedforward == "plan":
            offline = cached_plan(scenario, path)
            if offline.success:
                self._offline_plan = offline
            else:
                warnings.warn(
                    f"mpc.feedforward: the offline plan failed ({offline.status}); using the path's "
                    "velocity as feed-forward",
                    stacklevel=2,
                )
        self._started = False
        self._start_offset: np.ndarray | None = None
        self.last_prediction: np.ndarray | None = None
        self.clipped_steps = 0
        self._rest_leads: list[np.ndarray] = []
        self._calibrated = False
        self.fallback_steps = 0
        self.deadline_misses = 0
        self.approach = FinalApproach(
            scenario, path, self.stack.force, self.stack.ocp.lead_eq_m, self.dt_s, self.friction_belief
        )
        if self.approach.enabled:
            self.approach.warm_up(scenario.plate.epm_height_m)
        self._static_parts(scenario, path)

    def _static_parts(self, scenario: Scenario, path: ReferencePath) -> None:
        """The start's pre-load and its rest detector, only when configured."""
        cfg, stack = scenario.mpc, self.stack
        assert stack is not None
        used = cfg.start_preload is not None
        self.rest = RestDetector(scenario.camera.noise_std_m, _MOVING_MPS) if used else None
        self.start = None
        if self.rest is not None:
            self.start = StartPreload(
                scenario, path, stack.force, stack.ocp.lead_eq_m, self.friction_belief, self.rest, self.dt_s
            )

    def _use_stack(self, stack: MPCStack) -> None:
        """Solve with ``stack`` from now on. The stacks of a run share the problem's layout, so the
        plan and its multipliers warm-start either."""
        self.stack = stack
        wrap = self.solver_wrapper
        self.solver = stack.solver if wrap is None else wrap(stack.solver)

    # ------------------------------------------------------------------ helpers
    def _reference(self, t_s: float) -> np.ndarray:
        """Capsule position and velocity at stages 1..N and the EPM feed-forward of inputs 0..N-1."""
        ocp = self.stack.ocp  # type: ignore[union-attr]
        n = ocp.horizon
        times = t_s + ocp.node_times_s[1:]
        if t_s < 0:  # settle phase: the rig holds the EPM, so plan to stay at the start
            return np.vstack([self.path.position(np.zeros(n)).T, np.zeros((4, n))])
        pos, vel = self.path.position(times).T, self.path.velocity(times).T
        if self._start_offset is not None:
            pos, vel = self._join(times, pos, vel)
        if self._offline_plan is None:
            return np.vstack([pos, vel, vel])
        starts = times - ocp.steps_s  # input k applies from stage k's time on
        ff = np.array([self._offline_plan.epm_velocity_at(t)[:2] for t in starts]).T
        return np.vstack([pos, vel, ff])

    def _progress_m(self, t_s: float) -> float:
        """The tether paid out at ``t_s``, m: the reference's progress along the path (the capsule
        follows it within millimetres; a projection of the estimate would jump where a closed path
        passes its start again)."""
        duration = self.path.duration_s
        return self.path.length_m * min(max(t_s, 0.0) / duration, 1.0) if duration > 0 else 0.0

    def _update_disturbance(self, v_est: np.ndarray) -> None:
        cfg = self.scenario.mpc
        if self.plan is None or cfg.disturbance_gain == 0:
            return
        v_pred = self.plan.state((self.plan.age + 1) * self.dt_s)[2:4]
        mass = self.scenario.capsule.mass_kg
        # Force that would explain the velocity innovation over one frame.
        innov = cfg.disturbance_gain * mass * (v_est - v_pred) / self.dt_s
        speed = float(np.linalg.norm(v_pred))
        d = self.disturbance_n.copy()
        if float(np.linalg.norm(v_est)) < _MOVING_MPS:
            # The capsule is (nearly) at rest: static friction holds it, which is neither the
            # sliding friction nor a steady force -- learn nothing from a stuck capsule.
            return
        if speed > _MOVING_MPS:
            # Along the motion: extra friction (opposes v); across it: a constant force.
            v_hat = v_pred / speed
            along = float(innov @ v_hat)
            d[2] -= along
            d[0:2] += innov - along * v_hat
        else:
            d[0:2] += innov
        self.disturbance_n = np.clip(d, -cfg.disturbance_max_n, cfg.disturbance_max_n)

    def _calibrate_rest_offset(self, t_s: float, epm: np.ndarray, meas: Measurement) -> None:
        """Settle phase: where the capsule rests under the still EPM tells the model's force bias.

        While t < 0 the measured rest leads are collected; at t = 0 the constant disturbance
        is set to cancel the model's lateral force at their mean (the model then has its
        equilibrium where the capsule really rests). Runs without a settle phase skip this.
        """
        if t_s < 0:
            if meas.position_m is not None:
                self._rest_leads.append(epm[:2] - meas.position_m)
            return
        if self._calibrated or not self._rest_leads:
            return
        self._calibrated = True
        lead = np.mean(self._rest_leads, axis=0)
        force = np.asarray(self.stack.force(lead, epm[2])).ravel()  # type: ignore[union-attr]
        limit = self.scenario.mpc.disturbance_max_n
        self.disturbance_n[0:2] = np.clip(-force[0:2], -limit, limit)

    def _join(self, times: np.ndarray, pos: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The reference joining the path from where the capsule rested at the start.

        The offset of the rest position from the path's start fades out over
        ``mpc.start_blend_s`` (a half cosine), so the capsule breaks loose along the path and is
        steered onto it while it slides, instead of being dragged sideways out of the
        static-friction dead zone first (a breakaway across the path lurches millimetres on the
        soft axis). The run is still scored against the path itself.
        """
        blend = self.scenario.mpc.start_blend_s
        phase = np.clip(times / blend, 0.0, 1.0)
        weight = 0.5 * (1.0 + np.cos(np.pi * phase))
        rate = np.where(phase < 1.0, -0.5 * np.pi / blend * np.sin(np.pi * phase), 0.0)
        offset = self._start_offset[:, None]
        return pos + offset * weight, vel + offset * rate

    def _initial_guess(self, x0: np.ndarray) -> np.ndarray:
        """Everything standing still at the current state."""
        ocp = self.stack.ocp  # type: ignore[union-attr]
        n = ocp.horizon
        held = np.tile(self.u_prev[:, None], (1, n))
        return ocp.pack_variables(np.tile(x0[:, None], (1, n)), held, np.zeros((2, n)), x0, self.u_prev)

    def _solve(
        self, t_s: float, x0: np.ndarray, ref: np.ndarray, held: bool
    ) -> tuple[SolveResult, StepOutcome]:
        """This frame's solve and what it came to if it succeeds (solved, recovered, or held);
        ``held``: the rig holds the EPM (settle phase)."""
        stack = self.stack
        assert stack is not None
        solver = self.solver
        # The model's drag grows with the tether paid out: its growth so far joins the estimated
        # extra friction (both oppose the motion), a feed-forward the estimator need not learn.
        dist = self.disturbance_n + np.array([0.0, 0.0, self._drag_growth_n])
        plan = self.plan
        guess = None if plan is None else stack.ocp.shift(plan.w)
        p = stack.ocp.pack_parameters(x0, ref, self.u_prev, dist, self.slope_prev)
        if plan is None or guess is None:
            return solver.solve_converged(p, self._initial_guess(x0)), StepOutcome.SOLVED
        res = solver.solve(p, guess, plan.lam_x, plan.lam_g)
        if res.success or solver.scheme == "ipopt":
            return res, StepOutcome.SOLVED
        if held and np.all(np.isfinite(res.w)):
            # The command is 0 whatever the plan says: the step only warm-starts the next frame,
            # and the next frames absorb its violation (typically the friction's sign change of a
            # capsule at rest).
            return replace(res, success=True, status=f"held ({res.status})"), StepOutcome.HELD
        cfg = self.scenario.mpc
        if cfg.recovery_sqp_iter == 0 or solver.scheme != "rti":
            return res, StepOutcome.SOLVED
        # The RTI step failed: a few SQP iterations with line search from the same guess (counted
        # in the time). Paced by the wall clock they stop in time for the frame's deadline.
        budget = self.deadline_ms - res.solve_ms - _REST_OF_STEP_MS if cfg.enforce_deadline else None
        rec = solver.sqp(p, guess, cfg.recovery_sqp_iter, budget)
        status = f"recovered ({res.status})" if rec.success else f"{res.status}; {rec.status}"
        return replace(
            rec,
            status=status,
            iterations=res.iterations + rec.iterations,
            solve_ms=res.solve_ms + rec.solve_ms,
        ), StepOutcome.RECOVERED

    # ------------------------------------------------------------------ step
    def step(self, t_s: float, measurement: Measurement, epm_position_m: np.ndarray) -> Command:
        """One frame: estimate, solve, fall back if needed, and enforce the limits."""
        epm = np.asarray(epm_position_m, dtype=float)
        accepted = True
        if measurement.position_m is not None:
            accepted = self.estimator.update(measurement.capture_t_s, measurement.position_m)
        if not self.estimator.initialised:  # nothing seen yet: hold still
            return self._emit(
                np.zeros(3), epm, StepStats(status="no_measurement", outcome=StepOutcome.NO_MEASUREMENT)
            )
        if not accepted:  # an outlier rejected by the filter's gate: the prediction stands in for it
            measurement = replace(measurement, position_m=None)
        pos, vel = self.estimator.estimate(t_s)
        if t_s >= 0 and not self._started:
            self._started = True
            if self.scenario.mpc.start_blend_s > 0:
                self._start_offset = pos - self.path.start_m
        self._calibrate_rest_offset(t_s, epm, measurement)
        if self.rest is not None:
            self.rest.update(t_s, pos)
        self.approach.observe(measurement)
        u_approach = self.approach.step(t_s, epm, self.u_prev, self.disturbance_n[0:2])
        if u_approach is not None:
            return self._approach_command(u_approach, epm)
        x0 = np.concatenate([pos, vel, epm])
        self._drag_growth_n = self.friction_belief.drag_growth_n(self._progress_m(t_s))
        if measurement.position_m is not None:  # a dropped or rejected frame teaches nothing
            self._update_disturbance(vel)
        res, outcome = self._solve(t_s, x0, self._reference(t_s), held=t_s < 0)
        if res.success and not np.all(np.isfinite(res.w)):  # a solver that says so is not trusted
            res = replace(res, success=False, status=f"non-finite solution ({res.status})")
        late = res.solve_ms > self.deadline_ms and self.plan is not None
        self.deadline_misses += int(late)
        late = late and self.scenario.mpc.enforce_deadline
        stats = StepStats(
            solve_ms=res.solve_ms,
            status=res.status,
            iterations=res.iterations,
            outcome=outcome,
            extra={
                "disturbance_x_n": float(self.disturbance_n[0]),
                "disturbance_y_n": float(self.disturbance_n[1]),
                "disturbance_friction_n": float(self.disturbance_n[2]),
            },
        )
        if not accepted:
            stats.extra["measurement_rejected"] = 1.0
        if res.success:
            xs, us, _ = self.stack.ocp.unpack(res.w)  # type: ignore[union-attr]
            new_plan = _Plan(res.w, res.lam_x, res.lam_g, xs, us, self.stack.ocp.node_times_s)  # type: ignore[union-attr]
            if not late:
                self.plan = new_plan
                self.last_prediction = xs[0:2].T.copy()
                return self._send(us[:, 0], epm, stats, t_s)
            # Late: this frame's command comes from the previous plan (the new one arrived too
            # late to be sent), but the new solution is the better warm start for the next
            # frame -- dropping it makes the next step start cold and be late again.
            stats.failed, stats.outcome = True, StepOutcome.LATE
            stats.status = "late: " + res.status
            self.fallback_steps += 1
            u = self._fallback_command()
            self.plan = new_plan
            return self._send(u, epm, stats, t_s)
        stats.failed, stats.outcome = True, StepOutcome.FAILED
        stats.status = "failed: " + res.status
        self.fallback_steps += 1
        u = self._fallback_command()
        if res.solver == "sqp" and self.plan is not None and np.all(np.isfinite(res.w)):
            # A recovery that ran out of iterations: its iterate (each line search lowered the
            # merit from the shifted plan's) warm-starts the next frame, whose step goes on with
            # the repair; restarting from the shifted plan would repeat the same failed step.
            self.plan.w = res.w
        return self._send(u, epm, stats, t_s)

    def _send(self, u: np.ndarray, epm: np.ndarray, stats: StepStats, t_s: float) -> Command:
        """Send the MPC's command ``u``, or the start's pre-load command while that phase lasts
        (:mod:`.start`; the MPC solves meanwhile, so its plan is warm when it takes over)."""
        start = self.start
        if start is not None and t_s >= 0 and start.active:
            u_start = start.command(t_s, epm, self.u_prev, self.disturbance_n[0:2])
            if u_start is not None:
                stats.extra["start_preload"] = 1.0
                u = u_start
        return self._emit(u, epm, stats, hold=t_s < 0)

    def _approach_command(self, u: np.ndarray, epm: np.ndarray) -> Command:
        """The final approach's command (:mod:`.approach`): the MPC's plan is dropped (a new one is
        solved from scratch should the MPC take over again) and it predicts nothing."""
        self.plan = None
        self.last_prediction = None
        attempts = float(self.approach.attempts)
        stats = StepStats(
            status=f"approach: {self.approach.phase}",
            extra={"approach_attempts": attempts},
            outcome=StepOutcome.APPROACH,
        )
        return self._emit(u, epm, stats)

    @property
    def finished(self) -> bool:
        """Whether the final approach (:mod:`.approach`) is over: done, given up, or switched off
        (``mpc.final_approach``); until then the run does not end at rest."""
        return self.approach.finished

    def _fallback_command(self) -> np.ndarray:
        """The previous plan's command for now while the plan lasts (it predicts the next frame),
        else brake.

        The warm start is shifted by the frame that passed (the plan's command for it was
        applied), so it stays aligned with time for the next solve.
        """
        plan = self.plan
        if plan is not None and (plan.age + 2) * self.dt_s < plan.times[-1] + 1e-9:
            plan.age += 1
            plan.w = self.stack.ocp.shift(plan.w)  # type: ignore[union-attr]
            plan.lam_x = plan.lam_g = None
            return plan.command((plan.age + 1) * self.dt_s)
        self.plan = None
        return np.zeros(3)  # braking target; the safety layer limits the deceleration

    def _emit(self, u: np.ndarray, epm: np.ndarray, stats: StepStats, hold: bool = False) -> Command:
        """Send ``u`` through the safety layer; ``hold``: the settle phase (t < 0), in which the
        rig keeps the EPM still whatever is commanded, so the controller sends (and assumes) 0."""
        if hold:
            u = np.zeros(3)
        cmd, clipped = safe_command(u, self.u_prev, epm, self.scenario, self.dt_s, self.slope_prev)
        if clipped:
            self.clipped_steps += 1
            stats.extra["clipped"] = 1.0
        self.slope_prev = (cmd - self.u_prev) / self.dt_s
        self.u_prev = cmd
        return Command(epm_velocity_mps=cmd, stats=stats)

    def predicted_capsule_path(self) -> np.ndarray | None:
        """The capsule positions (N, 2) predicted by the last successful solve."""
        return None if self.last_prediction is None else self.last_prediction.copy()

    @property
    def build_s(self) -> float:
        """Time it took to build the problem and solver, s (0 when reused)."""
        return math.nan if self.stack is None else self.stack.build_s
