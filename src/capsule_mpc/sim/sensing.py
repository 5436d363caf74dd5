"""The camera: capsule position at a frame rate with bias, Gaussian noise, latency and dropped frames."""

from __future__ import annotations

import math
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from ..config import CameraConfig
from ..interfaces import Measurement

if TYPE_CHECKING:
    from .faults import FaultInjector

__all__ = ["Camera"]


class Camera:
    """A camera that sees the capsule's true position and delivers it late and noisy.

    At every frame the camera captures the true position plus a constant bias
    (``bias_m``) plus independent Gaussian noise (``noise_std_m`` per axis); the
    capture is lost with probability ``drop_probability``; what the controller
    receives at frame j is the capture of frame ``j - latency_frames``. Every frame
    draws exactly one 2-vector of noise (``rng.normal(0, noise_std_m, 2)``) and one
    uniform number from ``rng`` (in that order), so a seed fixes the whole sequence
    whatever is dropped, and the bias and the noise level change neither the draws
    nor which frames are dropped.

    The bias and the noise level here are the truth; the controller's estimator
    keeps using ``config.noise_std_m`` (its belief) and knows nothing of the bias.

    Parameters
    ----------
    config : CameraConfig
        Rate, noise (the belief, and the truth unless ``noise_std_m`` is given), latency and drop
        probability.
    rng : numpy.random.Generator
        The run's random generator.
    bias_m : tuple of float
        Constant offset (x, y) of every captured position, m, finite: the calibration error of the
        camera-to-plate registration. Default (0, 0).
    noise_std_m : float, optional
        True noise standard deviation per axis, m, finite and >= 0; None (the default) uses
        ``config.noise_std_m``.
    faults : FaultInjector, optional
        Injected camera faults (drop bursts, outliers; :mod:`.faults`), applied to each capture
        after the noise and bias, from their own random streams (the camera's draws are the
        same with or without them). None (the default): no injected faults.

    Raises
    ------
    ValueError
        If ``bias_m`` is not 2 finite values or ``noise_std_m`` is not finite and >= 0.
    """

    def __init__(
        self,
        config: CameraConfig,
        rng: np.random.Generator,
        *,
        bias_m: tuple[float, float] = (0.0, 0.0),
        noise_std_m: float | None = None,
        faults: FaultInjector | None = None,
    ) -> None:
        bias = np.asarray(bias_m, dtype=float)
        if bias.shape != (2,) or not np.all(np.isfinite(bias)):
            raise ValueError(f"bias_m: must be 2 finite values (x, y), m, got {bias_m!r}")
        sigma = float(config.noise_std_m if noise_std_m is None else noise_std_m)
        if not (math.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"noise_std_m: must be finite and >= 0, m, got {noise_std_m}")
        self.config = config
        self.rng = rng
        self.bias_m: tuple[float, float] = (float(bias[0]), float(bias[1]))
        self.noise_std_m = sigma
        self.faults = faults
        # A zero bias is not added at all, so default cameras reproduce earlier runs bit for bit.
        self._bias = bias if np.any(bias != 0) else None
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
            The capsule's true position at ``t_s``, m (only the first 2 entries are read).

        Returns
        -------
        Measurement
            Delivered at ``t_s``; ``position_m`` is None when the delivered capture was dropped or
            none has arrived yet (then ``capture_t_s`` is NaN).
        """
        noise = self.rng.normal(0.0, self.noise_std_m, 2)
        lost = self.rng.random() < self.config.drop_probability
        capture = None if lost else np.asarray(true_position_m, dtype=float)[:2] + noise
        if capture is not None and self._bias is not None:
            capture += self._bias
        if self.faults is not None:
            capture = self.faults.camera_capture(t_s, capture)
        self._queue.append((t_s, capture))
        if len(self._queue) <= self.config.latency_frames:
            return Measurement(t_s=t_s, capture_t_s=math.nan, position_m=None)
        capture_t, pos = self._queue.popleft()
        return Measurement(t_s=t_s, capture_t_s=capture_t, position_m=pos)
