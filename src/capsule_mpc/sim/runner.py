"""What a closed-loop run produces and how it is judged: the result, how it ended, where it starts,
its progress along the path and its score. The loop itself is :mod:`.loop`."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..config import Scenario
from ..interfaces import Actuator, StepStats
from ..magnetics import model_equilibrium_lead
from ..metrics import run_metrics
from ..paths import ReferencePath
from .faults import FaultEvent
from .plant import CapsulePlant
from .truth import PlantTruth

__all__ = [
    "LIMIT_WORDS",
    "START_STREAM",
    "PathProgress",
    "RealtimeStats",
    "RunFlags",
    "RunOutcome",
    "RunResult",
    "check_arm_run",
    "limit_text",
    "realtime_scenario",
    "score_run",
    "start_pose",
]

#: Each actuator limit counter (:meth:`~capsule_mpc.interfaces.Actuator.limit_counts`) in words:
#: (what the limit did, what the count counts).
LIMIT_WORDS: dict[str, tuple[str, str]] = {
    "workspace_clamped_steps": ("clamped by the workspace", "axis-steps"),
    "workspace_braking_ticks": ("braked at the workspace boundary", "arm ticks"),
    "speed_clipped_frames": ("speed-clipped", "commands"),
    "accel_limited_steps": ("acceleration-limited", "axis-steps"),
}
#: How far (m) along the path the progress tracker looks back / ahead of its last value per frame.
_PROGRESS_WINDOW_M = (0.03, 0.03)
#: Half-width (m) of the box of leads around the true equilibrium searched for the start dead zone
#: (the dead zone measured on the default rig spans about +-6 mm in x and +-22 mm in y).
_DEAD_ZONE_SEARCH_M = 0.035
#: Candidate leads drawn per search box when searching the dead zone.
_DEAD_ZONE_TRIES = 20000
#: Second seed word of the start-offset random stream (``default_rng([rig seed, START_STREAM])``).
START_STREAM = 2
#: Search boxes tried in turn, as fractions of the full one (small dead-zone fractions need small boxes).
_DEAD_ZONE_BOXES = (1.0, 0.1, 0.01, 0.001)


class PathProgress:
    """Monotone arc-length progress of a point moving along a path.

    Each update projects the point onto the part of the path within a window
    around the previous progress, so a closed path's start is never mistaken for
    its end and a path passing near itself is not short-cut.
    """

    def __init__(self, path: ReferencePath) -> None:
        self.path = path
        v = path.vertices_m
        self._a = v[:-1]
        seg = np.diff(v, axis=0)
        self._len = np.hypot(seg[:, 0], seg[:, 1])
        self._dir = seg / self._len[:, None]
        self._s0 = np.concatenate([[0.0], np.cumsum(self._len)])[:-1]
        self.progress_m = 0.0

    def update(self, point_m: np.ndarray) -> float:
        """Advance the progress with a new position (2,), m; returns the progress, m."""
        back, ahead = _PROGRESS_WINDOW_M
        lo = self._s0 - (self.progress_m - back)  # window in each segment's own coordinate
        hi = self.progress_m + ahead - self._s0
        lo_c = np.clip(-lo, 0.0, self._len)
        hi_c = np.clip(hi, 0.0, self._len)
        usable = hi_c >= lo_c
        rel = np.asarray(point_m, dtype=float) - self._a
        along = np.clip(np.einsum("mk,mk->m", rel, self._dir), lo_c, hi_c)
        closest = self._a + along[:, None] * self._dir
        dist = np.where(usable, np.hypot(*(closest - point_m).T), np.inf)
        best = int(np.argmin(dist))
        self.progress_m = max(self.progress_m, float(self._s0[best] + along[best]))
        return self.progress_m


class RunOutcome(enum.Enum):
    """How a run ended, for code to act on (:meth:`RunFlags.describe` says it in words)."""

    #: Still running (the loop has not ended).
    RUNNING = "running"
    #: At rest after the path, within ``sim.completion_tol_m`` of its end.
    COMPLETED = "completed"
    #: At rest after the path, farther than ``sim.completion_tol_m`` from its end.
    STALLED = "stalled"
    #: Cut off at ``1.25 x`` the path's duration + ``sim.tail_s`` while the capsule still moved.
    TIMED_OUT = "timed_out"
    #: The capsule lost the magnet (the lead grew past the coupling limit).
    DECOUPLED = "decoupled"
    #: The capsule fell off the plate (the magnetic attraction vanished).
    DROPPED = "dropped"
    #: At rest after the path, but the controller gave up placing it (its reason in the outcome).
    GAVE_UP = "gave_up"


@dataclass
class RunFlags:
    """How a run ended."""

    completed: bool = False
    at_rest: bool = False
    decoupled: bool = False
    dropped: bool = False
    stalled: bool = False
    timed_out: bool = False
    failure: str = ""
    failure_t_s: float = math.nan
    invalid_commands: int = 0
    arm_failure: str = ""
    gave_up: str = ""

    @property
    def outcome(self) -> RunOutcome:
        """How the run ended, as a value (:class:`RunOutcome`)."""
        if self.decoupled:
            return RunOutcome.DECOUPLED
        if self.dropped:
            return RunOutcome.DROPPED
        if self.gave_up:
            return RunOutcome.GAVE_UP
        if self.completed:
            return RunOutcome.COMPLETED
        if self.stalled:
            return RunOutcome.STALLED
        if self.timed_out:
            return RunOutcome.TIMED_OUT
        return RunOutcome.RUNNING

    def describe(
        self, final_error_mm: float, path_left_mm: float = math.nan, end_t_s: float = math.nan
    ) -> str:
        """How the run ended, in words.

        Parameters
        ----------
        final_error_mm : float
            Distance from the capsule's last position to the path's end, mm.
        path_left_mm : float
            Arc length of the path the capsule's progress did not reach, mm (NaN: not said).
        end_t_s : float
            Time of the run's last frame, s (NaN: not said); a timed-out run names it.
        """
        if self.decoupled or self.dropped:
            return self.failure
        left = "" if math.isnan(path_left_mm) else f", {path_left_mm:.1f} mm of the path not covered"
        if self.gave_up:
            return f"gave up placing: {self.gave_up} (at rest {final_error_mm:.2f} mm from the end)"
        if self.completed:
            return f"completed: at rest {final_error_mm:.2f} mm from the end"
        if self.stalled:
            return f"stalled {final_error_mm:.2f} mm short of the end (at rest{left})"
        cut = "" if math.isnan(end_t_s) else f" at t = {end_t_s:.2f} s"
        return f"timed out{cut} while the capsule still moved, {final_error_mm:.2f} mm from the end{left}"


def limit_text(limit_counts: dict[str, int]) -> str:
    """The actuator's limit counts (:meth:`~capsule_mpc.interfaces.Actuator.limit_counts`) in words.

    Only the limits that acted are named; an empty string if none did. The simple arm counts
    workspace clamps and acceleration limits per plant step and axis ("axis-steps"), speed clips
    per command; the robot arm its workspace braking per arm tick. A counter without words here
    is given by its name.
    """
    parts = []
    for name, count in limit_counts.items():
        if count:
            words, unit = LIMIT_WORDS.get(name, (name.replace("_", " "), ""))
            parts.append(f"{words} in {count} {unit}" if unit else f"{words} {count}")
    return "actuator limits: " + ", ".join(parts) if parts else ""


@dataclass
class RealtimeStats:
    """Wall-clock pacing of a real-time run (see the module docstring).

    Attributes
    ----------
    period_ms : float
        Frame period (the slot length), ms.
    frames : int
        Controller steps taken.
    deadline_misses : int
        Steps whose command was ready after the end of their slot (a step that started late,
        behind a long one, counts too).
    deadline_misses_motion : int
        Of those, the ones at t >= 0 (after the settle phase, while the EPM may move).
    overruns : int
        Steps that by themselves took longer than a frame period.
    worst_step_ms : float
        Longest controller step (wall time of ``Controller.step``), ms.
    worst_step_t_s : float
        Frame time of that step, s.
    max_late_ms : float
        Worst time a command was ready after the end of its slot, ms (0 if never late).
    slept_s : float
        Total time the loop slept waiting for slots, s.
    """

    period_ms: float
    frames: int = 0
    deadline_misses: int = 0
    deadline_misses_motion: int = 0
    overruns: int = 0
    worst_step_ms: float = 0.0
    worst_step_t_s: float = math.nan
    max_late_ms: float = 0.0
    slept_s: float = 0.0

    def record(self, t_s: float, step_s: float, late_s: float) -> None:
        """Account for one step that took ``step_s`` and ended ``late_s`` after its slot (< 0: early)."""
        self.frames += 1
        self.overruns += int(step_s * 1e3 > self.period_ms)
        if step_s * 1e3 > self.worst_step_ms:
            self.worst_step_ms, self.worst_step_t_s = step_s * 1e3, t_s
        if late_s > 0:
            self.deadline_misses += 1
            self.deadline_misses_motion += int(t_s >= 0)
            self.max_late_ms = max(self.max_late_ms, late_s * 1e3)


@dataclass
class RunResult:
    """Everything a run produced.

    Attributes
    ----------
    scenario : Scenario
        The scenario that was simulated.
    controller : str
        The controller's name.
    seed : int
        Seed of the run's random generator (camera noise, drops, faults; the rig's draw is
        ``truth.seed``).
    path : ReferencePath
        The reference (nominal speed).
    log : dict of str to numpy.ndarray
        One entry per logged frame (columns in :data:`capsule_mpc.sim.log.LOG_COLUMNS`).
    metrics : dict
        :func:`capsule_mpc.metrics.run_metrics` plus the flags.
    flags : RunFlags
        How the run ended.
    step_stats : list of StepStats
        The controller's stats, one per frame.
    limit_counts : dict of str to int
        How often the actuator's limits changed the commanded motion.
    wall_time_s : float
        Wall-clock time of the loop, s.
    sim_time_s : float
        Simulated time (settle phase included), s.
    plant_steps : int
        Number of plant steps.
    meta : dict
        Free-form provenance (config path, waypoints file), written to run.json.
    predictions : list of (numpy.ndarray (N, 2) or None)
        The controller's predicted capsule path after each logged frame's step
        (:meth:`~capsule_mpc.interfaces.Controller.predicted_capsule_path`), m; None where it
        predicts nothing (and on a final failure row, where no step was taken).
    realtime : RealtimeStats or None
        Wall-clock pacing figures of a real-time run; None otherwise.
    truth : PlantTruth or None
        The plant's draw (the plant's own truth when a plant was passed in; None only when built by hand).
    fault_events : list of FaultEvent
        The faults injected (``scenario.faults``), in the order they began; empty without faults.
    """

    scenario: Scenario
    controller: str
    seed: int
    path: ReferencePath
    log: dict[str, np.ndarray]
    metrics: dict[str, Any]
    flags: RunFlags
    step_stats: list[StepStats]
    limit_counts: dict[str, int]
    wall_time_s: float
    sim_time_s: float
    plant_steps: int
    meta: dict[str, Any] = field(default_factory=dict)
    predictions: list[np.ndarray | None] = field(default_factory=list)
    realtime: RealtimeStats | None = None
    truth: PlantTruth | None = None
    arm_run: tuple[Any, Any] | None = None
    fault_events: list[FaultEvent] = field(default_factory=list)

    @property
    def failed(self) -> bool:
        """Whether the run failed: it did not come to rest within ``sim.completion_tol_m`` of the
        end (stalled, timed out, decoupled or dropped), or the joint commands the robot arm ran
        fail their check (``flags.arm_failure``)."""
        return not self.flags.completed or bool(self.flags.arm_failure)

    def outcome_text(self) -> str:
        """How the run ended, in words, for a console line.

        The outcome (:meth:`RunFlags.describe`: completed, stalled N mm short of the end, timed
        out, decoupled or dropped with its time), commands the runner replaced by a stop, and
        every limit the actuator enforced (:func:`limit_text`). ``capsule-mpc simulate`` prints
        it first; it is the same text for each controller of a comparison.
        """
        f = self.flags
        text = str(self.metrics["outcome"])
        if f.decoupled or f.dropped:
            text += f" at t = {f.failure_t_s:.3f} s"
        if f.invalid_commands:
            text += f"; {f.invalid_commands} invalid commands replaced by a stop"
        if f.arm_failure:
            text += f"; arm commands invalid: {f.arm_failure}"
        limits = limit_text(self.limit_counts)
        return f"{text}; {limits}" if limits else text

    @property
    def realtime_factor(self) -> float:
        """Simulated time per wall-clock time (> 1: faster than real time)."""
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.inf

    def summary(self) -> dict[str, Any]:
        """What ``run.json`` holds: provenance, metrics, flags, limit counts, timing, real-time pacing."""
        return {
            "controller": self.controller,
            "seed": self.seed,
            "config": self.meta.get("config"),
            "waypoints_file": self.meta.get("waypoints_file"),
            "speed_mps": self.path.speed_mps,
            "path_length_m": self.path.length_m,
            "metrics": self.metrics,
            "flags": vars(self.flags),
            "limit_counts": self.limit_counts,
            "timing": {
                "wall_time_s": self.wall_time_s,
                "sim_time_s": self.sim_time_s,
                "plant_steps": self.plant_steps,
                "realtime_factor": self.realtime_factor,
            },
            "realtime": None if self.realtime is None else vars(self.realtime),
            "plant": None if self.truth is None else self.truth.summary(),
        }


def realtime_scenario(scenario: Scenario) -> Scenario:
    """``scenario`` with ``mpc.enforce_deadline = True`` (what a wall-clock-paced controller gets)."""
    if scenario.mpc.enforce_deadline:
        return scenario
    return scenario.model_copy(update={"mpc": scenario.mpc.model_copy(update={"enforce_deadline": True})})


def start_pose(
    scenario: Scenario, plant: CapsulePlant, path: ReferencePath, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, float]:
    """Where a run starts: the EPM position (3,), the capsule position (2,), m, and its theta, s.

    Operator start (every preset but ``ideal``): the EPM over the path start at the equilibrium
    lead of the controller's nominal model (``force_model``); the capsule at rest at a lead drawn
    uniformly among the leads whose holding ratio (:meth:`CapsulePlant.holding_ratio`, with the
    friction healed for ``rest_before_start_s``) is at most ``start_dead_zone_fraction``: inside
    that fraction of the dead zone, so it does not move while the EPM is held still. Fraction 0:
    at the true equilibrium. ``ideal``: the capsule at the path start, the EPM at the plant's true
    equilibrium above it. The draw uses ``rng`` (the start stream of the rig's seed).
    """
    truth = plant.truth
    height = scenario.plate.epm_height_m
    start = np.asarray(path.start_m, dtype=float)
    rest_s = truth.rest_before_start_s
    theta0 = plant.law.d_c_m / plant.law.v_star_mps + rest_s
    if truth.start_at_true_equilibrium:
        return np.array([*(start + plant.equilibrium_lead_m), height]), start, theta0
    epm_xy = start + model_equilibrium_lead(scenario, height)
    fraction = truth.start_dead_zone_fraction
    lead = plant.equilibrium_lead_m.copy()
    if fraction > 0:
        lead = _draw_rest_lead(plant, epm_xy, height, theta0, fraction, rng)
    return np.array([*epm_xy, height]), epm_xy - lead, theta0


def _draw_rest_lead(
    plant: CapsulePlant,
    epm_xy: np.ndarray,
    height: float,
    theta0: float,
    fraction: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """A lead drawn uniformly among those with holding ratio <= ``fraction`` (rejection sampling).

    The box searched first spans the whole dead zone; a small fraction's set is a small region
    around the equilibrium (the force grows about linearly with the offset), so when no candidate
    lands in it the box shrinks (it still contains the set, so the draw stays uniform over it).
    """
    for box in _DEAD_ZONE_BOXES:
        half = box * _DEAD_ZONE_SEARCH_M
        for _ in range(_DEAD_ZONE_TRIES):
            cand = plant.equilibrium_lead_m + rng.uniform(-half, half, 2)
            rest_xy = (float(epm_xy[0] - cand[0]), float(epm_xy[1] - cand[1]))
            if plant.holding_ratio(float(cand[0]), float(cand[1]), height, theta0, rest_xy) <= fraction:
                return np.asarray(cand, dtype=float)
    return plant.equilibrium_lead_m.copy()  # fraction ~ 0: the equilibrium itself


def check_arm_run(
    scenario: Scenario, act: Actuator, flags: RunFlags, metrics: dict[str, Any]
) -> tuple[Any, Any] | None:
    """The robot arm's setpoints and joint commands from t = 0 on, checked as they would be exported
    (:func:`capsule_mpc.arm.check_run_trajectory`); None for an actuator that keeps none.

    Sets ``metrics['arm_ok']`` and, on a failed check, ``flags.arm_failure`` (the check's message).
    """
    trajectories = getattr(act, "joint_trajectory", None)
    if trajectories is None or not getattr(act, "record", False):
        return None
    from ..arm import ArmError, check_run_trajectory, run_trajectory_since  # lazy: Pinocchio

    cart, joints = run_trajectory_since(act.cartesian_trajectory(), act.joint_trajectory())  # type: ignore[attr-defined]
    if cart.t_s.shape[0] < 2:
        return None
    try:
        check, _summary = check_run_trajectory(scenario, cart, joints)
    except ArmError as exc:
        flags.arm_failure = str(exc)
        metrics["arm_ok"] = False
    else:
        metrics["arm_ok"] = True
        metrics["arm_max_fk_error_m"] = check.max_fk_error_m
    return cart, joints


def score_run(
    arrays: dict[str, np.ndarray],
    path: ReferencePath,
    scenario: Scenario,
    flags: RunFlags,
) -> dict[str, Any]:
    """The run's metrics over its own window (t = 0 to its end) and the flags that say how it ended."""
    tol = scenario.sim.completion_tol_m
    end_s = float(arrays["t_s"][-1]) if len(arrays["t_s"]) else 0.0
    metrics = run_metrics(
        arrays,
        path,
        window_end_s=max(end_s, 0.0),
        arrival_tol_m=tol,
        deadline_ms=1e3 / scenario.camera.rate_hz,
    )
    near = metrics["final_error_mm"] <= tol * 1e3
    progress = arrays["progress_m"]
    left_mm = max(path.length_m - float(progress[-1]), 0.0) * 1e3 if len(progress) else math.nan
    flags.completed = flags.at_rest and near and not flags.gave_up
    flags.stalled = flags.at_rest and not near
    outcome = flags.describe(metrics["final_error_mm"], left_mm, end_s)
    metrics.update(
        completed=flags.completed,
        at_rest=flags.at_rest,
        decoupled=flags.decoupled,
        dropped=flags.dropped,
        stalled=flags.stalled,
        timed_out=flags.timed_out,
        invalid_commands=flags.invalid_commands,
        outcome=outcome,
    )
    return metrics
