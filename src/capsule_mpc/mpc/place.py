"""Placement: bring a capsule that rests off its target onto it, where static friction decides.

A capsule held by static friction cannot be nudged: once the magnetic force passes its healed
static friction it lurches ``2 (F_static - F_sliding) / k`` (millimetres; ``k`` the coupling's
stiffness) and below that it does not move. What the plant does reliably is *stop*: a capsule that
slides behind the EPM along the coupling's stiff axis and is left by an EPM that stops comes to
rest at a lead from the EPM's final position that does not depend on where it started, the more
so the slower it came (``benchmarks/placement_stop.py`` measures it; across the axis a part of the
lateral offset it started with remains, less after a longer run-up). So a placement arrives
sliding, as an operator does with a sticky slide:

* **move**: along the stiff axis ``d`` (fixed for the whole placement, its sign toward the target
  from where the capsule first rested), the EPM backs off far enough to break the capsule loose
  backward and stage it behind the target, then comes forward and stops where the belief says
  the capsule will come to rest on the target: ``e_f = target + lead_eq + s``. When the target
  lies ahead by more than the breakaway, the back-off is skipped;
* **settle, observe**: the EPM holds; after the capsule has stopped, the camera's frames are
  averaged until their standard error is small (or a time cap); the capsule must not have moved
  between the first and second half of the frames;
* **release**: a capsule found within tolerance at its first rest, before any move, is still
  pulled by the lead that dragged it along the path's last leg, and under that pull it may creep
  on for seconds (rate-and-state creep) after the camera saw it stop; so the EPM first moves to
  the believed zero-force lead over it (``rest + lead_eq``) and the camera watches it again (a
  capsule that did not move is judged on both rests' frames, :data:`RELEASE_MOVED_SE`);
* **correct**: within ``place.tolerance_m`` of the target it is placed; else the stop offset
  ``s`` is replaced by the one just observed (``e_f - lead_eq - rest``, what the rig did: slope 1
  in ``e_f``), and the next move starts, up to ``place.max_moves``.

The belief sizes the back-off: the EPM must pull the lead beyond the breakaway of the *static*
friction, :meth:`~capsule_mpc.friction.FrictionBelief.breakaway_n` (after the rest so far, by
:data:`BREAKAWAY_MARGIN`), both to break loose backward and, after a short stop, forward; too short
a back-off leaves the capsule where it was, and the next move backs off :data:`GROWTH` times
farther.

Where the capsule comes to rest is read from the slide. While it slid along the path's legs the
camera saw the lead that dragged it, per axis and direction (:class:`SlideLeads`): that lead holds
the rig's coupling and sliding friction together, which the force model and the friction belief
each know only nominally. Once the EPM has stepped back, the capsule comes to rest where the force
along the approach has fallen to a part :data:`STOP_FROM_SLIDE` of the force at the leg's lead in
the same direction, and across the approach at the lead that leg held. Without such a leg (a path
that never slid along the stiff axis that way at about :data:`LEG_SPEED_MPS`) the belief alone
gives the stop: where the force has fallen to the tether drag it holds plus a part
:data:`STOP_FRICTION` of its static friction just after coming to rest. Both parts were fitted on
the first moves of closed-loop runs of tuning draws (``benchmarks/stop_friction.py``, which
reports the scatter each law leaves). The believed equilibrium ``lead_eq`` is where
the force model plus the controller's estimated constant force vanishes. Nothing of the plant is
read: only camera frames (through the estimator) and the EPM position the arm reports.

Each move is one jerk-limited Ruckig trajectory per segment, within ``limits.speed_mps``,
``limits.accel_mps2`` and ``limits.jerk_mps3``; the commands follow it, with a proportional
correction of the EPM's position error at ``place.track_gain_per_s``, and pass the controller's
safety layer. With the camera at 100 Hz that correction, fed back through the arm's lag and the
jerk-limited command stream, made the EPM ring millimetres about a move's end, so the 100 Hz
scenario follows the trajectory's velocities alone and corrects only once it is over.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np
import ruckig
from scipy.optimize import brentq, root

from ..config import PlaceConfig, Scenario
from ..dynamics import normal_force_expr
from ..friction import FrictionBelief
from ..interfaces import StepOutcome, StepStats
from .phases import Event, FrameContext, PhaseOutput
from .slide import SlideProducer

__all__ = [
    "BREAKAWAY_MARGIN",
    "GROWTH",
    "STOP_FROM_SLIDE",
    "Move",
    "PlaceGeometry",
    "PlaceOutcome",
    "Placement",
    "PlacementProducer",
    "SlideLeads",
    "place_geometry",
    "plan_move",
]

#: The back-off pulls the lead this far beyond the belief's breakaway force (a ratio): wide enough
#: to clear the learned breakaway's error against the plant's (docs/results.md, "The learned
#: breakaway against the plant's").
BREAKAWAY_MARGIN = 1.25
#: Scatter of one stop's rest position along the approach, m (the camera's averaged noise and the
#: plate's variation; measured by benchmarks/placement_stop.py, docs/results/placement_stop_lab.json).
STOP_SCATTER_M = 1e-4
#: Prior scale of the tether drag's growth the belief may miss, N/m (the drag grows with the
#: tether paid out; rigs drawn here grow by up to 0.15 N/m).
DRIFT_PRIOR_N_PER_M = 0.1
#: A move broke the capsule loose if a camera frame saw it this far from its rest, m (a move
#: slides it tens of millimetres; the camera's noise is a fraction of one).
BROKE_LOOSE_M = 3e-3
#: Weight of the newest stop in the learned stop offset (1: the last stop alone; the mean of all
#: stops is 1/n).
ADAPT_GAIN = 0.7
#: A move that left the capsule where it was backs off this many times farther next time.
GROWTH = 1.5
#: Run-up beyond the breakaway distance, m: the capsule slides at least this far before it is
#: brought to rest on the target. Sliding along the stiff axis relaxes its lateral offset from the
#: EPM; the longer the run-up, the less of it is left where the capsule stops
#: (benchmarks/placement_stop.py compares run-ups), but each millimetre is travelled twice per move
#: (docs/friction.md, placement, gives what run-ups of 8, 12 and 16 mm did in closed loop). A move
#: whose EPM follows its trajectory's velocities alone (``place.track_gain_per_s: 0``) runs tens of
#: milliseconds behind it; after a short run-up the stops of such moves scattered by millimetres,
#: so they keep :data:`LAGGING_RUN_UP_M`.
RUN_UP_M = 12e-3
LAGGING_RUN_UP_M = 16e-3
#: After the EPM's last move the capsule is left this long to stop before frames count, s.
SETTLE_S = 0.3
#: An observation ends once the mean's standard error is below this fraction of the tolerance.
SE_FRACTION = 0.3
#: Before the first move, a rest this many standard errors beyond the tolerance is off the target.
OFF_SE = 3.0
#: An observation whose mean lies within this many standard errors of the tolerance is ambiguous
#: and goes on past :data:`MAX_OBSERVE_S`, up to :data:`LONGEST_OBSERVE_S`, s.
AMBIGUOUS_SE = 2.0
LONGEST_OBSERVE_S = 3.0
#: The fewest frames an observation averages, and the longest it lasts unless ambiguous, s.
MIN_FRAMES = 8
MAX_OBSERVE_S = 1.5
#: Gain of the EPM's position correction onto a move's end once its trajectory is over, 1/s.
POSITION_GAIN = 4.0
#: The EPM has reached a move's end when it is this close, m, or this long after the
#: trajectory's end, s (the stop offset is learned from where it really stopped).
EPM_TOL_M = 5e-5
EPM_WAIT_S = 0.3
#: The last part of the approach runs at ``place.approach_speed_mps``, m: the slower the capsule
#: arrives, the better its rest repeats (benchmarks/placement_stop.py compares approach speeds).
SLOW_M = 4e-3
#: Speed cap of the run-up before the slow part, m/s: a faster run-up throws the capsule about more
#: (benchmarks/placement_stop.py).
RUN_UP_MPS = 0.04
#: At the end of a move the EPM steps back this far along the approach, m: the force drops below
#: the sliding friction and the capsule stops at once instead of creeping on for seconds under
#: the force it was dragged with (rate-and-state creep, a > b); a shorter step back left it
#: creeping on some draws.
RELEASE_M = 2e-3
#: A release (the module docstring) shorter than this is skipped, m.
RELEASE_MIN_M = 5e-4
#: The rest watched again after a release counts together with the first (their means weighted by
#: their standard errors) unless the means differ by more than this many standard errors of their
#: difference (then the capsule moved, and the new rest decides alone).
RELEASE_MOVED_SE = 3.0
#: Rest assumed for the forward breakaway after the short stop at the back-off, s.
STAGE_REST_S = 0.3
#: The placement starts once the estimator has seen the capsule at rest this long after the path,
#: s (the MPC holds the path's end meanwhile).
REST_BEFORE_S = 0.3
#: Without a leg of the slide along the approach: the fraction of the belief's static friction
#: (just after coming to rest) that still holds the capsule where it comes to rest after the
#: release; the force along the approach there is the drag plus ``STOP_FRICTION mu_s F_N``. Fitted
#: on the first moves of closed-loop runs on tuning draws by ``benchmarks/stop_friction.py``
#: (docs/results/stop_friction_lab.json).
STOP_FRICTION = 0.283
#: Where the path gave the camera a leg along the approach, the capsule comes to rest where the force
#: along the approach is this part of the force that dragged it along that leg (both in the force
#: model, at the lead the camera saw): the slide measures the rig's coupling and friction together,
#: which no belief of the friction alone does. Fitted on the first moves of closed-loop runs on tuning
#: draws by ``benchmarks/stop_friction.py`` (docs/results/stop_friction_lab.json).
STOP_FROM_SLIDE = 0.621
#: A leg counts once the capsule has slid this long in one direction along the axis, s (its lateral
#: offset has relaxed), and up to this long before it stops doing so (the MPC turns before a
#: corner); its frames are averaged if there are at least :data:`LEG_MIN_FRAMES`.
LEG_SETTLED_S = 1.5
LEG_TRIM_S = 0.8
LEG_MIN_FRAMES = 15
#: The capsule slides along an axis when its speed along it, over the last :data:`LEG_WINDOW_S`,
#: is within this band of ``LEG_SPEED_MPS`` (the speed :data:`STOP_FROM_SLIDE` was fitted at; the
#: sliding friction depends on the speed) and the speed across is below :data:`LEG_ACROSS`
#: of it.
LEG_SPEED_MPS = 0.02
LEG_SPEED_BAND = (0.5, 1.5)
LEG_ACROSS = 0.25
LEG_WINDOW_S = 0.5
#: Step of the force's finite differences, m.
_FD_STEP_M = 1e-4
#: The believed equilibrium is trusted this far from the model's own, m (beyond: a root finder
#: that wandered off the force map, where the force is flat).
_MAX_SHIFT_M = 0.01


class PlaceOutcome(enum.Enum):
    """How a placement stands."""

    ACTIVE = "active"
    PLACED = "placed"
    GAVE_UP = "gave_up"


@dataclass(frozen=True)
class PlaceGeometry:
    """What the belief says about the coupling near the target.

    Attributes
    ----------
    lead_eq_m : numpy.ndarray (2,)
        Lead ``e - p`` at which the believed lateral force vanishes, m.
    axis : numpy.ndarray (2,)
        Unit vector of the coupling's stiff axis.
    along_n : Callable[[float], float]
        Believed force along ``axis`` at the lead ``lead_eq + x axis`` (x in m), N.
    normal_n : float
        Believed normal force at ``lead_eq``, N.
    legs_m : Mapping[float, numpy.ndarray (2,)]
        What the slide showed of the coupling: the mean lead the camera saw while the capsule slid
        along ``direction * axis`` at about :data:`LEG_SPEED_MPS`, per direction (+1, -1) it did,
        m (:class:`SlideLeads`).
    """

    lead_eq_m: np.ndarray
    axis: np.ndarray
    along_n: Callable[[float], float]
    normal_n: float
    legs_m: Mapping[float, np.ndarray] = field(default_factory=dict)

    @property
    def stiffness_n_per_m(self) -> float:
        """The believed coupling stiffness along the axis at ``lead_eq``, N/m."""
        return abs(self.along_n(_FD_STEP_M) - self.along_n(-_FD_STEP_M)) / (2 * _FD_STEP_M)

    def offset_for(self, force_n: float, direction: float, limit_m: float) -> float:
        """Distance ``x >= 0`` (m) along ``direction * axis`` at which the believed force along it
        reaches ``force_n``; ``limit_m`` when it does not within that."""

        def excess(x: float) -> float:
            return direction * self.along_n(direction * x) - force_n

        if excess(0.0) >= 0:  # reached at the equilibrium already (a belief without friction)
            return 0.0
        if excess(limit_m) < 0:
            return limit_m
        return float(brentq(excess, 0.0, limit_m, xtol=1e-7))

    def leg_pull(self, direction: float) -> tuple[float, np.ndarray] | None:
        """What the slide's leg along ``direction * axis`` showed: the believed force along it at
        the leg's lead (N; > 0 when the leg dragged the capsule that way) and the leg's offset from
        ``lead_eq`` across the axis (2,), m; None without such a leg."""
        leg = self.legs_m.get(direction)
        if leg is None:
            return None
        offset = np.asarray(leg, dtype=float) - self.lead_eq_m
        along = float(offset @ self.axis)
        return direction * self.along_n(along), offset - along * self.axis


def place_geometry(
    force: Callable[[np.ndarray, float], np.ndarray],
    lead_guess_m: np.ndarray,
    height_m: float,
    disturbance_xy_n: np.ndarray,
    normal: Callable[[float], float],
) -> PlaceGeometry:
    """The belief's :class:`PlaceGeometry` from its force model ``force(lead, height) -> (F_x, F_y,
    F_att)`` (N), its constant force estimate and ``normal(F_att) -> F_N``."""

    def lateral(lead: np.ndarray) -> np.ndarray:
        return np.asarray(force(lead, height_m), dtype=float).ravel()[:2] + disturbance_xy_n

    def jacobian(lead: np.ndarray) -> np.ndarray:
        # Central differences over a tenth of a millimetre: the force map's spline is flat to
        # round-off at the steps a default finite-difference root finder takes.
        return np.column_stack(
            [
                (lateral(lead + _FD_STEP_M * e) - lateral(lead - _FD_STEP_M * e)) / (2 * _FD_STEP_M)
                for e in np.eye(2)
            ]
        )

    guess = np.asarray(lead_guess_m, dtype=float)
    sol = root(lateral, guess, jac=jacobian)
    lead_eq = sol.x if sol.success and float(np.linalg.norm(sol.x - guess)) < _MAX_SHIFT_M else guess
    axis = np.eye(2)[int(np.argmax(np.abs(np.diag(jacobian(lead_eq)))))]
    f_att = float(np.asarray(force(lead_eq, height_m)).ravel()[2])
    return PlaceGeometry(
        lead_eq_m=lead_eq,
        axis=axis,
        along_n=lambda x: float(lateral(lead_eq + x * axis) @ axis),
        normal_n=normal(f_att),
    )


class SlideLeads:
    """The leads (EPM minus capsule, the estimator's position at the frame's time) the camera saw
    while the capsule slid steadily along an axis of the plate, per axis and direction.

    A run starts when the capsule's mean velocity over the last :data:`LEG_WINDOW_S` points along
    one axis and direction (within :data:`LEG_ACROSS`) at a speed within :data:`LEG_SPEED_BAND` of
    :data:`LEG_SPEED_MPS`, and goes on while it keeps moving that way faster than across and than
    half the band's lower end (a stick-slipping capsule's speed swings about the path's). When it
    ends, its frames from :data:`LEG_SETTLED_S` after its start to :data:`LEG_TRIM_S` before its
    end count, if their mean speed is within the band.
    """

    def __init__(self) -> None:
        self._sums: dict[tuple[int, float], np.ndarray] = {}
        self._counts: dict[tuple[int, float], int] = {}
        self._recent: deque[tuple[float, np.ndarray]] = deque()
        self._key: tuple[int, float] | None = None
        self._run: list[tuple[float, np.ndarray, np.ndarray]] = []  # (t, position, lead)

    @staticmethod
    def _in_band(speed_mps: float) -> bool:
        lo, hi = LEG_SPEED_BAND
        return lo * LEG_SPEED_MPS <= speed_mps <= hi * LEG_SPEED_MPS

    def _direction(self, v: np.ndarray) -> tuple[int, float] | None:
        """The run this windowed velocity (2,) continues or starts, or None."""
        if self._key is not None:
            i, sign = self._key
            along = sign * float(v[i])
            if along >= 0.5 * LEG_SPEED_BAND[0] * LEG_SPEED_MPS and abs(float(v[1 - i])) <= along:
                return self._key
        i = int(np.argmax(np.abs(v)))
        speed = abs(float(v[i]))
        if self._in_band(speed) and abs(float(v[1 - i])) <= LEG_ACROSS * speed:
            return (i, 1.0 if v[i] > 0 else -1.0)
        return None

    def add(self, t_s: float, position_m: np.ndarray, epm_m: np.ndarray) -> None:
        """One frame: the estimated capsule position and the EPM's (m)."""
        pos = np.asarray(position_m, dtype=float)[:2]
        self._recent.append((t_s, pos))
        while self._recent[0][0] < t_s - LEG_WINDOW_S:
            self._recent.popleft()
        t0, p0 = self._recent[0]
        key = self._direction((pos - p0) / (t_s - t0)) if t_s - t0 >= 0.8 * LEG_WINDOW_S else None
        if key != self._key:
            self.close()
            self._key = key
        if key is not None:
            self._run.append((t_s, pos, np.asarray(epm_m, dtype=float)[:2] - pos))

    def close(self) -> None:
        """End the current run: its settled frames count if their mean speed is within the band."""
        if self._key is not None and self._run:
            start, end = self._run[0][0], self._run[-1][0]
            kept = [
                (t, p, lead) for t, p, lead in self._run if start + LEG_SETTLED_S <= t <= end - LEG_TRIM_S
            ]
            if len(kept) >= 2:
                i, sign = self._key
                speed = sign * float(kept[-1][1][i] - kept[0][1][i]) / (kept[-1][0] - kept[0][0])
                if self._in_band(speed):
                    leads = np.sum([lead for _, _, lead in kept], axis=0)
                    self._sums[self._key] = self._sums.get(self._key, np.zeros(2)) + leads
                    self._counts[self._key] = self._counts.get(self._key, 0) + len(kept)
        self._key, self._run = None, []

    def lead(self, axis_index: int, direction: float) -> np.ndarray | None:
        """The mean lead (2,) over the runs along ``direction`` (+-1) times the unit vector of axis
        ``axis_index`` (0: x, 1: y), m; None with fewer than :data:`LEG_MIN_FRAMES` frames."""
        key = (axis_index, float(direction))
        n = self._counts.get(key, 0)
        return self._sums[key] / n if n >= LEG_MIN_FRAMES else None


