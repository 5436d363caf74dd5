"""The final approach: bring a capsule that stopped short of (or past) the final waypoint onto it.

After the path's nominal end the MPC has braked the capsule; on a real plate it then either sticks
(static friction) or creeps on at a fraction of a mm/s under a force its smoothed friction model
believes moves it briskly, and it comes to rest a millimetre or two off. What the physics offers,
measured on the ``lab`` plant (a capsule held at rest, the EPM pushed out along one axis and back):

* a *breakaway pulse* from rest does not place the capsule: once the lateral force passes the
  healed static friction the capsule lurches until the magnetic spring has taken the excess back,
  2.4-5 mm along x (stiff axis) and ~14 mm along y, whatever the pulse's size beyond breakaway
  (the slide is ``2 (F_static - F_sliding) / k``, set by the friction, not by the pulse);
* below breakaway, a capsule that still moves *creeps*, its speed growing steeply with the force
  (rate-and-state friction is velocity-strengthening), so a slowly dragged EPM makes it crawl at
  about the EPM's speed and it stops within a few micrometres when the force is taken away.

So the approach does what an operator does with a sticky slide: drag the magnet slowly toward the
target, watch the capsule, let go when it arrives. Phases (one :class:`FinalApproach` per run):

``tracking``
    The MPC is in control. From the path's nominal end on, once the capsule's measured speed
    (a line fit over ``place.approach.window_s`` of camera frames) is below ``place.approach.speed_mps``:
    within ``place.tolerance_m`` of the end it is ``done``; otherwise a *crawl* starts.
``crawl``
    The EPM moves along the direction to the target, û, fixed for the attempt, at the desired
    crawl speed ``v_d = clip(d / τ, v/4, v)`` (d the remaining distance along û, τ
    :data:`CRAWL_TIME_CONSTANT_S`, v = ``place.approach.speed_mps`` halved after each overshoot)
    plus the speed error ``v_d - v̂`` (v̂ the measured speed along û): a stuck or slow capsule sees
    the lead, hence the force, grow until it moves. The lead is capped by the controller's own
    model (never the plant's truth): the model force along û (force model plus the estimated
    constant disturbance) stays below ``place.approach.force_fraction`` of the model's breakaway
    (:meth:`capsule_mpc.friction.FrictionBelief.breakaway_n`: the learned static friction after the
    capsule's rest so far where the model has one, else ``mu0 F_N``; plus the tether drag), and
    ``|lead - lead_eq| <= limits.max_lead_m``. The crawl ends when the capsule is about to reach
    the target (``d <= v̂ * RELEASE_LEAD_S``), has passed it, has not come closer by the
    tolerance for ``place.approach.attempt_s`` (it is stuck below the cap), or when the approach's
    time is up. A capsule still creeping on is never let go short of the
    target (stopped, it would have to break loose again): out of time, the EPM holds the lead.
``release``
    The EPM backs off along -û to the lead it had when the crawl began minus
    ``place.approach.backoff_m``, and at least to the lead at which the controller believes the
    lateral force vanishes (its force model plus its estimated constant disturbance; the component
    along û), taking the force away so the capsule stops where it is (a capsule that crept under
    the lead it had before the crawl would creep on past the target).
``observe``
    The EPM holds still for ``place.approach.observe_s``; the mean of the frames after the first
    :data:`OBSERVE_SETTLE_S` is where the capsule rests. Within the tolerance: ``done``. Otherwise a
    new attempt from the measured rest (a new û; the crawl speed halved if it overshot), up to
    ``place.approach.max_attempts`` and ``place.approach.max_s`` (a crawl under way when the time is
    up is released and observed); then, or when an attempt moved the capsule less than the
    tolerance toward the target (it is stuck below the cap, and only a breakaway lurch, far larger
    than the error, would move it), ``gave_up``: the EPM holds.

Every command passes Ruckig's velocity control here (``limits.jerk_mps3``,
``limits.accel_mps2``) and then the controller's safety layer (:func:`capsule_mpc.safety.safe_command`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import ruckig

from ..config import Scenario
from ..dynamics import normal_force_expr
from ..estimation import fit_window
from ..friction import FrictionBelief
from ..interfaces import Measurement
from ..magnetics import equilibrium_lead
from ..paths import ReferencePath
from .belief import RigBelief

__all__ = [
    "CRAWL_TIME_CONSTANT_S",
    "OBSERVE_SETTLE_S",
    "RELEASE_LEAD_S",
    "Attempt",
    "FinalApproach",
    "VelocityLimiter",
    "epm_ruckig",
]

#: Time constant of the crawl speed profile, s: the desired speed is the remaining distance over
#: this (bounded), so a 1 mm error is crawled in about a second.
CRAWL_TIME_CONSTANT_S = 1.0
#: The crawl lets go this long before the capsule would reach the target at its measured speed, s:
#: about the time the EPM needs to back off (a few mm at the acceleration limit) plus a frame.
RELEASE_LEAD_S = 0.15
#: Frames of the first part of an observation are skipped (the capsule may still be stopping), s.
OBSERVE_SETTLE_S = 0.3
#: A release ends when the lead along û is within this of its target, m.
_RELEASE_TOL_M = 2e-4
#: Crawl speed floor as a fraction of the crawl speed: the last fraction of a millimetre is still
#: crawled at a speed the capsule does not stop at.
_MIN_SPEED_FRACTION = 0.25
#: Largest EPM speed of the crawl and the release, in units of the crawl speed.
_EPM_SPEED_FACTOR = 4.0


def epm_ruckig(
    scenario: Scenario, dt_s: float
) -> tuple[ruckig.Ruckig, ruckig.InputParameter, ruckig.OutputParameter]:
    """Ruckig for the EPM's three axes at the frame period ``dt_s``, within ``limits.speed_mps``,
    ``limits.accel_mps2`` and ``limits.jerk_mps3`` per axis, each axis on its own time-optimal
    profile (synchronised, a millimetre's correction on one axis would stretch the motion on the
    others); the position interface unless the caller sets another."""
    lim = scenario.limits
    inp = ruckig.InputParameter(3)
    inp.synchronization = ruckig.Synchronization.No
    inp.max_velocity = [lim.speed_mps] * 3
    inp.max_acceleration = [lim.accel_mps2] * 3
    inp.max_jerk = [lim.jerk_mps3] * 3
    return ruckig.Ruckig(3, dt_s), inp, ruckig.OutputParameter(3)


class VelocityLimiter:
    """Ruckig's velocity control of the EPM, one frame at a time (:func:`epm_ruckig`), carrying the
    acceleration it left from frame to frame.

    Parameters
    ----------
    scenario : Scenario
        ``limits.speed_mps``, ``limits.accel_mps2`` and ``limits.jerk_mps3``.
    dt_s : float
        The frame period, s.
    """

    def __init__(self, scenario: Scenario, dt_s: float) -> None:
        self.dt_s = dt_s
        self.accel = np.zeros(3)
        self._otg, self._in, self._out = epm_ruckig(scenario, dt_s)
        self._in.control_interface = ruckig.ControlInterface.Velocity

    def limit(self, u: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        """One frame of Ruckig's velocity control from ``u_prev`` (and the acceleration it left)
        toward ``u``, within ``limits.jerk_mps3`` and ``limits.accel_mps2`` per axis; ``u_prev`` held
        if Ruckig reports an error."""
        inp, out = self._in, self._out
        inp.current_velocity = list(u_prev)
        inp.current_acceleration = list(self.accel)
        inp.target_velocity = list(u)
        if self._otg.update(inp, out) not in (ruckig.Result.Working, ruckig.Result.Finished):
            self.accel = np.zeros(3)
            return np.asarray(u_prev, dtype=float).copy()
        self.accel = np.asarray(out.new_acceleration, dtype=float)
        return np.asarray(out.new_velocity, dtype=float)


@dataclass
class Attempt:
    """The state of one crawl-release-observe attempt of the final approach.

    Attributes
    ----------
    dir : numpy.ndarray (2,)
        The direction û toward the target, fixed for the attempt.
    phase_t0 : float
        When the current phase of the attempt began, s.
    lead_start : float
        The lead along û when the crawl began, m.
    progress0 : float
        The capsule's position along û when the attempt was aimed, m.
    capped : bool
        Whether the crawl reached its force cap.
    best_remaining : float
        The closest the capsule came to the target along û, m.
    progress_t : float
        When it last came closer by the tolerance, s.
    release_lead : float
        The lead along û the release backs off to, m.
    """

    dir: np.ndarray = field(default_factory=lambda: np.zeros(2))
    phase_t0: float = math.nan
    lead_start: float = 0.0
    progress0: float = 0.0
    capped: bool = False
    best_remaining: float = math.inf
    progress_t: float = math.nan
    release_lead: float = 0.0


class FinalApproach:
    """The final-approach state machine of one run (see the module docstring).

    Parameters
    ----------
    scenario : Scenario
        The controller's scenario (its ``place`` settings, limits and nominal friction).
    path : ReferencePath
        The reference; the target is its last point, the approach may start at its nominal end.
    force : casadi.Function
        The controller's force model ``(lead (2), height) -> (F_x, F_y, F_att)``, N.
    lead_eq_m : numpy.ndarray (2,)
        The model's equilibrium lead (the coupling limit's centre), m.
    dt_s : float
        The controller's frame period, s.
    friction : FrictionBelief, optional
        The controller's friction belief (its breakaway caps the crawl); default: built from
        ``scenario``.
    """

    def __init__(
        self,
        scenario: Scenario,
        path: ReferencePath,
        force: ca.Function,
        lead_eq_m: np.ndarray,
        dt_s: float,
        friction: FrictionBelief | None = None,
    ) -> None:
        self.scenario = scenario
        self.path = path
        friction = FrictionBelief.from_scenario(scenario) if friction is None else friction
        self.model = RigBelief(force, np.asarray(lead_eq_m, dtype=float), friction)
        self.limiter = VelocityLimiter(scenario, dt_s)
        self.speed_mps = scenario.place.approach.speed_mps
        self.frames: deque[tuple[float, np.ndarray]] = deque()
        self.phase = "tracking"
        self.attempts = 0
        self.gave_up_reason = ""
        self._start_s = math.nan
        #: The current attempt's state (direction, phase start, leads, progress).
        self.attempt = Attempt()

    @property
    def enabled(self) -> bool:
        """Whether the approach runs at all (``place.enabled``)."""
        return self.scenario.place.enabled

    @property
    def tolerance_m(self) -> float:
        """Distance to the target within which the capsule counts as arrived (``place.tolerance_m``), m."""
        return self.scenario.place.tolerance_m

    @property
    def target_m(self) -> np.ndarray:
        """The target: the path's last point (2,), m."""
        return np.asarray(self.path.end_m, dtype=float)

    def warm_up(self, height_m: float) -> None:
        """Run once, before the loop, the numerics the approach first reaches at the path's end: the
        line fits (LAPACK's least squares), the zero-force lead (a root find on the force model)
        and the jerk limiter, on made-up frames; the approach's state is left as it was. Their first
        calls are what cost: in ``--realtime`` runs the frame at the path's end took 1.5-32 ms more
        than the solve (the loop sleeps between frames, so that code was cold), every other frame
        under 1 ms more. The frame budget then carries only the steady cost.
        """
        frames = deque((0.1 * i, np.array([1e-3 * i, 0.0])) for i in range(5))
        fit_window(frames, 0.4, 1.0)
        fit_window(frames, 0.4, 1.0, static=True)
        self.zero_force_lead(height_m, np.zeros(2))
        accel = self.limiter.accel.copy()
        self.limiter.limit(np.zeros(3), np.zeros(3))
        self.limiter.accel = accel

    # ------------------------------------------------------------------ state
    @property
    def finished(self) -> bool:
        """Whether the approach has ended (done or given up), or is off: the run may end at rest."""
        return not self.enabled or self.phase in ("done", "gave_up")

    @property
    def in_control(self) -> bool:
        """Whether the approach, not the MPC, commands the EPM: from its first crawl on (after it
        the EPM holds); never if the capsule was within the tolerance when the path ended."""
        return self.enabled and self.attempts > 0

    def observe(self, measurement: Measurement) -> None:
        """Keep the frame (dropped frames carry nothing); frames older than a few windows are forgotten."""
        if measurement.position_m is None:
            return
        self.frames.append((measurement.capture_t_s, np.asarray(measurement.position_m, dtype=float)))
        cfg = self.scenario.place
        horizon = 2.0 * max(cfg.approach.window_s, cfg.approach.observe_s)
        while self.frames and self.frames[0][0] < measurement.capture_t_s - horizon:
            self.frames.popleft()

    # ------------------------------------------------------------------ step
    def step(
        self, t_s: float, epm_position_m: np.ndarray, u_prev: np.ndarray, disturbance_xy_n: np.ndarray
    ) -> np.ndarray | None:
        """This frame's EPM velocity command (3,), m/s, or None while the MPC keeps control.

        Parameters
        ----------
        t_s : float
            Frame time, s.
        epm_position_m : numpy.ndarray (3,)
            EPM position the arm reports (x, y, height), m.
        u_prev : numpy.ndarray (3,)
            The command sent at the previous frame, m/s.
        disturbance_xy_n : numpy.ndarray (2,)
            The controller's estimated constant force on the capsule, N (part of its belief).
        """
        if not self.enabled or t_s < self.path.duration_s:
            return None
        epm = np.asarray(epm_position_m, dtype=float)
        if self.phase == "tracking" and self._trigger(t_s):
            self._start_crawl(t_s, epm)
        if not self.in_control:
            return None
        if self.phase == "crawl":
            along = self._crawl(t_s, epm, np.asarray(disturbance_xy_n, dtype=float))
        elif self.phase == "release":
            along = self._release(t_s, epm)
        else:
            if self.phase == "observe":
                self._observe_step(t_s, epm)
            along = 0.0
        return self.limiter.limit(along * np.array([*self.attempt.dir, 0.0]), np.asarray(u_prev, dtype=float))

    def _trigger(self, t_s: float) -> bool:
        """At the path's end: whether a crawl starts.

        Once the capsule is slower than a crawl (a line fit over ``place.approach.window_s``): within
        the tolerance both by the line fit and by the mean of the frames, ``done`` (the MPC keeps
        the EPM); else a crawl starts toward the target.
        """
        cfg = self.scenario.place
        fit = fit_window(self.frames, t_s, cfg.approach.window_s)
        rest = fit_window(self.frames, t_s, cfg.approach.window_s, static=True)
        if fit is None or rest is None or float(np.linalg.norm(fit.velocity_mps)) >= self.speed_mps:
            return False
        off = max(float(np.linalg.norm(self.target_m - p)) for p in (fit.position_m, rest.position_m))
        if off <= self.tolerance_m:
            self.phase = "done"
            return False
        self._aim(fit.position_m)
        return True

    def _aim(self, position_m: np.ndarray) -> None:
        err = self.target_m - position_m
        self.attempt.dir = err / float(np.linalg.norm(err))
        self.attempt.progress0 = float(position_m @ self.attempt.dir)

    def _start_crawl(self, t_s: float, epm: np.ndarray) -> None:
        self.phase, self.attempt.phase_t0 = "crawl", t_s
        if self.attempts == 0:
            self._start_s = t_s
        self.attempts += 1
        self.attempt.capped = False
        self.attempt.best_remaining = math.inf
        self.attempt.progress_t = t_s
        fit = fit_window(self.frames, t_s, self.scenario.place.approach.window_s)
        capsule = self.target_m - self.attempt.dir if fit is None else fit.position_m
        self.attempt.lead_start = float((epm[:2] - capsule) @ self.attempt.dir)

    def _crawl(self, t_s: float, epm: np.ndarray, disturbance_xy_n: np.ndarray) -> float:
        """EPM speed along û while crawling, m/s."""
        cfg = self.scenario.place
        fit = fit_window(self.frames, t_s, cfg.approach.window_s)
        remaining = math.nan if fit is None else float((self.target_m - fit.position_m) @ self.attempt.dir)
        speed = math.nan if fit is None else float(fit.velocity_mps @ self.attempt.dir)
        if remaining < self.attempt.best_remaining - self.tolerance_m:  # False without frames
            self.attempt.best_remaining, self.attempt.progress_t = remaining, t_s
        progressing = t_s - self.attempt.progress_t < cfg.approach.attempt_s
        if self._out_of_time(t_s) and progressing and remaining > 0:
            # Still creeping on toward the target: letting go would stop it short; hold the lead.
            self.phase = "gave_up"
            self.gave_up_reason = "out of time while the capsule crept on; holding (place.approach.max_s)"
            return 0.0
        if remaining <= max(speed, 0.0) * RELEASE_LEAD_S or not progressing or self._out_of_time(t_s):
            self._start_release(t_s, epm[2], disturbance_xy_n)
            return self._release(t_s, epm)
        if fit is None:  # no frames (drops): hold the lead
            return 0.0
        wanted = float(
            np.clip(remaining / CRAWL_TIME_CONSTANT_S, _MIN_SPEED_FRACTION * self.speed_mps, self.speed_mps)
        )
        along = wanted + (wanted - speed)
        limit = _EPM_SPEED_FACTOR * self.speed_mps
        along = float(np.clip(along, -limit, limit))
        lead = epm[:2] - fit.position_m
        if along > 0 and self._at_cap(t_s, lead, epm[2], disturbance_xy_n):
            self.attempt.capped = True
            along = 0.0
        return along

    def _at_cap(self, t_s: float, lead_m: np.ndarray, height_m: float, disturbance_xy_n: np.ndarray) -> bool:
        """Whether more lead along û would pass the model's force cap or the coupling limit."""
        scenario = self.scenario
        ahead = lead_m + self.attempt.dir * self.limiter.dt_s * _EPM_SPEED_FACTOR * self.speed_mps
        if float(np.linalg.norm(ahead - self.model.lead_eq_m)) > scenario.limits.max_lead_m:
            return True
        f = np.asarray(self.model.force(ahead, height_m)).ravel()
        normal_n = float(normal_force_expr(scenario, float(f[2])))
        # At rest since the crawl last moved it (or since it began), and slow over the window before.
        rest_s = t_s - self.attempt.progress_t + scenario.place.approach.window_s
        breakaway_n = self.model.friction.breakaway_n(normal_n, rest_s, self.path.length_m)
        along_n = float((f[:2] + disturbance_xy_n) @ self.attempt.dir)
        return along_n > scenario.place.approach.force_fraction * breakaway_n

    def _start_release(self, t_s: float, height_m: float, disturbance_xy_n: np.ndarray) -> None:
        """Enter the release: its target lead along û (see the module docstring)."""
        self.phase, self.attempt.phase_t0 = "release", t_s
        zero = self.zero_force_lead(height_m, disturbance_xy_n)
        backoff = self.attempt.lead_start - self.scenario.place.approach.backoff_m
        self.attempt.release_lead = min(backoff, float(zero @ self.attempt.dir))

    def zero_force_lead(self, height_m: float, disturbance_xy_n: np.ndarray) -> np.ndarray:
        """The lead (2,), m, at which the controller believes the lateral force vanishes: its force
        model plus the estimated constant disturbance (:func:`~capsule_mpc.magnetics.equilibrium_lead`
        from the model's equilibrium lead); the model's equilibrium lead if no root is found within
        the coupling limit."""
        d = np.asarray(disturbance_xy_n, dtype=float)
        try:
            lead = equilibrium_lead(
                lambda x: np.asarray(self.model.force(x, height_m)).ravel()[:2] + d,
                guess_m=tuple(self.model.lead_eq_m),
            )
        except RuntimeError:
            return self.model.lead_eq_m.copy()
        near = float(np.linalg.norm(lead - self.model.lead_eq_m)) <= self.scenario.limits.max_lead_m
        return lead if near and bool(np.all(np.isfinite(lead))) else self.model.lead_eq_m.copy()

    def _release(self, t_s: float, epm: np.ndarray) -> float:
        """EPM speed along û while backing off, m/s (<= 0)."""
        cfg = self.scenario.place
        fit = fit_window(self.frames, t_s, cfg.approach.window_s)
        capsule = fit.position_m if fit is not None else self.target_m
        excess = float((epm[:2] - capsule) @ self.attempt.dir) - self.attempt.release_lead
        if excess <= _RELEASE_TOL_M:
            self.phase, self.attempt.phase_t0 = "observe", t_s
            return 0.0
        limit = _EPM_SPEED_FACTOR * self.speed_mps
        return -min(excess / (4.0 * self.limiter.dt_s), limit)

    def _observe_step(self, t_s: float, epm: np.ndarray) -> None:
        cfg = self.scenario.place
        if t_s - self.attempt.phase_t0 < cfg.approach.observe_s:
            return
        fit = fit_window(self.frames, t_s, cfg.approach.observe_s - OBSERVE_SETTLE_S, static=True)
        if fit is None:  # every frame dropped: keep watching while there is time
            if self._out_of_time(t_s):
                self.phase = "gave_up"
                self.gave_up_reason = "out of time, no camera frames (place.approach.max_s)"
            return
        err = self.target_m - fit.position_m
        if float(np.linalg.norm(err)) <= self.tolerance_m:
            self.phase = "done"
            return
        if self._out_of_time(t_s):
            self.phase = "gave_up"
            self.gave_up_reason = f"out of time after {t_s - self._start_s:.1f} s (place.approach.max_s)"
            return
        progress = float(fit.position_m @ self.attempt.dir) - self.attempt.progress0
        if progress < self.tolerance_m:
            self.phase = "gave_up"
            cap = " (it reached the force cap)" if self.attempt.capped else ""
            self.gave_up_reason = f"stuck: the crawl did not move the capsule{cap}"
            return
        if self.attempts >= cfg.approach.max_attempts:
            self.phase = "gave_up"
            self.gave_up_reason = f"{self.attempts} attempts (place.approach.max_attempts)"
            return
        if float(err @ self.attempt.dir) < 0:  # passed the target: crawl slower next time
            self.speed_mps *= 0.5
        self._aim(fit.position_m)
        self._start_crawl(t_s, epm)

    def _out_of_time(self, t_s: float) -> bool:
        """Whether the approach has used its time (``place.approach.max_s`` from its first crawl)."""
        return t_s - self._start_s >= self.scenario.place.approach.max_s
