"""Fault injection (``faults:`` section): what breaks on a real rig, drawn from the run's seed.

Kinds (:data:`FAULT_KINDS`), each switched on by a rate or probability in
:class:`~capsule_mpc.config.FaultsConfig` and injected only from t = 0:

* ``solver_failure`` -- the MPC's solve reports failure (its solution kept, ``success`` false);
* ``solver_nan`` -- the solve returns a NaN solution while reporting success;
* ``solver_late`` -- the solve reports ``solver_late_ms`` more than it took (past the deadline);
* ``camera_drop`` -- a burst of dropped frames, U(one frame, ``camera_drop_burst_max_s``) long;
* ``camera_outlier`` -- a captured position jumps by ``camera_outlier_m`` in a random direction;
* ``arm_stall`` -- the EPM stops following its commands for ``arm_stall_s`` (the arm brakes
  to rest within its limits, then takes the latest command);
* ``latency_spike`` -- one command reaches the arm ``latency_spike_ms`` later.

Where they act: the solver faults in :class:`FaultySolver`, a wrapper around the MPC's solver
that the controller uses in place of its own when the runner hands it one (the controller's
logic is untouched: it sees a solver that misbehaves); the camera faults in
:class:`~capsule_mpc.sim.sensing.Camera` (at capture, so an outlier or a drop is delivered
``camera.latency_frames`` later); the arm stall and the latency spike in the runner's loop. The
controller learns of the rig's faults only through their effects.

Randomness: each kind draws from its own stream ``numpy.random.default_rng([seed,``
:data:`FAULT_STREAM` ``, i])`` (``i`` the kind's index), so switching one kind on changes
neither the plant's draw, the camera noise nor another kind's draws; a kind whose rate is 0
draws nothing. The solver kinds draw once per frame from t = 0 whether or not the controller
solves on it; a drawn solver fault counts when it is applied to a solve.

Recovery (:func:`recovery_times`): for each fault event, the time from the fault's end until
the capsule's tracking error (distance to the time-parameterised reference) is back within
``max(`` :data:`RECOVERY_TOL_MM` ``, its mean over the`` :data:`PRE_FAULT_WINDOW_S` ``before the
fault)``. Within one run that is all there is to compare with, and it is an upper bound: where
the path itself raises the error (a corner, a stick-slip episode) the time includes it. Given
the fault-free run of the same seed (same plant, start and camera noise), the level is instead
that run's error at the same time plus :data:`TWIN_MARGIN_MM` (at least
:data:`RECOVERY_TOL_MM`): the time the fault itself cost.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..config import FaultsConfig
from ..metrics import tracking_errors

__all__ = [
    "FAULT_KINDS",
    "FAULT_STREAM",
    "PRE_FAULT_WINDOW_S",
    "RECOVERY_TOL_MM",
    "SOLVER_FAULT_KINDS",
    "TWIN_MARGIN_MM",
    "FaultEvent",
    "FaultInjector",
    "FaultySolver",
    "Recovery",
    "fault_metrics",
    "recovery_times",
]

#: Second seed word of the fault streams (the camera uses the bare seed, the plant 1, the start 2).
FAULT_STREAM = 3
#: Every fault kind, in the order of their random streams.
FAULT_KINDS: tuple[str, ...] = (
    "solver_failure",
    "solver_nan",
    "solver_late",
    "camera_drop",
    "camera_outlier",
    "arm_stall",
    "latency_spike",
)
#: The kinds injected around the solver.
SOLVER_FAULT_KINDS: tuple[str, ...] = FAULT_KINDS[:3]
#: Tracking error below which the capsule counts as recovered whatever its pre-fault level, mm
#: (the MPC's tracking error on the lab rig is below 1 mm on 90 % of the frames of a run).
RECOVERY_TOL_MM = 1.0
#: Window before a fault whose mean tracking error is the level to recover to, s.
PRE_FAULT_WINDOW_S = 0.5
#: Margin over the fault-free run's tracking error within which a faulty run counts as recovered,
#: mm (the two runs' stick-slip episodes differ by a few tenths of a mm once their paths differ).
TWIN_MARGIN_MM = 0.5
#: Frames fall on the plant grid, up to half a plant step (0.5 ms at the 1 kHz minimum) from
#: j / camera rate: a frame this close before a fault's end counts as at its end, s.
_GRID_TOL_S = 1e-3


@dataclass(frozen=True)
class FaultEvent:
    """One injected fault.

    Attributes
    ----------
    kind : str
        One of :data:`FAULT_KINDS`.
    start_s, end_s : float
        When the fault began and when its direct effect ended (a drop burst's last lost frame plus
        one frame, a stall's end, a late command's arrival, an outlier's delivery frame plus one
        frame, a solver fault's frame plus one frame), s.
    """

    kind: str
    start_s: float
    end_s: float


def _per_step(rate_hz: float, step_s: float) -> float:
    """Probability that a Poisson process of ``rate_hz`` starts an event within ``step_s``."""
    return -math.expm1(-rate_hz * step_s)


class FaultInjector:
    """The faults of one run: their random streams, the state of those in progress, the counts.

    Parameters
    ----------
    config : FaultsConfig
        What to inject.
    seed : int
        The run's seed.
    frame_s : float
        Camera frame period, s.
    latency_frames : int
        Camera latency, frames (an outlier's effect starts when it is delivered).
    """

    def __init__(self, config: FaultsConfig, seed: int, frame_s: float, latency_frames: int = 0) -> None:
        self.config = config
        self.frame_s = float(frame_s)
        self.latency_s = latency_frames * self.frame_s
        self._rng = {k: np.random.default_rng([seed, FAULT_STREAM, i]) for i, k in enumerate(FAULT_KINDS)}
        self.counts: dict[str, int] = dict.fromkeys(FAULT_KINDS, 0)
        self.dropped_frames = 0
        self.events: list[FaultEvent] = []
        self.t_s = -math.inf
        self._solver_due: set[str] = set()
        self._solver_applied: set[str] = set()
        self._burst_end_s = -math.inf
        self.stall_end_s = -math.inf

    @property
    def solver_faults(self) -> bool:
        """Whether any solver fault is switched on."""
        return self.config.solver_enabled

    def _hit(self, kind: str, probability: float) -> bool:
        return probability > 0 and bool(self._rng[kind].random() < probability)

    def _record(self, kind: str, start_s: float, end_s: float) -> None:
        self.counts[kind] += 1
        self.events.append(FaultEvent(kind, start_s, end_s))

    def begin_frame(self, t_s: float) -> None:
        """A new frame at ``t_s`` (s): draw this frame's solver faults (none before t = 0)."""
        self.t_s = t_s
        self._solver_applied = set()
        self._solver_due = set()
        if t_s < 0:
            return
        cfg = self.config
        p = {
            "solver_failure": cfg.solver_failure_probability,
            "solver_nan": cfg.solver_nan_probability,
            "solver_late": cfg.solver_late_probability,
        }
        self._solver_due = {kind for kind in SOLVER_FAULT_KINDS if self._hit(kind, p[kind])}

    # ------------------------------------------------------------------ solver
    def corrupt_solve(self, result: Any) -> Any:
        """This frame's solver faults applied to a solve's ``SolveResult``.

        A failure or a NaN holds for every solve of the frame (the recovery iterations of a
        failed frame fail too); the late time is added to the frame's first solve only.
        """
        if not self._solver_due:
            return result
        due, t = self._solver_due, self.t_s
        for kind in sorted(due - self._solver_applied):
            self._record(kind, t, t + self.frame_s)
        first = not self._solver_applied
        self._solver_applied |= due
        if "solver_nan" in due:
            result = replace(result, success=True, w=np.full_like(result.w, np.nan), status="injected NaN")
        if "solver_failure" in due:
            result = replace(result, success=False, status=f"injected failure ({result.status})")
        if "solver_late" in due and first:
            result = replace(result, solve_ms=result.solve_ms + self.config.solver_late_ms)
        return result

    # ------------------------------------------------------------------ camera
    def camera_capture(self, t_s: float, capture: np.ndarray | None) -> np.ndarray | None:
        """A capture at ``t_s`` (s) after the camera faults: None when dropped, else maybe jumped."""
        if t_s < 0:
            return capture
        cfg = self.config
        if t_s >= self._burst_end_s and self._hit(
            "camera_drop", _per_step(cfg.camera_drop_burst_rate_hz, self.frame_s)
        ):
            length = self._rng["camera_drop"].uniform(
                min(self.frame_s, cfg.camera_drop_burst_max_s), cfg.camera_drop_burst_max_s
            )
            self._burst_end_s = t_s + length
            lost = math.ceil(length / self.frame_s - 1e-9)
            self._record("camera_drop", t_s, t_s + lost * self.frame_s + self.latency_s)
        if t_s < self._burst_end_s - 1e-9:
            self.dropped_frames += int(capture is not None)
            return None
        if capture is not None and self._hit("camera_outlier", cfg.camera_outlier_probability):
            angle = self._rng["camera_outlier"].uniform(-math.pi, math.pi)
            capture = capture + cfg.camera_outlier_m * np.array([math.cos(angle), math.sin(angle)])
            delivered = t_s + self.latency_s
            self._record("camera_outlier", delivered, delivered + self.frame_s)
        return capture

    # ------------------------------------------------------------------ arm and loop
    def stall_starts(self, t_s: float) -> bool:
        """Whether an arm stall starts at frame ``t_s`` (s); sets :attr:`stall_end_s`."""
        cfg = self.config
        if t_s < 0 or t_s < self.stall_end_s:
            return False
        if not self._hit("arm_stall", _per_step(cfg.arm_stall_rate_hz, self.frame_s)):
            return False
        self.stall_end_s = t_s + cfg.arm_stall_s
        self._record("arm_stall", t_s, self.stall_end_s)
        return True

    def latency_spike_s(self, t_s: float) -> float:
        """Extra delay of the command of frame ``t_s``, s (0 without a spike)."""
        if t_s < 0 or not self._hit("latency_spike", self.config.latency_spike_probability):
            return 0.0
        extra = self.config.latency_spike_ms * 1e-3
        self._record("latency_spike", t_s, t_s + extra)
        return extra

    def wrap_solver(self, solver: Any) -> FaultySolver:
        """``solver`` (an :class:`~capsule_mpc.mpc.solver.MPCSolver`) with this run's solver faults."""
        return FaultySolver(solver, self)


class FaultySolver:
    """An MPC solver whose solves go through :meth:`FaultInjector.corrupt_solve`.

    Every solve method (``solve``, ``rti``, ``sqp``, ``solve_converged``) calls the real solver
    and hands its result to the injector; every other attribute is the real solver's.
    """

    def __init__(self, solver: Any, injector: FaultInjector) -> None:
        self._solver = solver
        self._injector = injector

    def __getattr__(self, name: str) -> Any:
        return getattr(self._solver, name)

    def solve(self, *args: Any, **kwargs: Any) -> Any:
        """:meth:`MPCSolver.solve` with this frame's faults."""
        return self._injector.corrupt_solve(self._solver.solve(*args, **kwargs))

    def rti(self, *args: Any, **kwargs: Any) -> Any:
        """:meth:`MPCSolver.rti` with this frame's faults."""
        return self._injector.corrupt_solve(self._solver.rti(*args, **kwargs))

    def sqp(self, *args: Any, **kwargs: Any) -> Any:
        """:meth:`MPCSolver.sqp` with this frame's faults."""
        return self._injector.corrupt_solve(self._solver.sqp(*args, **kwargs))

    def solve_converged(self, *args: Any, **kwargs: Any) -> Any:
        """:meth:`MPCSolver.solve_converged` with this frame's faults."""
        return self._injector.corrupt_solve(self._solver.solve_converged(*args, **kwargs))


@dataclass
class Recovery:
    """Recovery times of a run's faults (see :func:`recovery_times`)."""

    times_s: dict[str, list[float]] = field(default_factory=dict)
    unrecovered: dict[str, int] = field(default_factory=dict)


def recovery_times(
    t_s: np.ndarray,
    error_mm: np.ndarray,
    events: list[FaultEvent],
    fault_free_error_mm: np.ndarray | None = None,
) -> Recovery:
    """For each event, the time from its end until the tracking error is back to its level.

    Parameters
    ----------
    t_s : numpy.ndarray
        Frame times of the run, s (increasing).
    error_mm : numpy.ndarray
        Tracking error at those frames, mm.
    events : list of FaultEvent
        The run's faults.
    fault_free_error_mm : numpy.ndarray, optional
        The tracking error of the fault-free run of the same seed at the same frames, mm; the
        level is then ``max(RECOVERY_TOL_MM, it + TWIN_MARGIN_MM)`` frame by frame instead of the
        pre-fault level (see the module docstring).

    Returns
    -------
    Recovery
        Per kind, the recovery times (s; 0 when the error is within the level when the fault ends)
        and the number of events after which the error never came back within the run.
    """
    out = Recovery()
    t_s, err = np.asarray(t_s, dtype=float), np.asarray(error_mm, dtype=float)
    twin = None if fault_free_error_mm is None else np.asarray(fault_free_error_mm, dtype=float)
    for ev in events:
        if twin is not None:
            level: float | np.ndarray = np.maximum(RECOVERY_TOL_MM, twin + TWIN_MARGIN_MM)
        else:
            before = (t_s >= ev.start_s - PRE_FAULT_WINDOW_S) & (t_s < ev.start_s)
            level = max(RECOVERY_TOL_MM, float(np.mean(err[before])) if np.any(before) else 0.0)
        after = np.flatnonzero((t_s >= ev.end_s - _GRID_TOL_S) & (err <= level))
        if len(after):
            out.times_s.setdefault(ev.kind, []).append(max(float(t_s[after[0]]) - ev.end_s, 0.0))
        elif len(t_s) and ev.end_s <= t_s[-1]:
            out.unrecovered[ev.kind] = out.unrecovered.get(ev.kind, 0) + 1
    return out


def fault_metrics(injector: FaultInjector, log: dict[str, np.ndarray]) -> dict[str, float | int]:
    """The run's fault counts and recovery times, for its metrics.

    Keys: ``faults_injected_<kind>`` for every kind, ``faults_dropped_frames`` (frames lost in
    drop bursts), ``fault_recovery_max_s`` and ``fault_recovery_mean_s`` over every recovered
    event (NaN without one), ``fault_recovery_max_s_<kind>`` per kind that occurred, and
    ``faults_unrecovered`` (events whose error did not come back before the run ended; events
    ending after the run's last frame are not counted).
    """
    metrics: dict[str, float | int] = {f"faults_injected_{k}": n for k, n in injector.counts.items()}
    metrics["faults_dropped_frames"] = injector.dropped_frames
    t = log["t_s"]
    err = 1e3 * tracking_errors(log)
    rec = recovery_times(t, err, injector.events)
    every = [x for times in rec.times_s.values() for x in times]
    metrics["fault_recovery_max_s"] = max(every) if every else math.nan
    metrics["fault_recovery_mean_s"] = float(np.mean(every)) if every else math.nan
    for kind, times in rec.times_s.items():
        metrics[f"fault_recovery_max_s_{kind}"] = max(times)
    metrics["faults_unrecovered"] = sum(rec.unrecovered.values())
    return metrics