@dataclass(frozen=True)
class Move:
    """One placement move.

    Attributes
    ----------
    waypoints_m : tuple of numpy.ndarray (3,)
        The EPM's waypoints (x, y, height), m, one Ruckig segment each.
    arrivals_mps : tuple of numpy.ndarray (3,)
        The EPM's velocity at each waypoint, m/s (0 but where the approach slows down).
    speeds_mps : tuple of float
        Each segment's speed cap, m/s (within ``limits.speed_mps``).
    final_m : numpy.ndarray (3,)
        Where the EPM stops for the capsule to come to rest on the target, m.
    model_offset_m : numpy.ndarray (2,)
        The belief's stop offset (the lead beyond ``lead_eq`` at which the capsule stops), m.
    """

    waypoints_m: tuple[np.ndarray, ...]
    arrivals_mps: tuple[np.ndarray, ...]
    speeds_mps: tuple[float, ...]
    final_m: np.ndarray
    model_offset_m: np.ndarray

    @property
    def length_m(self) -> float:
        """The EPM's travel over the waypoints from the first, m (the capsule slides about as far)."""
        pts = np.array(self.waypoints_m)
        return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


def plan_move(
    geometry: PlaceGeometry,
    belief: FrictionBelief,
    rest_m: np.ndarray,
    target_m: np.ndarray,
    direction: float,
    residual_m: np.ndarray,
    rest_s: float,
    progress_m: float,
    backoff_scale: float,
    height_m: float,
    max_lead_m: float,
    approach_speed_mps: float,
    run_up_m: float = RUN_UP_M,
) -> Move:
    """The EPM's waypoints of the next move (see the module docstring).

    ``direction`` (+-1) picks the side of the stiff axis the capsule approaches along;
    ``residual_m`` (2,) is what the stops so far showed beyond the belief's stop offset (0 before
    the first); ``rest_s`` how long the capsule has rested (its friction has healed);
    ``progress_m`` the tether paid out so far (the belief's drag grows with it);
    ``backoff_scale`` (>= 1) lengthens the back-off after a move that did not break loose;
    the last :data:`SLOW_M` of the approach run at ``approach_speed_mps``, after a run-up of
    ``run_up_m`` beyond the breakaway.
    """
    d = direction * geometry.axis
    fn = geometry.normal_n
    back_break = geometry.offset_for(
        BREAKAWAY_MARGIN * belief.breakaway_n(fn, rest_s, progress_m), -direction, max_lead_m
    )
    fwd_break = geometry.offset_for(
        BREAKAWAY_MARGIN * belief.breakaway_n(fn, STAGE_REST_S, progress_m), direction, max_lead_m
    )
    lead_now = geometry.lead_eq_m
    ahead = float((np.asarray(target_m) - np.asarray(rest_m)) @ d)
    single = ahead >= backoff_scale * fwd_break + run_up_m  # far enough ahead: it breaks loose on the way
    back_len = 0.0 if single else backoff_scale * max(ahead + back_break, fwd_break) + run_up_m
    # Where the capsule comes to rest the force along d has fallen to the drag (paid out by the
    # way there, out and back) and the part of the static friction that still holds it.
    drag = belief.drag_n(progress_m + (ahead if single else 2.0 * back_len))
    model_offset = _stop_from_slide(geometry, direction, max_lead_m)
    if model_offset is None:
        held = STOP_FRICTION * belief.breakaway_mu(0.0) * fn
        model_offset = geometry.offset_for(drag + held, direction, max_lead_m) * d
    final_xy = np.asarray(target_m) + lead_now + model_offset + np.asarray(residual_m)
    final = np.array([*final_xy, height_m])
    release = np.array([*(final_xy - RELEASE_M * d), height_m])
    slow = np.array([*(final_xy - SLOW_M * d), height_m])
    arrive = np.array([*(approach_speed_mps * d), 0.0])
    stop = np.zeros(3)
    slow_speeds = (approach_speed_mps, approach_speed_mps)
    if single:
        return Move(
            (slow, final, release), (arrive, stop, stop), (RUN_UP_MPS, *slow_speeds), final, model_offset
        )
    back = np.array([*(final_xy - back_len * d), height_m])
    return Move(
        (back, slow, final, release),
        (stop, arrive, stop, stop),
        (math.inf, RUN_UP_MPS, *slow_speeds),
        final,
        model_offset,
    )


