"""The sliding MPC's reference window: the path over the horizon, joined from where the capsule rests.

At the start the offset of the rest position from the path's start fades out over
``break_loose.blend_s`` (a half cosine), so the capsule breaks loose along the path and is steered
onto it while it slides, instead of being dragged sideways out of the static-friction dead zone
first (a breakaway across the path lurches millimetres on the soft axis). The run is still scored
against the path itself. Before t = 0 (the rig holds the EPM) the reference stays at the start.

At a turn of the path the coupling's lead must change by many millimetres (sliding along the soft
axis needs a far larger lead than along the stiff one), and the MPC's jerk cost, which smooths the
commands on the straight legs, makes the EPM build it slowly: much of the tracking error comes in
the second after a corner. So the window also carries a factor of the jerk cost's weight per
stage, :data:`TURN_JERK_FACTOR` from :data:`TURN_BEFORE_S` before a turn to :data:`TURN_AFTER_S`
after it and 1 elsewhere.
"""

from __future__ import annotations

import numpy as np

from ..friction import FrictionBelief
from ..paths import ReferencePath
from .problem import OCP

__all__ = ["TURN_AFTER_S", "TURN_BEFORE_S", "TURN_JERK_FACTOR", "SlideReference"]

#: The jerk cost's weight factor around a turn, and the window it holds over, s (tuned on `lab`
#: draws 0-99 and `hard` draws 0-49 of the rectangle).
TURN_JERK_FACTOR = 0.5
TURN_BEFORE_S = 0.3
TURN_AFTER_S = 1.0
#: Directions whose unit vectors' dot product is below this make a turn (about 25 degrees).
TURN_COS = 0.9


class SlideReference:
    """The reference of one run (see the module docstring).

    Parameters
    ----------
    path : ReferencePath
        The reference path.
    ocp : OCP
        The sliding MPC's problem (its stage times).
    blend_s : float
        ``break_loose.blend_s``, s (0: no join).
    belief : FrictionBelief
        The controller's friction belief (the tether drag's growth along the path).
    """

    def __init__(self, path: ReferencePath, ocp: OCP, blend_s: float, belief: FrictionBelief) -> None:
        self.path = path
        self.ocp = ocp
        self.blend_s = float(blend_s)
        self.belief = belief
        self.start_offset_m: np.ndarray | None = None
        self._started = False
        self.turns_s = path.turn_times_s(TURN_COS)

    def start(self, position_m: np.ndarray) -> None:
        """At the first frame with t >= 0: join the path from ``position_m`` (once)."""
        if self._started:
            return
        self._started = True
        if self.blend_s > 0:
            self.start_offset_m = np.asarray(position_m, dtype=float) - self.path.start_m

    def window(self, t_s: float) -> np.ndarray:
        """Capsule position and velocity at stages 1..N and the EPM feed-forward (the path's
        velocity) of inputs 0..N-1 and the jerk cost's factor of stages 1..N (7 x N)."""
        n = self.ocp.horizon
        times = t_s + self.ocp.node_times_s[1:]
        if t_s < 0:  # the rig holds the EPM: plan to stay at the start
            return np.vstack([self.path.position(np.zeros(n)).T, np.zeros((4, n)), np.ones((1, n))])
        pos, vel = self.path.position(times).T, self.path.velocity(times).T
        if self.start_offset_m is not None and times[0] < self.blend_s:  # after the blend: the path
            pos, vel = self.join(times, pos, vel)
        return np.vstack([pos, vel, vel, self.jerk_factor(times)[None, :]])

    def jerk_factor(self, times_s: np.ndarray) -> np.ndarray:
        """The jerk cost's weight factor at ``times_s``: :data:`TURN_JERK_FACTOR` around a turn."""
        since = np.asarray(times_s, dtype=float)[:, None] - self.turns_s[None, :]
        near = ((since >= -TURN_BEFORE_S) & (since <= TURN_AFTER_S)).any(axis=1)
        return np.where(near, TURN_JERK_FACTOR, 1.0)

    def join(self, times: np.ndarray, pos: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The path's positions and velocities at ``times`` (2 x n) with the start offset faded out
        over ``blend_s`` (a half cosine)."""
        assert self.start_offset_m is not None
        blend = self.blend_s
        phase = np.clip(times / blend, 0.0, 1.0)
        weight = 0.5 * (1.0 + np.cos(np.pi * phase))
        rate = np.where(phase < 1.0, -0.5 * np.pi / blend * np.sin(np.pi * phase), 0.0)
        offset = self.start_offset_m[:, None]
        return pos + offset * weight, vel + offset * rate

    def progress_m(self, t_s: float) -> float:
        """The tether paid out at ``t_s``, m: the reference's progress along the path (the capsule
        follows it within millimetres; a projection of the estimate would jump where a closed path
        passes its start again)."""
        duration = self.path.duration_s
        return self.path.length_m * min(max(t_s, 0.0) / duration, 1.0) if duration > 0 else 0.0

    def drag_growth_n(self, t_s: float) -> float:
        """The believed tether drag's growth at ``t_s`` over its value at the start, N."""
        return float(self.belief.drag_growth_n(self.progress_m(t_s)))
