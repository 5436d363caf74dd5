"""The camera's truth: a calibration bias and a noise level that differ from the controller's belief."""

from __future__ import annotations

import math

import numpy as np
import pytest

from capsule_mpc.config import CameraConfig
from capsule_mpc.sim.sensing import Camera

N_FRAMES = 4000
TRUE_POS = np.array([0.0123, -0.0456])


def config(**kw: float) -> CameraConfig:
    return CameraConfig(**{"noise_std_m": 3e-4, "latency_frames": 1, "drop_probability": 0.0, **kw})


def captures(cam: Camera, n: int = N_FRAMES, pos: np.ndarray = TRUE_POS) -> np.ndarray:
    """The delivered positions of n frames of a capsule at rest (dropped frames left out)."""
    got = [cam.frame(j * cam.period_s, pos).position_m for j in range(n)]
    return np.array([p for p in got if p is not None])


def test_mean_is_true_plus_bias_and_std_is_the_true_noise():
    # 4000 frames of sigma = 1 mm: the mean's standard error is 16 um, the std's 1.1 %; the
    # tolerances (80 um, 5 %) are ~5 and ~4.5 standard errors. The config's belief, 0.3 mm, is
    # more than 20 standard errors away.
    bias, sigma = (2e-3, -1e-3), 1e-3
    cam = Camera(config(), np.random.default_rng(1), bias_m=bias, noise_std_m=sigma)
    z = captures(cam)
    assert len(z) == N_FRAMES - 1  # the first frame is still in flight (latency 1)
    np.testing.assert_allclose(z.mean(axis=0), TRUE_POS + bias, atol=8e-5)
    np.testing.assert_allclose(z.std(axis=0), [sigma, sigma], rtol=0.05)
    assert cam.noise_std_m == sigma and cam.config.noise_std_m == 3e-4  # truth vs belief
    assert cam.bias_m == bias


def test_noise_defaults_to_the_config_and_zero_noise_gives_true_plus_bias():
    z = captures(Camera(config(), np.random.default_rng(2)))
    np.testing.assert_allclose(z.std(axis=0), [3e-4, 3e-4], rtol=0.05)
    exact = captures(Camera(config(), np.random.default_rng(2), bias_m=(1e-3, 0.0), noise_std_m=0.0), 10)
    assert np.all(exact == TRUE_POS + np.array([1e-3, 0.0]))


def test_defaults_reproduce_the_camera_without_the_new_arguments():
    cfg = config(latency_frames=2, drop_probability=0.3)
    old = Camera(cfg, np.random.default_rng(3))
    new = Camera(cfg, np.random.default_rng(3), bias_m=(0.0, 0.0), noise_std_m=None)
    # The documented draws, replayed by hand: one normal 2-vector, then one uniform, per frame.
    replay = np.random.default_rng(3)
    queue = []
    for j in range(500):
        pos = np.array([1e-4 * j, -2e-4 * j])
        a, b = old.frame(j / 30, pos), new.frame(j / 30, pos)
        noise = replay.normal(0.0, cfg.noise_std_m, 2)
        lost = replay.random() < cfg.drop_probability
        queue.append(None if lost else pos + noise)
        expected = queue.pop(0) if j >= 2 else None
        for m in (a, b):
            if expected is None:
                assert m.position_m is None
            else:
                assert m.position_m is not None and np.array_equal(m.position_m, expected)
        assert a.capture_t_s == b.capture_t_s or (math.isnan(a.capture_t_s) and math.isnan(b.capture_t_s))


def test_bias_and_noise_level_change_neither_the_draws_nor_the_drops():
    cfg = config(drop_probability=0.3)
    base = Camera(cfg, np.random.default_rng(4))
    other = Camera(cfg, np.random.default_rng(4), bias_m=(5e-4, 5e-4), noise_std_m=6e-4)
    for j in range(300):
        a, b = base.frame(j / 30, TRUE_POS), other.frame(j / 30, TRUE_POS)
        assert a.valid == b.valid
        if a.position_m is not None and b.position_m is not None:
            # Same standard normals, twice the sigma, plus the bias.
            np.testing.assert_allclose(
                b.position_m - TRUE_POS - 5e-4, 2 * (a.position_m - TRUE_POS), atol=1e-15
            )


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"noise_std_m": -1e-4}, r"noise_std_m: must be finite and >= 0, m, got -0.0001"),
        ({"noise_std_m": math.inf}, r"noise_std_m: must be finite and >= 0"),
        ({"noise_std_m": math.nan}, r"noise_std_m: must be finite and >= 0"),
        ({"bias_m": (0.0, math.nan)}, r"bias_m: must be 2 finite values"),
        ({"bias_m": (0.0, 0.0, 0.0)}, r"bias_m: must be 2 finite values"),
    ],
)
def test_bad_truth_is_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Camera(config(), np.random.default_rng(0), **kwargs)