def _stop_from_slide(geometry: PlaceGeometry, direction: float, max_lead_m: float) -> np.ndarray | None:
    """The stop offset (2,) beyond ``lead_eq`` from the slide's leg along the approach
    (:data:`STOP_FROM_SLIDE`; across the approach, the lead the leg held), m; None without a leg
    that pulled the capsule along the approach."""
    pull = geometry.leg_pull(direction)
    if pull is None or pull[0] <= 0.0:
        return None
    dragged, across = pull
    stop = geometry.offset_for(STOP_FROM_SLIDE * dragged, direction, max_lead_m)
    return stop * direction * geometry.axis + across


@dataclass
class _Observation:
    """Camera frames averaged at rest."""

    start_s: float
    target_m: np.ndarray
    #: The rest before the first move: the first move is planned from the target, not from this
    #: rest, so once the mean is off the target by the tolerance plus :data:`OFF_SE` standard
    #: errors the observation ends.
    first: bool = False
    frames: list[np.ndarray] = field(default_factory=list)

    def add(self, position_m: np.ndarray) -> None:
        self.frames.append(np.asarray(position_m, dtype=float))

    @property
    def se_m(self) -> float:
        """The standard error of the mean (the larger of the two axes'), m."""
        return float(np.max(np.std(self.frames, axis=0, ddof=1))) / math.sqrt(len(self.frames))

    def result(self, t_s: float, tolerance_m: float) -> tuple[np.ndarray | None, bool]:
        """(mean position, or None while the observation goes on; whether the capsule kept still).

        It goes on until the mean's standard error is below :data:`SE_FRACTION` of the tolerance
        or :data:`MAX_OBSERVE_S` have passed, also when the capsule is far off after a move: the
        next move learns its stop offset from this rest position. While the mean lies within
        :data:`AMBIGUOUS_SE` standard errors of the tolerance (placed or not is a coin toss), it
        goes on up to :data:`LONGEST_OBSERVE_S`. Before the first move it ends as soon as the
        capsule is clearly off the target (:attr:`first`).
        """
        n = len(self.frames)
        if n < MIN_FRAMES:
            return None, True
        pos = np.array(self.frames)
        mean = pos.mean(axis=0)
        se = self.se_m
        off = float(np.linalg.norm(mean - self.target_m))
        elapsed = t_s - self.start_s
        done = (
            se <= SE_FRACTION * tolerance_m
            or (self.first and off - OFF_SE * se > tolerance_m)
            or elapsed >= LONGEST_OBSERVE_S
            or (elapsed >= MAX_OBSERVE_S and abs(off - tolerance_m) >= AMBIGUOUS_SE * se)
        )
        if not done:
            return None, True
        half = n // 2
        drift = float(np.linalg.norm(pos[:half].mean(axis=0) - pos[half:].mean(axis=0)))
        return mean, drift <= 6.0 * se  # the halves' means differ by 2 SE (1 sd) when it kept still


