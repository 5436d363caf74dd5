"""The capsule state estimator (Kalman filter with latency prediction)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from capsule_mpc.estimation import GATE_CHI2, REACQUIRE_AFTER, CapsuleEstimator


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


def _tracked(est: CapsuleEstimator, v: np.ndarray, frames: int, rng: np.random.Generator) -> float:
    """Feed ``frames`` noisy frames of a constant-velocity capsule; returns the last frame's time."""
    t = 0.0
    for k in range(frames):
        t = k / 30
        assert est.update(t, v * t + rng.normal(0, 3e-4, 2))
    return t


def test_the_gate_rejects_a_10mm_outlier_and_keeps_the_prediction():
    rng = np.random.default_rng(2)
    est = CapsuleEstimator(noise_std_m=3e-4, accel_std_mps2=0.3)
    v = np.array([0.02, 0.0])
    t = _tracked(est, v, 60, rng)
    t += 1 / 30
    assert not est.update(t, v * t + np.array([0.0, 0.01]))
    assert est.rejected == 1
    p, _ = est.estimate(t)
    assert np.linalg.norm(p - v * t) < 1e-3  # the outlier was not fused
    t += 1 / 30
    assert est.update(t, v * t)  # the next good frame is accepted
    assert est.reacquisitions == 0


def test_the_gate_accepts_a_real_fast_motion():
    # A breakaway: from rest to 50 mm/s at 1 m/s^2 (twice the EPM's acceleration limit), noisy.
    rng = np.random.default_rng(3)
    est = CapsuleEstimator(noise_std_m=3e-4, accel_std_mps2=0.3)
    for k in range(120):
        t = k / 30
        moving = max(t - 1.0, 0.0)
        x = 0.5 * min(moving, 0.05) ** 2 + 0.05 * max(moving - 0.05, 0.0)
        assert est.update(t, np.array([x, 0.0]) + rng.normal(0, 5e-4, 2)), t  # true noise 0.5 mm
    assert est.rejected == 0


def test_the_filter_reacquires_a_capsule_that_really_jumped():
    rng = np.random.default_rng(4)
    est = CapsuleEstimator(noise_std_m=3e-4, accel_std_mps2=0.3)
    t = _tracked(est, np.zeros(2), 30, rng)
    jumped = np.array([0.01, 0.0])
    accepted = []
    for _ in range(REACQUIRE_AFTER):
        t += 1 / 30
        accepted.append(est.update(t, jumped))
    assert accepted == [False] * (REACQUIRE_AFTER - 1) + [True]
    assert est.reacquisitions == 1
    assert est.estimate(t)[0] == pytest.approx(jumped, abs=1e-12)


def test_after_a_long_drop_the_gate_is_open_again():
    rng = np.random.default_rng(5)
    est = CapsuleEstimator(noise_std_m=3e-4, accel_std_mps2=0.3)
    t = _tracked(est, np.array([0.02, 0.0]), 30, rng)
    # One second without frames, during which the capsule stopped 10 mm short of the prediction.
    t_after = t + 1.0
    assert est.update(t_after, np.array([0.02 * t_after - 0.01, 0.0]))
    assert est.rejected == 0


def test_the_gate_is_the_chi_square_quantile_scipy_gives():
    """The closed form -2 ln(p) of the 2-dof quantile equals scipy's chi2.ppf (an independent source)."""
    assert GATE_CHI2 == pytest.approx(float(chi2.ppf(1.0 - 1e-6, 2)), rel=1e-9)
