"""The closed loop: plant + camera + controller + actuator, run until the capsule rests, logged and scored.

Timeline of a run. The plant steps at ``sim.plant_rate_hz``; camera frames
fall on the plant steps nearest ``j / camera.rate_hz`` (j integer, so frames
are on the plant grid with at most half a step of jitter). Time 0 is the start
of the path; the run starts ``sim.settle_s`` earlier.

Start (:func:`start_pose`), as an operator starts a real rig: the EPM is put
(height ``plate.epm_height_m``) where the controller's *nominal* model says the
capsule rests when it is at the path's first point; the capsule rests wherever
static friction left it -- a lead drawn from the rig's seed inside a fraction
(``plant.start_dead_zone_fraction``) of the true static-friction dead zone, its
friction healed by ``plant.rest_before_start_s`` at rest. The ``ideal`` preset
keeps the reference start: the capsule at the path's first point, the EPM at the
plant's true equilibrium above it. During the settle phase (t < 0) the
controller is stepped on every frame (it sees the measurements, e.g. to
calibrate) but the arm is held still: the applied command is zero.

At each frame: the camera captures the true capsule position (delivered
``camera.latency_frames`` later, with the true bias and noise of the draw), the
controller is called with the delivered measurement and the EPM's own position,
its command reaches the actuator ``plant.compute_delay_s`` later (in the
``solve_time`` mode of ``plant.compute_delay_mode``, when the controller's step
has ended on this machine, plus that delay), and one log row is recorded (true
states at the frame time; the command column holds the command computed at that
frame).

A run ends at the first of:

* *at rest*: t >= the path's nominal duration, the controller says it is finished
  (:attr:`~capsule_mpc.interfaces.Controller.finished`: the MPC's final approach is over) and the
  capsule has been at rest (slower than ``sim.rest_speed_mps``) for ``sim.rest_hold_s``; never
  while it moves;
* *decoupled* / *dropped*: the plant failed (see :mod:`.plant`); a last row is
  logged at the failure time;
* *timed out*: t reaches ``1.25 * nominal duration + sim.tail_s``.

The run reports the arrival time (first frame within ``sim.completion_tol_m`` of
the final waypoint with the progress at the path end), the final error at rest
and whether it *stalled* (came to rest farther than that tolerance from the end);
it is *completed* when it came to rest within it. Metrics cover the window from
t = 0 to the run's end (:func:`capsule_mpc.metrics.run_metrics`); ``compare``
scores the controllers of one draw on their common window.

Real-time mode (``simulate(..., realtime=True)``, ``capsule-mpc simulate --realtime``):
the loop is paced to the wall clock at the camera rate. Frame ``i`` (counted from
the first frame) has the wall-clock slot ``[T0 + i P, T0 + (i + 1) P)``, P the
frame period: the plant is advanced to the frame's time, the loop sleeps until
the slot starts, then the controller is called. A command ready after the end of
its slot is a *deadline miss*: it is counted, the command is still applied, and
the loop carries on (the next frames start late, at once, until the schedule is
caught up). The runner sleeps only between frames, never inside a controller.
The controller gets the scenario with ``mpc.enforce_deadline = True`` (a late
MPC solve then makes it use its shifted plan); that scenario is the one recorded
in the result.

One rig, several runs: the run's ``seed`` draws the camera noise, drops and faults; the
rig -- the plant draw (:func:`~.truth.draw_plant_truth`: magnets, friction, tether, servo
lag, camera bias, start conditions) and the start offset -- is drawn from ``plant_seed``,
which defaults to ``seed``. Runs that share a ``plant_seed`` run on the same rig.

Faults (``scenario.faults``, :mod:`.faults`): when any is switched on, the run gets a
:class:`~.faults.FaultInjector` on its own random streams. The camera applies the drop bursts and
outliers to its captures; the controller's ``solver_wrapper`` (used by the MPC) is set to the
injector's solver wrapper before its reset; an arm stall holds the arm at zero velocity (it
brakes within its limits) and keeps the latest command until the stall ends, then applies it; a
latency spike adds its delay to one frame's command (the later ones queue behind it). The run's
metrics then carry the fault counts and recovery times (:func:`~.faults.fault_metrics`) and
:attr:`RunResult.fault_events` lists the faults. In ``solve_time`` mode the delay counts a
step as lasting at least the solve time the controller reports (an injected late solve delays
its command).

Predictions: after each step the runner records
:meth:`~capsule_mpc.interfaces.Controller.predicted_capsule_path` (``None`` for
controllers that do not predict), one entry per logged frame.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from tqdm import tqdm

from ..budget import TIMEOUT_FACTOR
from ..config import Scenario
from ..interfaces import Actuator, Command, Controller, StepStats, make_actuator, make_controller
from ..magnetics import model_equilibrium_lead
from ..metrics import run_metrics
from ..paths import ReferencePath
from .actuation import SimpleArm
from .columns import INT_COLUMNS, LOG_COLUMNS, STR_COLUMNS
from .faults import FaultEvent, FaultInjector, fault_metrics
from .plant import OK, CapsulePlant
from .sensing import Camera
from .truth import PlantTruth, draw_plant_truth

__all__ = [
    "LIMIT_WORDS",
    "TIMEOUT_FACTOR",
    "PathProgress",
    "RealtimeStats",
    "RunFlags",
    "RunResult",
    "limit_text",
    "realtime_scenario",
    "simulate",
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
#: Progress bar layout: simulated seconds out of the cut-off time.
_BAR_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} s simulated [{elapsed}]"
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


class _Log:
    """Preallocated per-frame columns."""

    def __init__(self, n_rows: int) -> None:
        self.cols: dict[str, np.ndarray] = {}
        for name in LOG_COLUMNS:
            if name in STR_COLUMNS:
                self.cols[name] = np.empty(n_rows, dtype=object)
            elif name in INT_COLUMNS:
                self.cols[name] = np.zeros(n_rows, dtype=int)
            else:
                self.cols[name] = np.full(n_rows, math.nan)
        self.n = 0

    def add(self, row: dict[str, Any]) -> None:
        i = self.n
        for name, value in row.items():
            self.cols[name][i] = value
        self.n += 1

    def arrays(self) -> dict[str, np.ndarray]:
        out = {name: col[: self.n].copy() for name, col in self.cols.items()}
        for name in STR_COLUMNS:
            out[name] = out[name].astype(str)
        return out


def _check_command(cmd: Any) -> np.ndarray | None:
    if not isinstance(cmd, Command):
        return None
    v = np.asarray(cmd.epm_velocity_mps, dtype=float).ravel()
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        return None
    return v


def realtime_scenario(scenario: Scenario) -> Scenario:
    """``scenario`` with ``mpc.enforce_deadline = True`` (what a wall-clock-paced controller gets)."""
    if scenario.mpc.enforce_deadline:
        return scenario
    return scenario.model_copy(update={"mpc": scenario.mpc.model_copy(update={"enforce_deadline": True})})


def _wait_until(deadline: float) -> float:
    """Sleep until ``time.perf_counter()`` reaches ``deadline``; returns the time slept, s."""
    remaining = deadline - time.perf_counter()
    if remaining <= 0:
        return 0.0
    time.sleep(remaining)
    return remaining


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


def _fault_injector(scenario: Scenario, seed: int) -> FaultInjector | None:
    """The run's fault injector (:mod:`.faults`); None when no fault is switched on."""
    if not scenario.faults.enabled:
        return None
    frame_s = 1.0 / scenario.camera.rate_hz
    return FaultInjector(scenario.faults, seed, frame_s, scenario.camera.latency_frames)