class _Trajectory:
    """A Ruckig position trajectory through a move's waypoints, one segment after another."""

    def __init__(self, scenario: Scenario, start_m: np.ndarray, move: Move) -> None:
        self.segments: list[ruckig.Trajectory] = []
        lim = scenario.limits
        pos, vel = np.asarray(start_m, dtype=float), np.zeros(3)
        for wp, arrival, cap in zip(move.waypoints_m, move.arrivals_mps, move.speeds_mps):
            speed = min(cap, lim.speed_mps)
            inp = ruckig.InputParameter(3)
            inp.current_position, inp.current_velocity = list(pos), list(vel)
            inp.target_position, inp.target_velocity = list(wp), list(arrival)
            inp.max_velocity = [speed] * 3
            inp.max_acceleration = [lim.accel_mps2] * 3
            inp.max_jerk = [lim.jerk_mps3] * 3
            traj = ruckig.Trajectory(3)
            result = ruckig.Ruckig(3).calculate(inp, traj)
            if result not in (ruckig.Result.Working, ruckig.Result.Finished):
                raise ValueError(f"placement move: Ruckig could not plan the segment ({result})")
            self.segments.append(traj)
            pos, vel = np.asarray(wp, dtype=float), np.asarray(arrival, dtype=float)
        self.end_m = pos
        self.duration_s = sum(s.duration for s in self.segments)

    def at(self, tau_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity at ``tau_s`` after the start (held at the end)."""
        for seg in self.segments:
            if tau_s <= seg.duration:
                p, v, _ = seg.at_time(max(tau_s, 0.0))
                return np.asarray(p), np.asarray(v)
            tau_s -= seg.duration
        return self.end_m, np.zeros(3)


@dataclass
class _Memory:
    """What the moves of one placement taught: the stop offset beyond the belief's, and its drift.

    Along the approach the residual is fitted as ``c + s (P - mean P)`` over the moves' tether paid
    out ``P`` (the tether's drag grows with it; a belief without that growth sees the stop drift
    move by move), the slope ``s`` held toward 0 by a prior of :data:`DRIFT_PRIOR_N_PER_M` over the
    coupling's stiffness against a stop's scatter :data:`STOP_SCATTER_M` (ridge regression: the
    closed form of a two-parameter Bayesian fit). Across it, each stop moves the residual by
    :data:`ADAPT_GAIN` of what it showed.
    """

    progress_m: float
    direction: float = 0.0
    backoff_scale: float = 1.0
    #: Per move that broke loose: the tether paid out, the stop offset it showed beyond ``lead_eq``
    #: and the one it was planned with (2,), m.
    points: list[tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    planned: Move | None = None
    last_rest: np.ndarray | None = None
    rest_se_m: float = 0.0  # the standard error of the first rest's mean, m (kept at the release)
    moved_m: float = 0.0  # how far the camera saw the capsule from its last rest during a move

    def residual(self, axis: np.ndarray, stiffness_n_per_m: float, progress_m: float) -> np.ndarray:
        """The residual expected at a stop after ``progress_m`` of tether (2,), m."""
        if not self.points:
            return np.zeros(2)
        prog = np.array([p for p, _, _ in self.points])
        res = np.array([seen - planned for _, seen, planned in self.points])
        along = res @ axis
        across = res - np.outer(along, axis)
        lateral = across[0]
        for r in across[1:]:
            lateral = lateral + ADAPT_GAIN * (r - lateral)
        dp = prog - prog.mean()
        prior = (STOP_SCATTER_M * stiffness_n_per_m / DRIFT_PRIOR_N_PER_M) ** 2
        slope = float(dp @ (along - along.mean())) / (float(dp @ dp) + prior)
        predicted = float(along.mean()) + slope * (progress_m - float(prog.mean()))
        return lateral + predicted * axis

    def learn(self, rest_m: np.ndarray, lead_eq_m: np.ndarray) -> None:
        """After a move: what its stop showed (slope 1 in the EPM's end), or a longer back-off if the
        camera never saw the capsule leave its rest during the move."""
        move = self.planned
        if move is None:
            return
        if self.moved_m < BROKE_LOOSE_M:
            self.backoff_scale *= GROWTH
            return
        observed = move.final_m[:2] - lead_eq_m - rest_m
        self.points.append((self.progress_m, observed, move.model_offset_m))


class Placement:
    """Placement moves of one capsule onto one target (see the module docstring).

    Parameters
    ----------
    scenario : Scenario
        The controller's scenario: its ``limits`` and camera rate.
    settings : PlaceConfig
        Tolerance, move budget and approach speed.
    geometry : PlaceGeometry
        The belief's coupling near the target.
    belief : FrictionBelief
        The controller's friction belief.
    target_m : numpy.ndarray (2,)
        Where the capsule must come to rest, m.
    progress_m : float
        The tether paid out when the placement starts (the path's length), m.
    """

    def __init__(
        self,
        scenario: Scenario,
        settings: PlaceConfig,
        geometry: PlaceGeometry,
        belief: FrictionBelief,
        target_m: np.ndarray,
        progress_m: float = 0.0,
    ) -> None:
        self.scenario = scenario
        self.settings = settings
        self.geometry = geometry
        self.belief = belief
        self.target_m = np.asarray(target_m, dtype=float)
        self.moves = 0
        self.outcome = PlaceOutcome.ACTIVE
        self.reason = ""
        self.memory = _Memory(float(progress_m))
        self._traj: tuple[float, _Trajectory] | None = None  # (start time, trajectory)
        self._obs: _Observation | None = None
        self._rest_since_s = math.nan

    def start(self, t_s: float, rest_since_s: float) -> None:
        """Begin observing at ``t_s``; the capsule has rested since ``rest_since_s``."""
        self._rest_since_s = rest_since_s
        self._obs = self._observation(t_s)

    def _observation(self, start_s: float) -> _Observation:
        """A new observation from ``start_s``; before the first move it may end early off target."""
        return _Observation(start_s, self.target_m, first=self.moves == 0)

    def command(self, t_s: float, position_m: np.ndarray | None, epm_m: np.ndarray) -> np.ndarray:
        """This frame's EPM velocity command (3,), m/s, from the camera frame ``position_m`` (None
        when dropped) and the EPM position the arm reports."""
        epm = np.asarray(epm_m, dtype=float)
        if self.outcome is not PlaceOutcome.ACTIVE:
            return np.zeros(3)
        if self._traj is not None:
            mem = self.memory
            if position_m is not None and mem.last_rest is not None:
                mem.moved_m = max(mem.moved_m, float(np.linalg.norm(np.asarray(position_m) - mem.last_rest)))
            return self._follow(t_s, epm)
        if self._obs is None:
            self._obs = self._observation(t_s)
        if position_m is not None and t_s >= self._obs.start_s:
            self._obs.add(position_m)
        mean, still = self._obs.result(t_s, self.settings.tolerance_m)
        if mean is None:
            return np.zeros(3)
        if not still:  # it was still moving: watch again
            self._obs = self._observation(t_s)
            return np.zeros(3)
        try:
            self._decide(t_s, mean, self._obs.se_m, epm)
        except (ValueError, ArithmeticError) as exc:  # a move that cannot be planned: hold, say why
            self._traj = None
            self.outcome = PlaceOutcome.GAVE_UP
            self.reason = f"could not plan placement move {self.moves + 1}: {exc}"
        return np.zeros(3)

    def _decide(self, t_s: float, rest_m: np.ndarray, se_m: float, epm: np.ndarray) -> None:
        """At rest at ``rest_m`` (the mean's standard error ``se_m``): placed, gave up, or the next
        move."""
        cfg = self.settings
        self._obs = None
        mem = self.memory
        mem.learn(rest_m, self.geometry.lead_eq_m)  # also from the last move: what it showed is on record
        if self.moves == 0 and mem.last_rest is not None:  # watched again after the release
            se_first = mem.rest_se_m
            if float(np.linalg.norm(rest_m - mem.last_rest)) <= RELEASE_MOVED_SE * math.hypot(se_m, se_first):
                w = se_first**2 / (se_first**2 + se_m**2)
                rest_m = w * rest_m + (1.0 - w) * mem.last_rest
        error = self.target_m - rest_m
        if float(np.linalg.norm(error)) <= cfg.tolerance_m:
            if self.moves == 0 and mem.last_rest is None and self._release(t_s, rest_m, se_m, epm):
                return
            self.outcome = PlaceOutcome.PLACED
            return
        if self.moves >= cfg.max_moves:
            self.outcome = PlaceOutcome.GAVE_UP
            self.reason = (
                f"{self.moves} moves spent, {1e3 * float(np.linalg.norm(error)):.2f} mm off the target"
            )
            return
        if self.moves == 0:
            mem.direction = 1.0 if float(error @ self.geometry.axis) >= 0 else -1.0
        if math.isnan(self._rest_since_s):
            self._rest_since_s = t_s
        last_length = 0.0 if mem.planned is None else mem.planned.length_m
        geo = self.geometry
        move = plan_move(
            geo,
            self.belief,
            rest_m,
            self.target_m,
            mem.direction,
            mem.residual(geo.axis, geo.stiffness_n_per_m, mem.progress_m + last_length),
            max(t_s - self._rest_since_s, 0.0),
            mem.progress_m,
            mem.backoff_scale,
            float(epm[2]),
            self.scenario.limits.max_lead_m,
            cfg.approach_speed_mps,
            RUN_UP_M if cfg.track_gain_per_s > 0 else LAGGING_RUN_UP_M,
        )
        self._traj = (t_s, _Trajectory(self.scenario, epm, move))
        mem.last_rest, mem.moved_m, mem.planned = rest_m, 0.0, move
        mem.progress_m += move.length_m
        self.moves += 1

    def _release(self, t_s: float, rest_m: np.ndarray, se_m: float, epm: np.ndarray) -> bool:
        """Move the EPM to the believed zero-force lead over ``rest_m``, then watch again (the module
        docstring); False when it is there already."""
        self.memory.last_rest, self.memory.rest_se_m = rest_m, se_m  # before any move: the release's mark
        goal = np.array([*(rest_m + self.geometry.lead_eq_m), epm[2]])
        if float(np.linalg.norm(goal[:2] - epm[:2])) < RELEASE_MIN_M:
            return False
        move = Move((goal,), (np.zeros(3),), (math.inf,), goal, np.zeros(2))
        self._traj = (t_s, _Trajectory(self.scenario, epm, move))
        return True

    def _follow(self, t_s: float, epm: np.ndarray) -> np.ndarray:
        """Follow the move's trajectory; at its end start settling and observing."""
        assert self._traj is not None
        t0, traj = self._traj
        tau = t_s - t0
        dt = 1.0 / self.scenario.camera.rate_hz
        pos, _ = traj.at(tau)
        _, vel = traj.at(tau + dt)
        u = vel + self.settings.track_gain_per_s * (pos - epm)
        if tau >= traj.duration_s:
            err = traj.end_m - epm
            if float(np.max(np.abs(err[:2]))) <= EPM_TOL_M or tau >= traj.duration_s + EPM_WAIT_S:
                self._traj = None
                self._obs = self._observation(t_s + SETTLE_S)
                self._rest_since_s = t_s
                return np.zeros(3)
            u = POSITION_GAIN * err
        u[2] = 0.0
        return u


class PlacementProducer:
    """``PLACE``, ``HOLD`` and ``FAILED``: the sliding MPC holds the path's end until the capsule
    rests, then :class:`Placement` moves it onto the path's last point (``place.max_moves: 0``: the
    MPC holds the end for good). ``DONE`` / ``GAVE_UP`` are raised at the frame the placement ends.

    Parameters
    ----------
    scenario : Scenario
        The controller's scenario (``place``, ``limits``, ``plate``).
    slide : SlideProducer
        The sliding MPC.
    force : casadi.Function
        The controller's force model ``(lead (2), height) -> (F_x, F_y, F_att)``, N.
    lead_eq_m : numpy.ndarray (2,)
        The model's equilibrium lead, m.
    belief : FrictionBelief
        The controller's friction belief.
    progress_m : float
        The tether paid out by the path (its length), m.
    """

    def __init__(
        self,
        scenario: Scenario,
        slide: SlideProducer,
        force: Callable[[np.ndarray, float], np.ndarray],
        lead_eq_m: np.ndarray,
        belief: FrictionBelief,
        progress_m: float,
    ) -> None:
        self.scenario = scenario
        self.slide = slide
        self.force = force
        self.lead_eq_m = np.asarray(lead_eq_m, dtype=float)
        self.belief = belief
        self.progress_m = float(progress_m)
        self.placement: Placement | None = None
        self.leads = SlideLeads()
        self._ended = False

    @property
    def moves(self) -> int:
        """Placement moves so far."""
        return 0 if self.placement is None else self.placement.moves

    def observe(self, ctx: FrameContext) -> None:
        """Until the placement begins, the leads of the slide (:class:`SlideLeads`); the placement
        reads the frames it needs in :meth:`produce`."""
        if self.placement is None:
            self.leads.add(ctx.t_s, ctx.position_m, ctx.epm_m)

    def _begin(self, ctx: FrameContext) -> Placement:
        """The placement of this run, from the belief at this frame (its disturbance included)."""
        height = float(ctx.epm_m[2])

        def normal(f_att: float) -> float:
            return float(normal_force_expr(self.scenario, f_att))

        geometry = place_geometry(self.force, self.lead_eq_m, height, ctx.disturbance_n[0:2], normal)
        self.leads.close()
        index = int(np.argmax(np.abs(geometry.axis)))
        legs = {d: self.leads.lead(index, d) for d in (1.0, -1.0)}
        geometry = replace(geometry, legs_m={d: lead for d, lead in legs.items() if lead is not None})
        placement = Placement(
            self.scenario, self.scenario.place, geometry, self.belief, ctx.target_m, self.progress_m
        )
        placement.start(ctx.t_s, ctx.t_s - ctx.rest_s)
        self.slide.drop_plan()
        return placement

    def produce(self, ctx: FrameContext) -> PhaseOutput:
        """The MPC's command until the capsule rests, then the placement's."""
        if self.placement is None:
            if self.scenario.place.max_moves == 0 or not (ctx.resting and ctx.rest_s >= REST_BEFORE_S):
                return self.slide.produce(ctx)
            self.placement = self._begin(ctx)
        placement = self.placement
        u = placement.command(ctx.t_s, ctx.measurement.position_m, ctx.epm_m)
        stats = StepStats(
            status=f"place: {placement.outcome.value}",
            extra={"placement_moves": float(placement.moves)},
            outcome=StepOutcome.PLACE,
        )
        event, reason = None, ""
        if placement.outcome is not PlaceOutcome.ACTIVE and not self._ended:
            self._ended = True
            if placement.outcome is PlaceOutcome.PLACED:
                event, reason = Event.DONE, "within place.tolerance_m of the target"
            else:
                event, reason = Event.GAVE_UP, placement.reason
        return PhaseOutput(u, stats, event, reason)
