"""The camera: capsule position at a fixed frame rate with Gaussian noise, latency and dropped frames."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from ..config import CameraConfig
from ..control import Measurement

__all__ = ["Camera"]


class Camera:
    """A camera that sees the capsule's true position and delivers it late and noisy.

    At every frame the camera captures the true position plus independent
    Gaussian noise (``noise_std_m`` per axis); the capture is lost with
    probability ``drop_probability``; what the controller receives at frame j is
    the capture of frame ``j - latency_frames``. Every frame draws exactly one
    2-vector of noise and one uniform number from ``rng`` (in that order), so a
    seed fixes the whole sequence whatever is dropped.

    Parameters
    ----------
    config : CameraConfig
        Rate, noise, latency and drop probability.
    rng : numpy.random.Generator
        The run's random generator.
    """

    def __init__(self, config: CameraConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.rng = rng
        self._queue: deque[tuple[float, np.ndarray | None]] = deque()

    @property
    def period_s(self) -> float:
        """Time between frames, s."""
        return 1.0 / self.config.rate_hz

    def reset(self) -> None:
        """Forget captures in flight."""
        self._queue.clear()

    def frame(self, t_s: float, true_position_m: np.ndarray) -> Measurement:
        """Capture the capsule at ``t_s`` (s) and deliver the frame due now.

        Parameters
        ----------
        t_s : float
            Frame time, s.
        true_position_m : numpy.ndarray (2,)
            The capsule's true position at ``t_s``, m.

        Returns
        -------
        Measurement
            Delivered at ``t_s``; ``position_m`` is None when the delivered capture was dropped or
            none has arrived yet (then ``capture_t_s`` is NaN).
        """
        noise = self.rng.normal(0.0, self.config.noise_std_m, 2)
        lost = self.rng.random() < self.config.drop_probability
        capture = None if lost else np.asarray(true_position_m, dtype=float)[:2] + noise
        self._queue.append((t_s, capture))
        if len(self._queue) <= self.config.latency_frames:
            return Measurement(t_s=t_s, capture_t_s=math.nan, position_m=None)
        capture_t, pos = self._queue.popleft()
        return Measurement(t_s=t_s, capture_t_s=capture_t, position_m=pos)
