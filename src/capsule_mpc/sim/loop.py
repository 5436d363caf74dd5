"""The closed loop: plant + camera + controller + actuator, stepped frame by frame, logged and scored.

:class:`ClosedLoop` is the loop a user can own::

    loop = ClosedLoop(scenario, "mpc", path, seed=0)
    loop.reset()
    while not loop.done:
        frame = loop.step()          # one camera frame: plant, camera, controller, command
        ...                          # frame.t_s, frame.measurement, frame.command, frame.row
    result = loop.result()           # RunResult: log, metrics, flags

:meth:`ClosedLoop.run` does the same with :class:`Observer` objects called at fixed points of each
frame (:class:`ProgressBar`; wall-clock pacing and fault injection are observers the loop adds
itself when the run asks for them); :func:`simulate` is ``ClosedLoop(...).run(...)``.

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
  (:attr:`~capsule_mpc.interfaces.Controller.finished`: the MPC's placement is over) and the
  capsule has been at rest (slower than ``sim.rest_speed_mps``) for ``sim.rest_hold_s``; never
  while it moves;
* *decoupled* / *dropped*: the plant failed (see :mod:`.plant`); a last row is
  logged at the failure time;
* *timed out*: t reaches ``1.25 * nominal duration + sim.tail_s``.

The run reports the arrival time (first frame within ``sim.completion_tol_m`` of
the final waypoint with the progress at the path end), the final error at rest
and whether it *stalled* (came to rest farther than that tolerance from the end);
it is *completed* when it came to rest within it (and the controller did not give up, see
:attr:`~capsule_mpc.interfaces.Controller.gave_up`). The path's metrics cover its nominal time,
t = 0 to the path's end, for every controller (:func:`capsule_mpc.metrics.run_metrics`); the end at
rest is scored from the plant's truth by :func:`capsule_mpc.metrics.end_metrics` (the final error
as it is and as the camera sees it with the draw's bias, the time to place, the placement moves
and the phase the run ended in).

Real-time mode (``ClosedLoop(..., realtime=True)``, ``capsule-mpc simulate --realtime``): the
loop is paced to the wall clock at the camera rate. Frame ``i`` (counted from the first frame) has
the wall-clock slot ``[T0 + i P, T0 + (i + 1) P)``, P the
frame period: the plant is advanced to the frame's time, the loop sleeps until
the slot starts, then the controller is called. A command ready after the end of
its slot is a *deadline miss*: it is counted, the command is still applied, and
the loop carries on (the next frames start late, at once, until the schedule is
caught up). The loop sleeps only between frames, never inside a controller.
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

Predictions: after each step the loop records
:meth:`~capsule_mpc.interfaces.Controller.predicted_capsule_path` (``None`` for
controllers that do not predict), one entry per logged frame.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from ..budget import TIMEOUT_FACTOR
from ..config import Scenario
from ..interfaces import (
    Actuator,
    Command,
    Controller,
    Measurement,
    StepOutcome,
    StepStats,
    make_actuator,
    make_controller,
)
from ..metrics import end_metrics, start_metrics
from ..paths import ReferencePath
from .actuation import SimpleArm
from .columns import INT_COLUMNS, LOG_COLUMNS, STR_COLUMNS
from .faults import FaultInjector, fault_metrics
from .plant import FAILURE_DECOUPLED, OK, CapsulePlant
from .runner import (
    START_STREAM,
    PathProgress,
    RealtimeStats,
    RunFlags,
    RunResult,
    check_arm_run,
    realtime_scenario,
    score_run,
    start_pose,
)
from .sensing import Camera
from .start_bound import breakaway_bound_s
from .truth import PlantTruth, draw_plant_truth

__all__ = ["ClosedLoop", "FaultInjection", "Frame", "Observer", "Pacer", "ProgressBar", "simulate"]

#: Progress bar layout: simulated seconds out of the cut-off time.
_BAR_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} s simulated [{elapsed}]"


@dataclass
class Frame:
    """One camera frame of a run, as :meth:`ClosedLoop.step` returns it.

    Attributes
    ----------
    index : int
        Frame number ``j`` (frame time ``j / camera.rate_hz`` on the plant grid; negative in the
        settle phase).
    t_s : float
        Frame time, s (0 is the start of the path).
    k : int
        Plant step of the frame.
    row : dict
        The frame's log row (columns of :data:`capsule_mpc.sim.log.LOG_COLUMNS`): true states at
        ``t_s``, the measurement, the command and the controller's stats.
    measurement : Measurement or None
        What the camera delivered; None on a failure row (the plant failed before the frame).
    command : Command or None
        What the controller returned (as returned, before the loop's check); None on a failure row.
    stats : StepStats or None
        The controller's stats (an invalid command gets status ``invalid``); None on a failure row.
    prediction : numpy.ndarray (N, 2) or None
        The controller's predicted capsule path after its step, m; None if it predicts nothing.
    step_s : float
        Wall time of the controller's step, s (NaN on a failure row).
    ready_wall_s : float
        ``time.perf_counter()`` when the controller returned, s (NaN on a failure row).
    extra_delay_s : float
        Extra delay of this frame's command (a latency spike injected by a fault), s.
    """

    index: int
    t_s: float
    k: int
    row: dict[str, Any]
    measurement: Measurement | None = None
    command: Command | None = None
    stats: StepStats | None = None
    prediction: np.ndarray | None = None
    step_s: float = math.nan
    ready_wall_s: float = math.nan
    extra_delay_s: float = 0.0


class Observer:
    """Called by :meth:`ClosedLoop.step` at fixed points of each frame; override what you need.

    The order within a frame: :meth:`frame_start` (the plant has reached the frame time; the
    camera has not captured), :meth:`before_controller` (the measurement is in ``frame``),
    :meth:`after_controller` (the command and ``frame.step_s`` are in ``frame``), :meth:`frame_end`
    (the row is complete and logged). :meth:`on_reset` after :meth:`ClosedLoop.reset`;
    :meth:`on_end` once the run is over, with the metrics it may add to.
    """

    def on_reset(self, loop: ClosedLoop) -> None:
        """The loop has been reset (plant, actuator, camera and controller at their start)."""

    def frame_start(self, loop: ClosedLoop, frame: Frame) -> None:
        """The plant is at the frame's time; set ``frame.extra_delay_s`` to delay its command."""

    def before_controller(self, loop: ClosedLoop, frame: Frame) -> None:
        """The camera's measurement is ready; the controller is called next."""

    def after_controller(self, loop: ClosedLoop, frame: Frame) -> None:
        """The controller has returned (``frame.command``, ``frame.step_s``)."""

    def frame_end(self, loop: ClosedLoop, frame: Frame) -> None:
        """The frame's row is complete and logged."""

    def on_end(self, loop: ClosedLoop, metrics: dict[str, Any]) -> None:
        """The run is over; ``metrics`` may be added to."""


class Pacer(Observer):
    """Paces the loop to the wall clock at the camera rate and counts deadline misses (real-time mode).

    Frame ``i`` (counted from the first) has the wall-clock slot ``[T0 + i P, T0 + (i + 1) P)``, P
    the frame period, T0 the wall time of the reset: the loop sleeps until the slot starts, then
    calls the controller; a command ready after the slot's end is a deadline miss.
    """

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.stats = RealtimeStats(period_ms=period_s * 1e3)
        self._slot_start = 0.0

    def before_controller(self, loop: ClosedLoop, frame: Frame) -> None:
        self._slot_start = loop.wall0 + (frame.index - loop.first_frame) * self.period_s
        self.stats.slept_s += _wait_until(self._slot_start)

    def after_controller(self, loop: ClosedLoop, frame: Frame) -> None:
        late_s = frame.ready_wall_s - (self._slot_start + self.period_s)
        self.stats.record(frame.t_s, frame.step_s, late_s)

    def on_end(self, loop: ClosedLoop, metrics: dict[str, Any]) -> None:
        metrics["deadline_misses"] = self.stats.deadline_misses  # from the wall clock, not solve times


class ProgressBar(Observer):
    """A tqdm progress bar of simulated time (appears only if the run takes longer than a second)."""

    def __init__(self, desc: str = "simulate") -> None:
        self.desc = desc
        self._bar: Any = None

    def on_reset(self, loop: ClosedLoop) -> None:
        total = round(loop.t_cut_s + loop.scenario.sim.settle_s, 1)
        self._bar = tqdm(total=total, desc=self.desc, delay=1.0, leave=False, bar_format=_BAR_FORMAT)

    def frame_end(self, loop: ClosedLoop, frame: Frame) -> None:
        if self._bar is not None and frame.measurement is not None:
            self._bar.update(loop.frame_s)

    def on_end(self, loop: ClosedLoop, metrics: dict[str, Any]) -> None:
        if self._bar is not None:
            self._bar.close()


class FaultInjection(Observer):
    """The scenario's faults (:mod:`.faults`) applied to the loop: camera drop bursts and outliers,
    the controller's solver failures, arm stalls and latency spikes, on the run's own random streams.

    The loop adds it itself when ``scenario.faults`` switches any fault on (and gives the injector
    to the camera and the controller's solver at its reset).
    """

    def __init__(self, injector: FaultInjector) -> None:
        self.injector = injector

    def frame_start(self, loop: ClosedLoop, frame: Frame) -> None:
        faults = self.injector
        faults.begin_frame(frame.t_s)
        if faults.stall_starts(frame.t_s):
            loop.stall(frame.k, frame.k + round(faults.config.arm_stall_s / loop.dt))
        frame.extra_delay_s = faults.latency_spike_s(frame.t_s)

    def on_end(self, loop: ClosedLoop, metrics: dict[str, Any]) -> None:
        metrics.update(fault_metrics(self.injector, loop.log.arrays()))


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


def _wait_until(deadline: float) -> float:
    """Sleep until ``time.perf_counter()`` reaches ``deadline``; returns the time slept, s."""
    remaining = deadline - time.perf_counter()
    if remaining <= 0:
        return 0.0
    time.sleep(remaining)
    return remaining


def fault_injector(scenario: Scenario, seed: int) -> FaultInjector | None:
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


class ClosedLoop:
    """The simulated rig and a controller, stepped one camera frame at a time (module docstring).

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
    actuator : Actuator, optional
        The EPM carrier; default :func:`~capsule_mpc.interfaces.make_actuator` (``sim.actuator``;
        the simple arm with the draw's servo lag).
    plant : CapsulePlant, optional
        The plant; default the finite-magnet plant of the draw.
    plant_seed : int, optional
        Seed of the rig: the plant draw (its servo lag, camera bias and noise level, start
        conditions) and the start offset, >= 0; None: ``seed`` (one seed for everything).
        Several runs with one ``plant_seed`` and their own ``seed`` run on one rig with
        independent camera noise. Ignored for the draw when ``plant`` is given (its truth is used).
    realtime : bool
        Pace the loop to the wall clock at the camera rate and count deadline misses
        (:class:`Pacer`); the controller gets :func:`~.runner.realtime_scenario`. The run then
        takes as long as the simulated time (settle phase included).
    meta : dict, optional
        Provenance copied into :attr:`RunResult.meta` (e.g. ``config``, ``waypoints_file``).

    Attributes
    ----------
    done : bool
        Whether the run is over (at rest after the path, the plant failed, or timed out).
    flags : RunFlags
        How the run ended (filled as it goes; final after :meth:`result`).
    plant, actuator, camera, controller, truth
        The loop's parts (after :meth:`reset`).
    """

    def __init__(
        self,
        scenario: Scenario,
        controller: Controller | str,
        path: ReferencePath,
        seed: int,
        *,
        actuator: Actuator | None = None,
        plant: CapsulePlant | None = None,
        plant_seed: int | None = None,
        realtime: bool = False,
        meta: dict[str, Any] | None = None,
    ) -> None:
        if plant_seed is not None and plant_seed < 0:
            raise ValueError(f"plant_seed: must be >= 0, got {plant_seed}")
        self.controller = make_controller(controller) if isinstance(controller, str) else controller
        own_name = self.controller.name or type(self.controller).__name__
        self.name: str = controller if isinstance(controller, str) else own_name
        self.scenario = realtime_scenario(scenario) if realtime else scenario
        self.path, self.seed, self.meta = path, seed, dict(meta or {})
        self.rig_seed = seed if plant_seed is None else int(plant_seed)
        self._plant_arg, self._actuator_arg = plant, actuator
        sim, rate = self.scenario.sim, self.scenario.camera.rate_hz
        self.dt = 1.0 / sim.plant_rate_hz
        self.frame_s = 1.0 / rate
        self.ratio = sim.plant_rate_hz / rate
        self.first_frame = math.ceil(-sim.settle_s * rate - 1e-9)
        self.t_cut_s = TIMEOUT_FACTOR * path.duration_s + sim.tail_s
        self.last_frame = math.floor(self.t_cut_s * rate + 1e-9)
        self.realtime = realtime
        self.solve_time_delay = self.scenario.plant.compute_delay_mode == "solve_time"
        self.pacer: Pacer | None = None
        self.done = True

    def reset(self) -> None:
        """Draw the rig, put the capsule and the EPM at their start (:func:`~.runner.start_pose`), reset
        the controller; the loop then stands before its first frame."""
        scenario, path = self.scenario, self.path
        given = self._plant_arg
        truth = draw_plant_truth(scenario, self.rig_seed) if given is None else given.truth
        plant = given if given is not None else CapsulePlant(scenario, truth=truth)
        act = self._actuator_arg if self._actuator_arg is not None else _make_actuator(scenario, truth)
        self.truth, self.plant, self.actuator = truth, plant, act
        bias = (truth.camera_bias_x_m, truth.camera_bias_y_m)
        injector = fault_injector(scenario, self.seed)
        self.camera = Camera(
            scenario.camera,
            np.random.default_rng(self.seed),
            bias_m=bias,
            noise_std_m=truth.camera_noise_std_m,
            faults=injector,
        )
        start_rng = np.random.default_rng([self.rig_seed, START_STREAM])
        epm0, capsule0, theta0 = start_pose(scenario, plant, path, start_rng)
        plant.reset(capsule0, theta_s=theta0)
        act.reset(epm0)
        plant.evaluate_forces(*epm0.tolist())
        # The friction heals at rest through the settle phase (theta grows by the time at rest).
        heading = np.asarray(path.velocity(np.array([0.0]))[0], dtype=float)
        norm = float(np.linalg.norm(heading))
        self.start_bound_s = (
            breakaway_bound_s(plant, epm0, capsule0, theta0 + scenario.sim.settle_s, heading / norm)
            if norm > 0
            else math.nan
        )
        self.controller.solver_wrapper = (
            injector.wrap_solver if injector is not None and injector.solver_faults else None
        )
        self.controller.reset(scenario, path, epm0.copy())
        self.injector = injector
        self.pacer = Pacer(self.frame_s) if self.realtime else None
        self.pending: deque[tuple[int, np.ndarray]] = deque()
        self.last_ready = -(2**62)
        self.tracker = PathProgress(path)
        self.flags = RunFlags()
        self.rest_s = 0.0
        self.first_motion_s = math.nan  # when the capsule first slid at t >= 0, s
        self.cmd_applied = np.zeros(3)
        self.stall_end_k = -(2**62)  # plant step at which an arm stall ends
        self._arm_log: list[tuple[float, np.ndarray]] = []  # arm commands not yet noted by _advance
        self._epm_buffer = np.empty((0, 3))
        self.arm_cmd = np.zeros(3)  # the latest command to reach the arm (kept through a stall)
        self.log = _Log(self.last_frame - self.first_frame + 2)
        self.step_stats: list[StepStats] = []
        self.predictions: list[np.ndarray | None] = []
        self.next_frame = self.first_frame
        self.k = self.k_first = round(self.first_frame * self.ratio)
        builtin = [FaultInjection(injector)] if injector is not None else []
        self.observers: list[Observer] = [*builtin, *([self.pacer] if self.pacer else [])]
        self.done = False
        self.wall0 = time.perf_counter()

    # -- the plant and the arm between frames ---------------------------------------------------

    def _to_arm(self, k: int, vel: np.ndarray) -> None:
        """A command reaches the arm at plant step ``k``; a stalled arm keeps it for later."""
        self.arm_cmd = vel
        if k >= self.stall_end_k:
            self._set_arm(k, vel)

    def stall(self, k: int, end_k: int) -> None:
        """The arm stops following its commands from plant step ``k`` to ``end_k`` (brakes to rest)."""
        self.stall_end_k = end_k
        self._set_arm(k, np.zeros(3))

    def _advance(self, k: int, k_to: int) -> tuple[int, int]:
        """Step the arm and the plant from plant step ``k`` to ``k_to``; returns (k, status). A
        failing step counts: the arm has moved for it and the plant failed under the arm's new
        position, so the failure is at the step's end (its row comes after the last frame's).

        The arm runs first over the whole span (it does not depend on the capsule), then the plant
        over the arm's positions in one compiled call (:meth:`CapsulePlant.advance`). If the plant
        fails before the span's end, the arm goes back to its state at ``k`` and runs again only to
        the failing step. An actuator without ``snapshot``/``restore`` is stepped with the plant."""
        n = k_to - k
        snapshot = getattr(self.actuator, "snapshot", None)
        if n <= 0 or snapshot is None:
            return self._advance_each(k, k_to)
        state = snapshot()
        self._arm_log.clear()  # commands sent before the span are in the snapshot
        if len(self._epm_buffer) < n:
            self._epm_buffer = np.empty((n, 3))
        epm = self._epm_buffer[:n]
        calls: list[tuple[int, float, np.ndarray]] = []
        advance = getattr(self.actuator, "advance_xyz", None)
        i = 0
        while i < n:  # the arm in compiled spans between the steps at which commands reach it
            self._arm_inputs(k + i, calls, i)
            if advance is None:
                epm[i] = self.actuator.step_xyz(self.dt)
                i += 1
                continue
            j = self._next_arm_input(k + i, k_to) - k
            advance(self.dt, epm[i:j])
            i = j
        steps, status = self._plant_advance(k, epm)
        if steps < n:  # the plant failed early: the arm only reached the failing step
            self.actuator.restore(state)  # type: ignore[attr-defined]
            for i in range(steps):
                for _, t_s, vel in (c for c in calls if c[0] == i):
                    self.actuator.set_velocity_command(t_s, vel)
                self.actuator.step_xyz(self.dt)
        return k + steps, status

    def _plant_advance(self, k: int, epm: np.ndarray) -> tuple[int, int]:
        """The plant from step ``k`` over the EPM positions ``epm`` (n, 3) in one compiled call; until
        the capsule first slides at t >= 0, one call per step, so that time is known to the plant's
        step (:attr:`first_motion_s`). Returns (steps, status) as :meth:`CapsulePlant.advance`."""
        plant, n = self.plant, len(epm)
        if not math.isnan(self.first_motion_s) or k + n < 0:
            return plant.advance(self.dt, epm)
        for i in range(n):
            _, status = plant.advance(self.dt, epm[i : i + 1])
            if status != OK:
                return i + 1, status
            if self._note_motion(k + i + 1) and i + 1 < n:
                steps, status = plant.advance(self.dt, epm[i + 1 :])
                return i + 1 + steps, status
        return n, OK

    def _note_motion(self, k: int) -> bool:
        """After plant step ``k``: whether the capsule has slid at t >= 0 (its first time noted)."""
        if math.isnan(self.first_motion_s) and k >= 0 and not self.plant.stuck:
            self.first_motion_s = k * self.dt
        return not math.isnan(self.first_motion_s)

    def _next_arm_input(self, k: int, k_to: int) -> int:
        """The first plant step after ``k`` (and at most ``k_to``) at which a command reaches the arm."""
        nxt = k_to
        if self.pending:
            nxt = min(nxt, self.pending[0][0])
        if self.stall_end_k > k:
            nxt = min(nxt, self.stall_end_k)
        return max(nxt, k + 1)

    def _arm_inputs(self, k: int, calls: list[tuple[int, float, np.ndarray]], i: int) -> None:
        """Commands due at plant step ``k`` reach the arm (recorded in ``calls`` at index ``i``)."""
        pending = self.pending
        while pending and pending[0][0] <= k:
            _, vel = pending.popleft()
            self._to_arm(k, vel)
        if k == self.stall_end_k:  # the stall is over: the arm takes the latest command
            self._set_arm(k, self.arm_cmd)
        calls.extend((i, t_s, vel) for t_s, vel in self._arm_log)
        self._arm_log.clear()

    def _set_arm(self, k: int, vel: np.ndarray) -> None:
        """The arm's velocity command from plant step ``k``, noted for a replay of the frame."""
        t_s = k * self.dt
        self.actuator.set_velocity_command(t_s, vel)
        self._arm_log.append((t_s, vel))

    def _advance_each(self, k: int, k_to: int) -> tuple[int, int]:
        """:meth:`_advance` one plant step at a time (Python calls per step)."""
        step_plant, step_act, pending = self.plant.step, self.actuator.step_xyz, self.pending
        status = OK
        while k < k_to:
            while pending and pending[0][0] <= k:
                _, vel = pending.popleft()
                self._to_arm(k, vel)
            if k == self.stall_end_k:  # the stall is over: the arm takes the latest command
                self._set_arm(k, self.arm_cmd)
            ex, ey, ez = step_act(self.dt)
            status = step_plant(self.dt, ex, ey, ez)
            k += 1
            self._note_motion(k)
            if status != OK:
                break
        self._arm_log.clear()
        return k, status

    def _command(self, k: int, t: float, vel: np.ndarray, step_s: float, extra_s: float = 0.0) -> None:
        """Send the frame's command (zero at t < 0): applied ``plant.compute_delay_s`` from now, plus
        the controller's ``step_s`` in ``solve_time`` mode, plus ``extra_s`` (a latency spike), and
        never before the previous frame's command (a rig's loop handles one frame at a time)."""
        self.cmd_applied = vel if t >= 0 else np.zeros(3)
        delay_s = self.truth.compute_delay_s + (step_s if self.solve_time_delay else 0.0) + extra_s
        ready = max(k + round(delay_s / self.dt), self.last_ready)
        self.last_ready = ready
        if ready <= k and not self.pending:
            self._to_arm(k, self.cmd_applied)
        else:
            self.pending.append((ready, self.cmd_applied))

    def _state_row(self, t: float) -> dict[str, Any]:
        """The true states at frame time ``t``."""
        plant, act = self.plant, self.actuator
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

    def _at_rest_after_end(self, t: float, finished: bool = True) -> bool:
        """Whether the capsule has rested (speed < ``sim.rest_speed_mps``) for ``sim.rest_hold_s``
        after the path's nominal end, with the controller ``finished`` (:attr:`Controller.finished`)."""
        slow = math.hypot(self.plant.vx, self.plant.vy) < self.scenario.sim.rest_speed_mps
        resting = slow and t >= self.path.duration_s and finished
        self.rest_s = self.rest_s + self.frame_s if resting else 0.0
        return self.rest_s >= self.scenario.sim.rest_hold_s - 1e-9

    # -- one frame ----------------------------------------------------------------------------

    def step(self) -> Frame:
        """Run one camera frame: advance the plant and the arm to the frame's time, capture, call the
        controller, send its command and log the frame.

        Returns
        -------
        Frame
            What happened in the frame; :attr:`done` is set when it ended the run.

        Raises
        ------
        RuntimeError
            If the loop was not reset or the run is over.
        """
        if self.done:
            raise RuntimeError("ClosedLoop.step: the run is over (or was never reset); call reset()")
        j = self.next_frame
        self.next_frame += 1
        k, status = self._advance(self.k, round(j * self.ratio))
        self.k = k
        t = k * self.dt
        row = self._state_row(t)
        frame = Frame(index=j, t_s=t, k=k, row=row)
        if status != OK:
            return self._fail(frame, decoupled=status == FAILURE_DECOUPLED)
        for obs in self.observers:
            obs.frame_start(self, frame)
        frame.measurement = meas = self.camera.frame(t, self.plant.position_m)
        for obs in self.observers:
            obs.before_controller(self, frame)
        ctrl = self.controller
        c0 = time.perf_counter()
        cmd = ctrl.step(t, meas, self.actuator.position_m)
        c1 = time.perf_counter()
        frame.command, frame.step_s, frame.ready_wall_s = cmd, c1 - c0, c1
        for obs in self.observers:
            obs.after_controller(self, frame)
        frame.prediction = ctrl.predicted_capsule_path()
        self.predictions.append(frame.prediction)
        vel = _check_command(cmd)
        stats = (
            cmd.stats
            if isinstance(cmd, Command)
            else StepStats(status="invalid", failed=True, outcome=StepOutcome.INVALID)
        )
        if vel is None:
            self.flags.invalid_commands += 1
            vel = np.zeros(3)
        frame.stats = stats
        self.step_stats.append(stats)
        step_s = c1 - c0
        if math.isfinite(stats.solve_ms):  # a step lasts at least the solve it reports
            step_s = max(step_s, stats.solve_ms * 1e-3)
        self._command(k, t, vel, step_s, frame.extra_delay_s)
        if meas.position_m is not None:
            row["meas_x_m"], row["meas_y_m"] = float(meas.position_m[0]), float(meas.position_m[1])
        row["meas_capture_t_s"], row["controller_ms"] = meas.capture_t_s, (c1 - c0) * 1e3
        row.update(zip(("cmd_vx_mps", "cmd_vy_mps", "cmd_vz_mps"), self.cmd_applied.tolist()))
        row["solve_ms"], row["solver_status"] = stats.solve_ms, stats.status
        row["solver_failed"], row["phase"] = int(stats.failed), stats.phase
        self.log.add(row)
        for obs in self.observers:
            obs.frame_end(self, frame)
        if self._at_rest_after_end(t, ctrl.finished):
            self.flags.at_rest = self.done = True
            self.flags.gave_up = ctrl.gave_up
        elif j >= self.last_frame:
            self.flags.timed_out = self.done = True
        return frame

    def _fail(self, frame: Frame, *, decoupled: bool) -> Frame:
        """The plant failed (decoupled or dropped) before the frame: log a last row and end the run."""
        flags, plant = self.flags, self.plant
        flags.decoupled, flags.dropped = decoupled, not decoupled
        flags.failure, flags.failure_t_s = plant.failure, frame.t_s
        row = frame.row
        row.update(zip(("cmd_vx_mps", "cmd_vy_mps", "cmd_vz_mps"), self.cmd_applied.tolist()))
        row["solver_status"], row["solver_failed"], row["phase"] = "", 0, ""
        self.log.add(row)
        self.predictions.append(None)
        self.done = True
        for obs in self.observers:
            obs.frame_end(self, frame)
        return frame

    # -- the whole run ------------------------------------------------------------------------

    def result(self) -> RunResult:
        """Score the run so far (its window: t = 0 to the last frame) and return everything it produced."""
        wall = time.perf_counter() - self.wall0
        arrays = self.log.arrays()
        pacing = None if self.pacer is None else self.pacer.stats
        metrics = score_run(arrays, self.path, self.scenario, self.flags)
        limits = self.actuator.limit_counts()
        metrics.update(limits)
        stats = self.step_stats
        bias = np.array([self.truth.camera_bias_x_m, self.truth.camera_bias_y_m])
        moves = max((int(st.extra.get("placement_moves", 0)) for st in stats), default=0)
        metrics.update(end_metrics(arrays, self.path, bias, moves, self.flags.at_rest))
        metrics.update(start_metrics(self.first_motion_s, self.start_bound_s))
        metrics["measurements_rejected"] = sum(int(st.extra.get("measurement_rejected", 0)) for st in stats)
        for obs in self.observers:
            obs.on_end(self, metrics)
        arm_run = check_arm_run(self.scenario, self.actuator, self.flags, metrics)
        return RunResult(
            scenario=self.scenario,
            controller=self.name,
            seed=self.seed,
            path=self.path,
            log=arrays,
            metrics=metrics,
            flags=self.flags,
            step_stats=stats,
            limit_counts=limits,
            wall_time_s=wall,
            sim_time_s=(self.k - self.k_first) * self.dt,
            plant_steps=self.k - self.k_first,
            meta=dict(self.meta),
            predictions=self.predictions,
            realtime=pacing,
            truth=self.truth,
            fault_events=[] if self.injector is None else list(self.injector.events),
            arm_run=arm_run,
        )

    def run(self, observers: Sequence[Observer] = ()) -> RunResult:
        """Reset, step until the run is over (``observers`` called in each frame), return the result."""
        self.reset()
        self.observers.extend(observers)
        for obs in self.observers:
            obs.on_reset(self)
        while not self.done:
            self.step()
        return self.result()


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
    observers: Sequence[Observer] = (),
) -> RunResult:
    """Run one closed-loop simulation: :class:`ClosedLoop` run to its end.

    Parameters are those of :class:`ClosedLoop`, plus ``progress``: show a progress bar (appears
    only if the run takes longer than a second), and ``observers``: called in every frame
    (:meth:`ClosedLoop.run`; e.g. :class:`capsule_mpc.telemetry.observer.Telemetry`).

    Returns
    -------
    RunResult
        Log, metrics, flags, per-step stats, limit counts and timing. Failures (decoupled,
        dropped, invalid commands) are values in the result, not exceptions.
    """
    loop = ClosedLoop(
        scenario,
        controller,
        path,
        seed,
        actuator=actuator,
        plant=plant,
        plant_seed=plant_seed,
        realtime=realtime,
        meta=meta,
    )
    bar = [ProgressBar(f"simulate {loop.name}")] if progress else []
    return loop.run([*bar, *observers])
