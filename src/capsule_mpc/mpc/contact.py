"""Whether the capsule rests, and since when: what the phases that use static friction (the
start's pre-load, the placement) judge a capsule by.

A capsule at rest stays put until the lateral force on it exceeds its breakaway force, which heals
(grows) with the time it has rested. A noisy velocity estimate alone cannot tell a stuck capsule
from a creeping one, so the rule is on positions:

* the capsule rests from the first frame (it was placed and settled) until the mean of its last
  :data:`DEPART_FRAMES` estimated positions leaves the rest position (the mean of the estimates
  since it came to rest) by more than :attr:`RestDetector.depart_m`;
* after moving it rests again once a line through its estimated positions over
  :data:`REST_WINDOW_S` is slower than ``moving_mps`` (the rest counted from the window's start).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from ..estimation import MIN_FIT_FRAMES

__all__ = ["DEPART_FRAMES", "DEPART_MIN_M", "DEPART_NOISE_STDS", "REST_WINDOW_S", "RestDetector"]

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
        if len(self._recent) < MIN_FIT_FRAMES or self._speed_mps() >= self.moving_mps:
            return False
        self._rest(self._recent[0][0], [p for _, p in self._recent])
        return True

    def _speed_mps(self) -> float:
        """Speed of the least-squares line through the recent positions (all within the window),
        m/s: the slope in closed form, on Python floats (a two-parameter fit to about ten points,
        where NumPy's and LAPACK's call overhead costs more than the sums; this runs every frame)."""
        n = len(self._recent)
        ts = [tc for tc, _ in self._recent]
        xs = [float(p[0]) for _, p in self._recent]
        ys = [float(p[1]) for _, p in self._recent]
        tm, xm, ym = sum(ts) / n, sum(xs) / n, sum(ys) / n
        dts = [t - tm for t in ts]
        stt = sum(d * d for d in dts)
        vx = sum(d * (x - xm) for d, x in zip(dts, xs, strict=True)) / stt
        vy = sum(d * (y - ym) for d, y in zip(dts, ys, strict=True)) / stt
        return math.hypot(vx, vy)