def _make_actuator(scenario: Scenario, truth: PlantTruth) -> Actuator:
    """The scenario's actuator with the draw's servo lag: on the simple arm's velocity, on the
    robot arm's joints."""
    if truth.servo_bandwidth_hz is not None and scenario.sim.actuator == "simple":
        return SimpleArm(scenario, servo_bandwidth_hz=truth.servo_bandwidth_hz)
    if truth.servo_bandwidth_hz is not None and scenario.sim.actuator == "robot":
        from ..arm import RobotArmActuator  # lazy: Pinocchio loads only for the robot arm

        return RobotArmActuator(scenario, servo_bandwidth_hz=truth.servo_bandwidth_hz)
    return make_actuator(scenario)


class _Loop:
    """One run's state between frames: plant, actuator, pending commands, log and end detection."""

    def __init__(
        self, scenario: Scenario, path: ReferencePath, plant: CapsulePlant, act: Actuator, delay_s: float
    ) -> None:
        self.scenario, self.path, self.plant, self.act = scenario, path, plant, act
        self.dt = 1.0 / scenario.sim.plant_rate_hz
        self.frame_s = 1.0 / scenario.camera.rate_hz
        self.ratio = scenario.sim.plant_rate_hz / scenario.camera.rate_hz
        self.delay_s = delay_s
        self.solve_time_delay = scenario.plant.compute_delay_mode == "solve_time"
        self.pending: deque[tuple[int, np.ndarray]] = deque()
        self.last_ready = -(2**62)
        self.tracker = PathProgress(path)
        self.flags = RunFlags()
        self.rest_s = 0.0
        self.cmd_applied = np.zeros(3)
        self.stall_end_k = -(2**62)  # plant step at which an arm stall ends
        self.arm_cmd = np.zeros(3)  # the latest command to reach the arm (kept through a stall)

    def _to_arm(self, k: int, vel: np.ndarray) -> None:
        """A command reaches the arm at plant step ``k``; a stalled arm keeps it for later."""
        self.arm_cmd = vel
        if k >= self.stall_end_k:
            self.act.set_velocity_command(k * self.dt, vel)

    def stall(self, k: int, end_k: int) -> None:
        """The arm stops following its commands from plant step ``k`` to ``end_k`` (brakes to rest)."""
        self.stall_end_k = end_k
        self.act.set_velocity_command(k * self.dt, np.zeros(3))

    def advance(self, k: int, k_to: int) -> tuple[int, int]:
        """Step the plant and the arm from plant step ``k`` to ``k_to``; returns (k, status)."""
        step_plant, step_act, pending = self.plant.step, self.act.step_xyz, self.pending
        status = OK
        while k < k_to:
            while pending and pending[0][0] <= k:
                _, vel = pending.popleft()
                self._to_arm(k, vel)
            if k == self.stall_end_k:  # the stall is over: the arm takes the latest command
                self.act.set_velocity_command(k * self.dt, self.arm_cmd)
            ex, ey, ez = step_act(self.dt)
            status = step_plant(self.dt, ex, ey, ez)
            if status != OK:
                break
            k += 1
        return k, status

    def command(self, k: int, t: float, vel: np.ndarray, step_s: float, extra_s: float = 0.0) -> None:
        """Send the frame's command (zero at t < 0): applied ``plant.compute_delay_s`` from now, plus
        the controller's ``step_s`` in ``solve_time`` mode, plus ``extra_s`` (a latency spike), and
        never before the previous frame's command (a rig's loop handles one frame at a time)."""
        self.cmd_applied = vel if t >= 0 else np.zeros(3)
        delay_s = self.delay_s + (step_s if self.solve_time_delay else 0.0) + extra_s
        ready = max(k + round(delay_s / self.dt), self.last_ready)
        self.last_ready = ready
        if ready <= k and not self.pending:
            self._to_arm(k, self.cmd_applied)
        else:
            self.pending.append((ready, self.cmd_applied))

    def state_row(self, t: float) -> dict[str, Any]:
        """The true states at frame time ``t``."""
        plant, act = self.plant, self.act
        row: dict[str, Any] = {"t_s": t, "capsule_x_m": plant.px, "capsule_y_m": plant.py, "capsule_z_m": 0.0}
        row["capsule_vx_mps"], row["capsule_vy_mps"] = plant.vx, plant.vy
        row.update(zip(("epm_x_m", "epm_y_m", "epm_z_m"), act.position_m.tolist()))
        row.update(zip(("epm_vx_mps", "epm_vy_mps", "epm_vz_mps"), act.velocity_mps.tolist()))
        ref = self.path.position(t)
        row["ref_x_m"], row["ref_y_m"] = float(ref[0]), float(ref[1])
        row.update(zip(("force_x_n", "force_y_n", "force_att_n"), plant.force_n))
        row["normal_force_n"], row["plant_mu"] = plant.normal_force_n, plant.mu
        row["stuck"] = int(plant.stuck)
        row["progress_m"] = self.tracker.update(plant.position_m)
        return row

    def at_rest_after_end(self, t: float, finished: bool = True) -> bool:
        """Whether the capsule has rested (speed < ``sim.rest_speed_mps``) for ``sim.rest_hold_s``
        after the path's nominal end, with the controller ``finished`` (:attr:`Controller.finished`)."""
        slow = math.hypot(self.plant.vx, self.plant.vy) < self.scenario.sim.rest_speed_mps
        resting = slow and t >= self.path.duration_s and finished
        self.rest_s = self.rest_s + self.frame_s if resting else 0.0
        return self.rest_s >= self.scenario.sim.rest_hold_s - 1e-9


