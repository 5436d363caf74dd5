"""Contact modes of the MPC's prediction: the stages in which static friction holds the capsule.

A capsule at rest stays put until the lateral force on it exceeds its breakaway force, which heals
(grows) with the time it has rested. A smooth friction law cannot say that: at low speed it
predicts little friction, so a plan from rest expects the capsule to follow a small force, and
the capsule instead sticks while the reference moves on, then lurches. A switch between sticking
and sliding inside the optimisation would make the problem non-smooth; instead each stage gets a
static friction force, fixed before each solve (``mpc.stick_prediction``): the breakaway force
less the model's own friction at rest, in the stages the capsule is predicted to rest in, 0 in
the others. It acts like the model's friction (against the motion, through the smoothed
direction), so in the prediction a force below breakaway only creeps the capsule and more force
moves it more: the solver sees what building the force up earlier buys. Which stages rest:

* the capsule rests from the first frame (it was placed and settled) until the mean of its last
  :data:`DEPART_FRAMES` estimated positions leaves the rest position (the mean of the estimates
  since it came to rest) by more than :attr:`ContactModes.depart_m`; after moving it rests again
  once a line through its estimated positions over :data:`REST_WINDOW_S` is slower than
  ``moving_mps`` (the rest counted from the window's start). A noisy velocity estimate alone
  cannot tell a stuck capsule from a creeping one;
* while it moves, every stage slides;
* while it rests, the stages are stuck up to the first stage at which the force the model
  predicts on the still capsule (the EPM where the previous plan, shifted by a frame, puts it;
  the estimated constant disturbance added) exceeds the friction belief's breakaway force after
  the rest so far plus the time to that stage (:meth:`capsule_mpc.friction.FrictionBelief.breakaway_n`).
  From that stage on the capsule slides.

Each frame re-evaluates the stages from the newest plan, so the predicted breakaway moves as the
plan does. The paper's law has no static part: its breakaway is ``mu0 F_N`` plus the drag.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np

from ..dynamics import CapsuleModel
from ..estimation import fit_window
from ..friction import FrictionBelief

__all__ = ["REST_WINDOW_S", "ContactModes", "RestDetector"]

#: Window of estimated positions a capsule must stay slow over to count as resting again, s.
REST_WINDOW_S = 0.3
#: Fewest camera noise standard deviations the recent estimates must leave the rest position by
#: to count as moving, the least distance (m), and how many recent estimates are averaged.
DEPART_NOISE_STDS, DEPART_MIN_M, DEPART_FRAMES = 4.0, 5e-4, 4


class RestDetector:
    """Whether a capsule rests, from its estimated positions, and since when (see the module
    docstring for the rule).

    Parameters
    ----------
    noise_std_m : float
        The camera's noise per axis the controller assumes, m.
    moving_mps : float
        Speed of a line through the recent estimates above which the capsule has not come to
        rest, m/s.
    """

    def __init__(self, noise_std_m: float, moving_mps: float) -> None:
        #: Distance from the rest position at which the capsule counts as moving, m.
        self.depart_m = max(DEPART_NOISE_STDS * noise_std_m, DEPART_MIN_M)
        self.moving_mps = float(moving_mps)
        self._rest_start_s: float | None = None
        self._rest_sum = np.zeros(2)
        self._rest_count = 0
        self._recent: deque[tuple[float, np.ndarray]] = deque()
        self._first = True

    @property
    def resting(self) -> bool:
        """Whether the capsule rested at the last update."""
        return self._rest_start_s is not None

    @property
    def rest_position_m(self) -> np.ndarray | None:
        """Where it rests (the mean of its estimates since it came to rest), m; None if it moves."""
        return None if self._rest_start_s is None else self._rest_sum / self._rest_count

    def rest_s(self, t_s: float) -> float:
        """How long the capsule has rested at ``t_s``, s (0 while it moves)."""
        return 0.0 if self._rest_start_s is None else t_s - self._rest_start_s

    def _rest(self, since_s: float, positions: list[np.ndarray]) -> None:
        self._rest_start_s = since_s
        self._rest_sum = np.sum(positions, axis=0)
        self._rest_count = len(positions)

    def update(self, t_s: float, position_m: np.ndarray) -> bool:
        """Take the estimated position at ``t_s`` and say whether the capsule rests."""
        pos = np.asarray(position_m, dtype=float)
        if self._first:
            self._first = False
            self._rest(t_s, [pos])
            self._recent.append((t_s, pos))
            return True
        self._recent.append((t_s, pos))
        if self._rest_start_s is not None:
            last = np.mean([p for _, p in list(self._recent)[-DEPART_FRAMES:]], axis=0)
            if float(np.linalg.norm(last - self._rest_sum / self._rest_count)) <= self.depart_m:
                self._rest_sum += pos
                self._rest_count += 1
                while len(self._recent) > DEPART_FRAMES:
                    self._recent.popleft()
                return True
            self._rest_start_s = None  # broke loose
        while self._recent[0][0] < t_s - REST_WINDOW_S:
            self._recent.popleft()
        if self._recent[-1][0] - self._recent[0][0] < REST_WINDOW_S - 1e-9:
            return False
        fit = fit_window(self._recent, t_s, REST_WINDOW_S)
        if fit is None or float(np.linalg.norm(fit.velocity_mps)) >= self.moving_mps:
            return False
        self._rest(self._recent[0][0], [p for _, p in self._recent])
        return True


class ContactModes:
    """Per-frame static friction of the MPC's stages (:mod:`capsule_mpc.mpc.contact`).

    Parameters
    ----------
    model : CapsuleModel
        The MPC's capsule model: its force, normal force and friction at rest.
    belief : FrictionBelief
        The controller's friction belief (its breakaway force).
    stage_times_s : numpy.ndarray (N,)
        Times of stages 1..N from the frame the plan starts at, s.
    rest : RestDetector
        Whether the capsule rests and since when (updated by the caller every frame).
    """

    def __init__(
        self,
        model: CapsuleModel,
        belief: FrictionBelief,
        stage_times_s: np.ndarray,
        rest: RestDetector,
    ) -> None:
        self.belief = belief
        self.stage_times_s = np.asarray(stage_times_s, dtype=float)
        self._outputs = model.outputs.map(len(self.stage_times_s))
        self.rest = rest
        self.breakaway_stage = 0

    def static_n(
        self,
        t_s: float,
        epm_path_m: np.ndarray,
        disturbance_xy_n: np.ndarray,
        progress_m: Callable[[float], float],
    ) -> np.ndarray:
        """The static friction of stages 0..N-1 for the frame at ``t_s``, N (stage k's velocity
        row gives the velocity at stage k+1, so whether it rests is decided by the force there),
        with the capsule where it rests (:attr:`RestDetector.rest_position_m`).

        Parameters
        ----------
        t_s : float
            The frame's time, s.
        epm_path_m : numpy.ndarray (3 x N)
            The EPM's predicted position (x, y, height) at stages 1..N, m.
        disturbance_xy_n : numpy.ndarray (2,)
            The estimated constant force on the capsule besides the magnet's, N.
        progress_m : callable
            The tether paid out at a time, m (the drag grows with it).
        """
        n = len(self.stage_times_s)
        position = self.rest.rest_position_m
        if position is None:
            self.breakaway_stage = 0
            return np.zeros(n)
        epm = np.asarray(epm_path_m, dtype=float)
        still = np.vstack([np.tile(position[:, None], (1, n)), np.zeros((2, n)), epm])
        _lead, forces, normal, mu = (np.asarray(x) for x in self._outputs(still))
        lateral = np.linalg.norm(forces[0:2] + np.asarray(disturbance_xy_n, dtype=float)[:, None], axis=0)
        normal = np.maximum(normal.ravel(), 0.0)
        rest = self.rest.rest_s(t_s)
        drag = np.array([self.belief.drag_n(progress_m(t_s + dt)) for dt in self.stage_times_s])
        breakaway = (
            np.array([self.belief.breakaway_mu(rest + dt) for dt in self.stage_times_s]) * normal + drag
        )
        free = np.maximum.accumulate(lateral > breakaway)
        self.breakaway_stage = int(np.argmax(free)) if free.any() else n
        sliding = mu.ravel() * normal + drag  # the model's own friction of a capsule at rest
        return np.where(free, 0.0, np.maximum(breakaway - sliding, 0.0))
