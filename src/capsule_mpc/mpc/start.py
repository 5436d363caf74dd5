"""The start from rest: pre-load the capsule up to its believed breakaway at once.

A capsule that has rested is held by healed static friction until the lateral force passes its
breakaway force, and from t = 0 the reference moves on without it. The MPC's own ramp of the EPM
is set by its acceleration and jerk weights and by its smooth friction law, which says a small
force moves the capsule, so the capsule sits stuck for a few tenths of a second while the lead
builds up, then lurches. What an operator does instead: pull the magnet ahead briskly until the
capsule is about to go.

With ``break_loose.preload`` (a fraction of the believed breakaway), from the first frame of
motion the EPM is driven time-optimally within ``limits.speed_mps``, ``limits.accel_mps2`` and
``limits.jerk_mps3`` (Ruckig, position interface) along the path's initial direction û to the
lead at which the controller's force model plus its estimated constant disturbance, along û,
reaches that fraction of the friction belief's breakaway force after the rest so far
(:meth:`capsule_mpc.friction.FrictionBelief.breakaway_n`). It arrives there still speeding up:
at ``break_loose.arrival`` times the fastest speed the limits reach from rest over that
distance (:func:`fastest_arrival_mps`), but no faster than it can stop before the coupling limit,
and never below the path's speed. Arriving at the path's speed
instead would spend the last tenth of a second slowing down while the capsule, still stuck, falls
behind the reference; arriving fast, the EPM overshoots the lead once the capsule breaks loose,
and the larger force makes the capsule catch up with the reference it lost while it was stuck.
A capsule held off the path's first line (the coupling's dead zone is widest across its soft
axis) would slide on beside it while the MPC's lateral pull builds up; so the EPM's target also
moves across û, to the far side of the line, by ``break_loose.toward_path`` times the capsule's
offset from it, and the capsule that breaks loose is drawn onto the path at once (Ruckig stops
that axis there).
The phase ends there (pre-loaded), or earlier when the camera sees the capsule leave its rest
position (:class:`~capsule_mpc.mpc.contact.RestDetector`), when the lead would leave the coupling
limit (``limits.max_lead_m`` around the model's equilibrium lead), or after :data:`PRELOAD_MAX_S`;
the MPC, which has solved every frame meanwhile, then takes over. The target lead is fixed at the
phase's start and Ruckig runs open loop on its own state: the EPM's motion is one jerk-limited
profile. The arm's servos lag their setpoints by about ``1 / (2 pi arm.servo_bandwidth_hz)``, the
lag the MPC predicts too, so the phase commands the profile's velocity that far ahead, passed
through the limits the controller's safety layer applies to every command (from rest the lead is
a step they do not allow): the EPM then follows the profile instead of trailing it, and the capsule
breaks loose sooner. A breakaway the belief puts too low stops the pre-load short, one it puts
too high makes the capsule break loose during the pre-load and lurch further: the phase is as
good as the believed breakaway.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import ruckig
from scipy.optimize import brentq

from ..config import Scenario
from ..dynamics import normal_force_expr
from ..friction import FrictionBelief
from ..interfaces import servo_time_constant_s
from ..paths import ReferencePath
from ..safety import SafetyFilter
from .belief import RigBelief
from .contact import RestDetector

__all__ = ["PRELOAD_MAX_S", "StartPreload", "epm_ruckig", "fastest_arrival_mps"]

#: Longest pre-load from t = 0, s: the MPC takes over then whatever the capsule does.
PRELOAD_MAX_S = 1.5


def fastest_arrival_mps(distance_m: float, jerk_mps3: float, accel_mps2: float, speed_mps: float) -> float:
    """The highest speed an axis can have, with zero acceleration, after ``distance_m`` from rest
    within the jerk, acceleration and speed limits, m/s (a higher target speed needs a run-up).

    The fastest way to a speed v from rest is a jerk-limited S-curve: the acceleration ramps up
    and back down at the jerk limit (a triangle while v <= a²/j, a trapezoid capped at the
    acceleration limit a above that); it covers v * sqrt(v / j), resp. v (v / a + a / j) / 2, and
    this inverts that closed form. Written out because Ruckig plans a given target state but does
    not give the fastest reachable one; the tests check it against Ruckig's own profiles.
    """
    d = max(float(distance_m), 0.0)
    j, a = float(jerk_mps3), float(accel_mps2)
    if d <= a**3 / j**2:  # the acceleration never reaches its limit: d = v^(3/2) / sqrt(j)
        v = (d * d * j) ** (1.0 / 3.0)
    else:  # d = v^2 / (2a) + v a / (2j)
        half = a / (2.0 * j)
        v = a * (math.sqrt(half * half + 2.0 * d / a) - half)
    return min(v, float(speed_mps))


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


class StartPreload:
    """The start's pre-load phase of one run (see the module docstring).

    Parameters
    ----------
    scenario : Scenario
        The controller's scenario (``break_loose.preload``, the limits).
    path : ReferencePath
        The reference; û is its direction at the start, the speed its nominal speed.
    force : casadi.Function
        The controller's force model ``(lead (2), height) -> (F_x, F_y, F_att)``, N.
    lead_eq_m : numpy.ndarray (2,)
        The model's equilibrium lead (the coupling limit's centre), m.
    belief : FrictionBelief
        The controller's friction belief (its breakaway).
    rest : RestDetector
        Tells whether the capsule rests and since when (updated by the caller every frame).
    dt_s : float
        The controller's frame period, s.
    """

    def __init__(
        self,
        scenario: Scenario,
        path: ReferencePath,
        force: ca.Function,
        lead_eq_m: np.ndarray,
        belief: FrictionBelief,
        rest: RestDetector,
        dt_s: float,
    ) -> None:
        self.scenario = scenario
        self.model = RigBelief(force, np.asarray(lead_eq_m, dtype=float), belief)
        self.rest = rest
        self.path = path
        speed = self.speed_mps
        self.active = self.fraction is not None and speed > 0
        self.target_lead_m: np.ndarray | None = None
        self.arrival_mps = speed
        self.end_reason = ""
        self._otg = epm_ruckig(scenario, dt_s)
        self._limit = SafetyFilter(scenario, dt_s)
        self._state: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.target_epm_m: np.ndarray | None = None  # the EPM's target position (3,), m

    @property
    def start_m(self) -> np.ndarray:
        """The path's first point (2,), m."""
        return np.asarray(self.path.start_m, dtype=float)[:2]

    @property
    def velocity_mps(self) -> np.ndarray:
        """The path's velocity at its start (2,), m/s."""
        return np.asarray(self.path.velocity(np.array([0.0]))[0], dtype=float)

    @property
    def lead_s(self) -> float:
        """How far ahead of its profile the phase commands, s: the arm's servo lag as the MPC
        predicts it (0 without a servo bandwidth)."""
        return servo_time_constant_s(self.scenario.arm.servo_bandwidth_hz) or 0.0

    @property
    def speed_mps(self) -> float:
        """The path's speed at its start, m/s."""
        return float(np.linalg.norm(self.velocity_mps))

    @property
    def direction(self) -> np.ndarray:
        """û, the path's direction at its start (2,); zeros for a path at rest."""
        speed = self.speed_mps
        return self.velocity_mps / speed if speed > 0 else np.zeros(2)

    @property
    def fraction(self) -> float | None:
        """The pre-load's fraction of the believed breakaway (``break_loose.preload``; None: off)."""
        return self.scenario.break_loose.preload

    def _along(self, lead: np.ndarray, height_m: float, disturbance_xy_n: np.ndarray) -> tuple[float, float]:
        """The believed lateral force along û at ``lead`` (N) and the normal force there (N)."""
        f = np.asarray(self.model.force(lead, height_m)).ravel()
        return float((f[0:2] + disturbance_xy_n) @ self.direction), float(
            normal_force_expr(self.scenario, f[2])
        )

    def target_lead(
        self, rest_lead_m: np.ndarray, height_m: float, rest_s: float, disturbance_xy_n: np.ndarray
    ) -> np.ndarray:
        """The lead (2,), m, along û from ``rest_lead_m`` at which the believed force along û is the
        pre-load fraction of the believed breakaway after ``rest_s``; the farthest lead within the
        coupling limit if the force does not get there."""
        d = np.asarray(disturbance_xy_n, dtype=float)
        fraction = float(self.fraction or 0.0)
        offset = float(np.linalg.norm(rest_lead_m - self.model.lead_eq_m))
        reach = max(self.scenario.limits.max_lead_m - offset, 0.0)

        def excess(s: float) -> float:
            along, normal = self._along(rest_lead_m + s * self.direction, height_m, d)
            return along - fraction * self.model.friction.breakaway_n(normal, rest_s)

        if excess(0.0) >= 0.0:
            return np.asarray(rest_lead_m, dtype=float).copy()
        if excess(reach) <= 0.0:
            return rest_lead_m + reach * self.direction
        return rest_lead_m + brentq(excess, 0.0, reach, xtol=1e-6) * self.direction

    def _fastest_along(self, distance_m: float) -> float:
        """The fastest speed along û an EPM reaches from rest over ``distance_m`` (each axis over
        its share, :func:`fastest_arrival_mps`), m/s; the same bounds the speed from which it can
        stop within that distance."""
        lim = self.scenario.limits
        fastest = math.inf
        for component in np.abs(self.direction):
            if component > 1e-9:  # axis i moves component * distance and must reach component * v
                way = component * distance_m
                reach = fastest_arrival_mps(way, lim.jerk_mps3, lim.accel_mps2, lim.speed_mps)
                fastest = min(fastest, reach / component)
        return fastest

    def arrival_speed(self, rest_lead_m: np.ndarray, target_lead_m: np.ndarray) -> float:
        """The speed along û at the pre-load lead, m/s, for an EPM at rest at ``rest_lead_m`` (2,):
        ``break_loose.arrival`` of the fastest it can reach over the way to
        ``target_lead_m``, and no faster than it can stop from before the coupling limit
        (``limits.max_lead_m`` around the model's equilibrium lead); never below the path's
        speed."""
        fraction = float(self.scenario.break_loose.arrival)
        way = float(np.linalg.norm(target_lead_m - rest_lead_m))
        # Distance along û from the target lead to the coupling limit's circle.
        offset = np.asarray(target_lead_m, dtype=float) - self.model.lead_eq_m
        b = float(offset @ self.direction)
        room = -b + math.sqrt(max(b * b - float(offset @ offset) + self.scenario.limits.max_lead_m**2, 0.0))
        speed = min(fraction * self._fastest_along(way), self._fastest_along(max(room, 0.0)))
        return max(self.speed_mps, speed) if math.isfinite(speed) else self.speed_mps

    def command(
        self,
        t_s: float,
        epm_m: np.ndarray,
        u_prev: np.ndarray,
        disturbance_xy_n: np.ndarray,
    ) -> np.ndarray | None:
        """This frame's EPM velocity command (3,), m/s, or None once the phase is over (or off)."""
        if not self.active:
            return None
        over = self._over(t_s, epm_m)
        if over:
            self.active, self.end_reason = False, over
            return None
        rest_pos = self.rest.rest_position_m
        assert rest_pos is not None  # _over: it rests
        if self.target_lead_m is None:  # fixed at the phase's start: the EPM's target stays put
            self.target_lead_m = self.target_lead(
                epm_m[0:2] - rest_pos, float(epm_m[2]), self.rest.rest_s(t_s), disturbance_xy_n
            )
            normal = np.array([-self.direction[1], self.direction[0]])
            beside = float((rest_pos - self.start_m) @ normal)  # the rest's offset from the first line
            across = -self.scenario.break_loose.toward_path * beside * normal
            self.target_epm_m = np.append(rest_pos + self.target_lead_m + across, float(epm_m[2]))
        assert self.target_epm_m is not None
        if self._state is None:
            self.arrival_mps = self.arrival_speed(epm_m[0:2] - rest_pos, self.target_lead_m)
        cruise = np.append(self.arrival_mps * self.direction, 0.0)
        # Ruckig runs open loop on its own state from the phase's first frame (the measured EPM,
        # the command being applied): fed back its own output, every command it gives lies on one
        # jerk-limited profile; the arm's lag does not restart it.
        if self._state is None:
            self._state = (np.asarray(epm_m, dtype=float), np.asarray(u_prev, dtype=float), np.zeros(3))
        otg, inp, out = self._otg
        inp.current_position, inp.current_velocity, inp.current_acceleration = (list(x) for x in self._state)
        inp.target_position = list(self.target_epm_m)
        inp.target_velocity = list(cruise)
        inp.target_acceleration = [0.0, 0.0, 0.0]
        result = otg.update(inp, out)
        if result == ruckig.Result.Finished:  # pre-loaded: the MPC goes on from here
            self.active, self.end_reason = False, "pre-loaded"
        elif result != ruckig.Result.Working:
            self.active, self.end_reason = False, "no jerk-limited profile to the pre-load lead"
            return None
        self._state = tuple(
            np.asarray(x, dtype=float) for x in (out.new_position, out.new_velocity, out.new_acceleration)
        )  # type: ignore[assignment]
        # The profile's velocity a servo lag ahead, within the limits (see the module docstring).
        _, ahead, _ = out.trajectory.at_time(out.time + self.lead_s)
        u, _ = self._limit.apply(np.asarray(ahead, dtype=float), epm_m)
        return u

    def _over(self, t_s: float, epm_m: np.ndarray) -> str:
        """Why the phase ends at this frame ('' if it goes on)."""
        if t_s >= PRELOAD_MAX_S:
            return f"no breakaway within {PRELOAD_MAX_S} s"
        if not self.rest.resting:
            return "broke loose"
        rest_pos = self.rest.rest_position_m
        assert rest_pos is not None
        lead = epm_m[0:2] - rest_pos
        if float(np.linalg.norm(lead - self.model.lead_eq_m)) > self.scenario.limits.max_lead_m:
            return "coupling limit"
        return ""
