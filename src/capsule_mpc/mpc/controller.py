"""The MPC controller: an estimator, a supervisor with explicit phases, the sliding MPC as a pure
step, and a safety filter on every command.

Every frame:

1. the estimator (:mod:`.estimator`, :attr:`MPCController.state`) fuses the camera frame in the
   Kalman filter and predicts it over the latency; before t = 0 it collects where the capsule
   rests, and calibrates at t = 0;
2. the supervisor (:mod:`.supervisor`) applies the events of time and asks the phase's producer
   (:mod:`.phases`) for the command: ``SETTLE`` (t < 0) and ``SLIDE`` the sliding MPC
   (:mod:`.slide`), ``BREAK_LOOSE`` the start's pre-load (:mod:`.start`), ``PLACE`` and after it
   ``HOLD`` or ``FAILED`` the placement moves (:mod:`.place`);
3. the safety filter (:class:`capsule_mpc.safety.SafetyFilter`) enforces speed, acceleration,
   jerk and workspace limits on the command actually sent, and counts any clipping.

The frame's phase goes to the run log (:attr:`StepStats.phase`). The controller is not
:attr:`~MPCController.finished` (the run does not end at rest) until the placement is over.
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
from ..safety import SafetyFilter, safe_command
from .estimator import StateEstimator
from .grid import prediction_steps_s
from .phases import TERMINAL, FrameContext, Phase, PhaseProducer
from .place import PlacementProducer
from .problem import OCP, build_ocp
from .producers import PreloadBreakLoose
from .reference import SlideReference
from .slide import Plan, SettleProducer, SlideProducer
from .solver import MPCSolver
from .start import StartPreload
from .supervisor import Supervisor

__all__ = ["MPCController", "MPCStack", "build_mpc_stack", "model_scenario", "safe_command"]


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
    key = scenario.model_dump_json(
        exclude={"sim", "camera", "path", "name", "faults", "estimator", "break_loose", "place"}
    )
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
        solver = MPCSolver(ocp, cfg.scheme, compile_dir=compile_dir, qpsol=cfg.qp_solver)
    except (OSError, RuntimeError) as exc:  # no C compiler, or it failed: run uncompiled
        if compile_dir is None:
            raise
        warnings.warn(f"mpc.compile_c: compiling the NLP failed ({exc}); running uncompiled", stacklevel=2)
        solver = MPCSolver(ocp, cfg.scheme, qpsol=cfg.qp_solver)
    stack = MPCStack(ocp, solver, time.perf_counter() - t0, force, model)
    _STACKS[key] = stack
    return stack


@register_controller("mpc")
class MPCController(Controller):
    """Estimator -> supervisor of phases -> producers (the sliding MPC among them) -> safety
    filter (see the module docstring)."""

    name = "mpc"

    def __init__(self) -> None:
        self.stack: MPCStack | None = None

    def reset(self, scenario: Scenario, path: ReferencePath, epm_position_m: np.ndarray) -> None:
        """Build (or reuse) the problem for ``scenario`` and forget the previous run."""
        self.scenario = scenario
        stack = self.stack = build_mpc_stack(scenario)
        wrap = self.solver_wrapper
        self.solver = stack.solver if wrap is None else wrap(stack.solver)
        # The frame period: the first stage of the plan, the time between commands.
        self.dt_s = stack.ocp.frame_s
        self.state = StateEstimator(scenario, stack.force, self.dt_s)
        belief = FrictionBelief.from_scenario(scenario)
        self.reference = SlideReference(path, stack.ocp, scenario.break_loose.blend_s, belief)
        self.slide = SlideProducer(
            self.solver, stack.ocp, scenario.mpc, self.state, self.reference, self.dt_s
        )
        self.safety = SafetyFilter(scenario, self.dt_s)
        self.target_m = np.asarray(path.end_m, dtype=float)
        self.supervisor = Supervisor(self._producers(scenario, path, stack, belief), path.duration_s)

    def _producers(
        self, scenario: Scenario, path: ReferencePath, stack: MPCStack, belief: FrictionBelief
    ) -> dict[Phase, PhaseProducer]:
        """Each phase's producer for this run."""
        start = None
        if scenario.break_loose.preload is not None:
            rest = self.state.rest
            start = StartPreload(scenario, path, stack.force, stack.ocp.lead_eq_m, belief, rest, self.dt_s)
        self.placement = place = PlacementProducer(
            scenario, self.slide, stack.force, stack.ocp.lead_eq_m, belief, path.length_m
        )
        return {
            Phase.SETTLE: SettleProducer(self.slide),
            Phase.BREAK_LOOSE: PreloadBreakLoose(start, self.slide),
            Phase.SLIDE: self.slide,
            Phase.PLACE: place,
            Phase.HOLD: place,
            Phase.FAILED: place,
        }

    @property
    def plan(self) -> Plan | None:
        """The sliding MPC's current plan (None before the first solve, or after another phase
        took over)."""
        return self.slide.plan

    @property
    def estimator(self) -> CapsuleEstimator:
        """The Kalman filter of the estimator (:attr:`state`): position and velocity from the camera."""
        return self.state.kalman

    @property
    def disturbance_n(self) -> np.ndarray:
        """The estimated disturbance: constant force (x, y) and extra friction along the motion, N."""
        return self.state.disturbance_n

    @property
    def deadline_ms(self) -> float:
        """The solve deadline, ms (``mpc.deadline_ms``, else one frame)."""
        return self.slide.deadline_ms

    @property
    def phase(self) -> Phase:
        """The current phase (:class:`~capsule_mpc.mpc.phases.Phase`)."""
        return self.supervisor.phase

    def step(self, t_s: float, measurement: Measurement, epm_position_m: np.ndarray) -> Command:
        """One frame: estimate, let the phase's producer command, enforce the limits."""
        epm = np.asarray(epm_position_m, dtype=float)
        accepted = self.state.fuse(measurement)
        if not self.state.initialised:  # nothing seen yet: hold still
            stats = StepStats(status="no_measurement", outcome=StepOutcome.NO_MEASUREMENT)
            stats.phase = self.supervisor.phase.value
            return self._emit(np.zeros(3), epm, stats)
        if not accepted:  # an outlier rejected by the filter's gate: the prediction stands in for it
            measurement = replace(measurement, position_m=None)
        est = self.state.estimate(t_s, measurement.position_m, epm)
        if t_s >= 0:
            self.reference.start(est.position_m)
        ctx = FrameContext(
            t_s=t_s,
            measurement=measurement,
            position_m=est.position_m,
            velocity_mps=est.velocity_mps,
            resting=est.resting,
            rest_s=est.rest_s,
            epm_m=epm,
            u_prev_mps=self.safety.u_prev,
            slope_prev_mps2=self.safety.slope_prev,
            disturbance_n=self.state.disturbance_n.copy(),
            target_m=self.target_m,
        )
        phase, out = self.supervisor.step(ctx)
        assert out.command is not None  # the supervisor returns only an output with a command
        stats = out.stats if out.stats is not None else StepStats()
        stats.phase = phase.value
        if not accepted:
            stats.extra["measurement_rejected"] = 1.0
        return self._emit(out.command, epm, stats, hold=t_s < 0)

    @property
    def finished(self) -> bool:
        """Whether the placement is over (done or given up) or off (``place.max_moves: 0``); until
        then the run does not end at rest."""
        return self.scenario.place.max_moves == 0 or self.supervisor.phase in TERMINAL

    @property
    def gave_up(self) -> str:
        """The placement's reason when it gave up (the ``FAILED`` phase), else empty."""
        if self.supervisor.phase is not Phase.FAILED:
            return ""
        return next(
            (tr.reason for tr in reversed(self.supervisor.transitions) if tr.after is Phase.FAILED), ""
        )

    def _emit(self, u: np.ndarray, epm: np.ndarray, stats: StepStats, hold: bool = False) -> Command:
        """Send ``u`` through the safety filter; ``hold``: the settle phase (t < 0), in which the
        rig keeps the EPM still whatever is commanded, so the controller sends (and assumes) 0."""
        cmd, clipped = self.safety.apply(np.zeros(3) if hold else u, epm)
        if clipped:
            stats.extra["clipped"] = 1.0
        return Command(epm_velocity_mps=cmd, stats=stats)

    def predicted_capsule_path(self) -> np.ndarray | None:
        """The capsule positions (N, 2) predicted by the last successful solve."""
        pred = self.slide.last_prediction
        return None if pred is None else pred.copy()

    @property
    def build_s(self) -> float:
        """Time it took to build the problem and solver, s (0 when reused)."""
        return math.nan if self.stack is None else self.stack.build_s
