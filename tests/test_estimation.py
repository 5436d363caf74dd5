"""The capsule state estimator (Kalman filter with latency prediction)."""

from __future__ import annotations

import numpy as np
import pytest

from capsule_mpc.estimation import CapsuleEstimator


def test_converges_on_a_noisy_constant_velocity_track():
    rng = np.random.default_rng(0)
    est = CapsuleEstimator(noise_std_m=3e-4, accel_std_mps2=0.3)
    v = np.array([0.02, -0.01])
    latency = 1 / 30
    errors_v, errors_p, errors_fd, errors_raw = [], [], [], []
    prev = None
    for k in range(150):
        capture = k / 30
        z = v * capture + rng.normal(0, 3e-4, 2)
        est.update(capture, z)
        now = capture + latency
        p_hat, v_hat = est.estimate(now)
        if k > 60:
            errors_v.append(np.linalg.norm(v_hat - v))
            errors_p.append(np.linalg.norm(p_hat - v * now))
            errors_fd.append(np.linalg.norm((z - prev) * 30 - v))
            errors_raw.append(np.linalg.norm(z - v * now))
        prev = z
    rms_v = np.sqrt(np.mean(np.square(errors_v)))
    # Far better than differentiating the camera (~18 mm/s RMS in 2-D from 0.3 mm noise).
    assert rms_v < 0.5 * np.sqrt(np.mean(np.square(errors_fd)))
    assert rms_v < 1.2e-2  # 2-D, about 6 mm/s per axis
    # Latency compensated: the estimate of *now* beats the raw, one-frame-old measurement.
    assert np.sqrt(np.mean(np.square(errors_p))) < 0.85 * np.sqrt(np.mean(np.square(errors_raw)))


@pytest.mark.parametrize("noise", [0.0, 3e-4])
def test_tracks_a_velocity_change(noise):
    # A noiseless camera must not make the filter ring (velocity gain -> 2/dt without a floor).
    rng = np.random.default_rng(1)
    est = CapsuleEstimator(noise_std_m=noise, accel_std_mps2=0.3)
    errors = []
    for k in range(90):
        t = k / 30
        truth = np.array([0.01 * t if t < 1 else 0.01 + 0.03 * (t - 1), 0.0])
        est.update(t, truth + rng.normal(0, noise, 2))
        if k >= 60:
            errors.append(est.estimate(t)[1][0] - 0.03)
    assert np.sqrt(np.mean(np.square(errors))) < (1e-4 if noise == 0 else 8e-3)


def test_dropped_frames_only_predict_and_time_must_not_go_back():
    est = CapsuleEstimator(noise_std_m=3e-4, accel_std_mps2=0.3)
    with pytest.raises(RuntimeError, match="before the first measurement"):
        est.estimate(0.0)
    est.update(0.0, np.zeros(2))
    est.update(0.1, np.array([0.002, 0.0]))
    std_before = est.position_std_m()
    p, _ = est.estimate(1.0)  # a second without frames: prediction only, uncertainty grows
    assert np.all(np.isfinite(p))
    with pytest.raises(ValueError, match="back in time"):
        est.update(0.05, np.zeros(2))
    est.update(1.0, np.array([0.02, 0.0]))
    assert est.position_std_m() <= max(std_before, 3e-4) * 1.5