def simulate(
    scenario: Scenario,
    controller: Controller | str,
    path: ReferencePath,
    seed: int,
    *,
    progress: bool = False,
    actuator: Actuator | None = None,
    plant: CapsulePlant | None = None,
    meta: dict[str, Any] | None = None,
    realtime: bool = False,
    plant_seed: int | None = None,
) -> RunResult:
    """Run one closed-loop simulation.

    Parameters
    ----------
    scenario : Scenario
        The nominal rig (what the controller believes), the controller's settings, and the
        ``plant`` section the simulated truth is drawn from.
    controller : Controller or str
        A controller instance or a registry name (:func:`capsule_mpc.interfaces.make_controller`).
    path : ReferencePath
        The reference at its nominal speed.
    seed : int
        Seed of the run: camera noise, drops and faults; also the plant draw and start offset
        (:func:`~.truth.draw_plant_truth`) unless ``plant_seed`` is given.
    progress : bool
        Show a progress bar (appears only if the run takes longer than a second).
    actuator : Actuator, optional
        The EPM carrier; default :func:`make_actuator` (``sim.actuator``; the simple arm with the
        draw's servo lag).
    plant : CapsulePlant, optional
        The plant; default the finite-magnet plant of the draw.
    meta : dict, optional
        Provenance copied into :attr:`RunResult.meta` (e.g. ``config``, ``waypoints_file``).
    realtime : bool
        Pace the loop to the wall clock at the camera rate and count deadline misses
        (:class:`RealtimeStats`); the controller gets :func:`realtime_scenario`. The run then
        takes as long as the simulated time (settle phase included).
    plant_seed : int, optional
        Seed of the rig: the plant draw (its servo lag, camera bias and noise level, start
        conditions) and the start offset, >= 0; None: ``seed`` (one seed for everything).
        Several runs with one ``plant_seed`` and their own ``seed`` run on one rig with
        independent camera noise. Ignored for the draw when ``plant`` is given (its truth is used).

    Returns
    -------
    RunResult
        Log, metrics, flags, per-step stats, limit counts and timing. Failures (decoupled,
        dropped, invalid commands) are values in the result, not exceptions.
    """
    ctrl = make_controller(controller) if isinstance(controller, str) else controller
    name = controller if isinstance(controller, str) else (ctrl.name or type(ctrl).__name__)
    if realtime:
        scenario = realtime_scenario(scenario)
    if plant_seed is not None and plant_seed < 0:
        raise ValueError(f"plant_seed: must be >= 0, got {plant_seed}")
    rig_seed = seed if plant_seed is None else int(plant_seed)
    truth = draw_plant_truth(scenario, rig_seed) if plant is None else plant.truth
    plant = plant if plant is not None else CapsulePlant(scenario, truth=truth)
    act = actuator if actuator is not None else _make_actuator(scenario, truth)
    bias = (truth.camera_bias_x_m, truth.camera_bias_y_m)
    faults = _fault_injector(scenario, seed)
    camera = Camera(
        scenario.camera, np.random.default_rng(seed), bias_m=bias, noise_std_m=truth.camera_noise_std_m,
        faults=faults,
    )  # fmt: skip
    start_rng = np.random.default_rng([rig_seed, START_STREAM])
    epm0, capsule0, theta0 = start_pose(scenario, plant, path, start_rng)
    plant.reset(capsule0, theta_s=theta0)
    act.reset(epm0)
    plant.evaluate_forces(*epm0.tolist())
    ctrl.solver_wrapper = faults.wrap_solver if faults is not None and faults.solver_faults else None
    ctrl.reset(scenario, path, epm0.copy())
    loop = _Loop(scenario, path, plant, act, truth.compute_delay_s)

    sim, rate = scenario.sim, scenario.camera.rate_hz
    j0 = math.ceil(-sim.settle_s * rate - 1e-9)
    t_cut = TIMEOUT_FACTOR * path.duration_s + sim.tail_s
    j_last = math.floor(t_cut * rate + 1e-9)
    k = k_first = round(j0 * loop.ratio)
    log = _Log(j_last - j0 + 2)
    stats: list[StepStats] = []
    predictions: list[np.ndarray | None] = []
    pacing = RealtimeStats(period_ms=loop.frame_s * 1e3) if realtime else None
    bar = tqdm(
        total=round(t_cut + sim.settle_s, 1), desc=f"simulate {name}", disable=not progress, delay=1.0,
        leave=False, bar_format=_BAR_FORMAT,
    )  # fmt: skip
    flags = loop.flags
    wall0 = time.perf_counter()
    for j in range(j0, j_last + 1):
        k, status = loop.advance(k, round(j * loop.ratio))
        t = k * loop.dt
        row = loop.state_row(t)
        if status != OK:
            flags.decoupled = plant.failure.startswith("decoupled")
            flags.dropped = not flags.decoupled
            flags.failure, flags.failure_t_s = plant.failure, t
            row.update(zip(("cmd_vx_mps", "cmd_vy_mps", "cmd_vz_mps"), loop.cmd_applied.tolist()))
            row["solver_status"], row["solver_failed"] = "", 0
            log.add(row)
            predictions.append(None)
            break
        extra_s = 0.0
        if faults is not None:
            faults.begin_frame(t)
            if faults.stall_starts(t):
                loop.stall(k, k + round(faults.config.arm_stall_s / loop.dt))
            extra_s = faults.latency_spike_s(t)
        meas = camera.frame(t, plant.position_m)
        slot_start = wall0 + (j - j0) * loop.frame_s
        if pacing is not None:
            pacing.slept_s += _wait_until(slot_start)
        c0 = time.perf_counter()
        cmd = ctrl.step(t, meas, act.position_m)
        c1 = time.perf_counter()
        if pacing is not None:
            pacing.record(t, c1 - c0, c1 - (slot_start + loop.frame_s))
        predictions.append(ctrl.predicted_capsule_path())
        vel = _check_command(cmd)
        step_stats = cmd.stats if isinstance(cmd, Command) else StepStats(status="invalid", failed=True)
        if vel is None:
            flags.invalid_commands += 1
            vel = np.zeros(3)
        stats.append(step_stats)
        step_s = c1 - c0
        if math.isfinite(step_stats.solve_ms):  # a step lasts at least the solve it reports
            step_s = max(step_s, step_stats.solve_ms * 1e-3)
        loop.command(k, t, vel, step_s, extra_s)
        if meas.position_m is not None:
            row["meas_x_m"], row["meas_y_m"] = float(meas.position_m[0]), float(meas.position_m[1])
        row["meas_capture_t_s"], row["controller_ms"] = meas.capture_t_s, (c1 - c0) * 1e3
        row.update(zip(("cmd_vx_mps", "cmd_vy_mps", "cmd_vz_mps"), loop.cmd_applied.tolist()))
        row["solve_ms"], row["solver_status"] = step_stats.solve_ms, step_stats.status
        row["solver_failed"] = int(step_stats.failed)
        log.add(row)
        bar.update(loop.frame_s)
        if loop.at_rest_after_end(t, ctrl.finished):
            flags.at_rest = True
            break
    else:
        flags.timed_out = True
    wall = time.perf_counter() - wall0
    bar.close()
    arrays = log.arrays()
    metrics = _score(arrays, path, scenario, flags, pacing)
    limits = act.limit_counts()
    metrics.update(limits)
    metrics["measurements_rejected"] = sum(int(st.extra.get("measurement_rejected", 0)) for st in stats)
    if faults is not None:
        metrics.update(fault_metrics(faults, arrays))
    arm_run = _check_arm_run(scenario, act, flags, metrics)
    return RunResult(
        scenario=scenario, controller=name, seed=seed, path=path, log=arrays, metrics=metrics,
        flags=flags, step_stats=stats, limit_counts=limits, wall_time_s=wall,
        sim_time_s=(k - k_first) * loop.dt, plant_steps=k - k_first, meta=dict(meta or {}),
        predictions=predictions, realtime=pacing, truth=truth,
        fault_events=[] if faults is None else list(faults.events), arm_run=arm_run,
    )  # fmt: skip


def _check_arm_run(
    scenario: Scenario, act: Actuator, flags: RunFlags, metrics: dict[str, Any]
) -> tuple[Any, Any] | None:
    """The robot arm's setpoints and joint commands from t = 0 on, checked as they would be exported
    (:func:`capsule_mpc.arm.check_run_trajectory`); None for an actuator that keeps none.

    Sets ``metrics['arm_ok']`` and, on a failed check, ``flags.arm_failure`` (the check's message).
    """
    trajectories = getattr(act, "joint_trajectory", None)
    if trajectories is None or not getattr(act, "record", False):
        return None
    from ..arm import ArmError, check_run_trajectory, run_trajectory_since

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


def _score(
    arrays: dict[str, np.ndarray],
    path: ReferencePath,
    scenario: Scenario,
    flags: RunFlags,
    pacing: RealtimeStats | None,
) -> dict[str, Any]:
    """The run's metrics over its own window (t = 0 to its end) and the flags that say how it ended."""
    tol = scenario.sim.completion_tol_m
    end_s = float(arrays["t_s"][-1]) if len(arrays["t_s"]) else 0.0
    metrics = run_metrics(
        arrays, path, window_end_s=max(end_s, 0.0), arrival_tol_m=tol,
        deadline_ms=1e3 / scenario.camera.rate_hz,
    )  # fmt: skip
    if pacing is not None:  # measured on the wall clock rather than from the reported solve times
        metrics["deadline_misses"] = pacing.deadline_misses
    near = metrics["final_error_mm"] <= tol * 1e3
    progress = arrays["progress_m"]
    left_mm = max(path.length_m - float(progress[-1]), 0.0) * 1e3 if len(progress) else math.nan
    flags.completed = flags.at_rest and near
    flags.stalled = flags.at_rest and not near
    outcome = flags.describe(metrics["final_error_mm"], left_mm, end_s)
    metrics.update(
        completed=flags.completed, at_rest=flags.at_rest, decoupled=flags.decoupled,
        dropped=flags.dropped, stalled=flags.stalled, timed_out=flags.timed_out,
        invalid_commands=flags.invalid_commands, outcome=outcome,
    )  # fmt: skip
    return metrics
