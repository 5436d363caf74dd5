"""When the capsule counts as resting (capsule_mpc.mpc.contact): camera noise never breaks a rest, a
capsule that slides off stops resting, and rests again once still."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc.mpc.contact import REST_WINDOW_S, RestDetector

MOVING_MPS = 2e-3
FRAME_S = 1 / 30


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_camera_noise_alone_never_breaks_the_rest(scenario, seed):
    sigma = scenario.camera.noise_std_m
    rest = RestDetector(sigma, MOVING_MPS)
    rng = np.random.default_rng(seed)
    for k in range(300):  # ten seconds of frames of a still capsule, noise at the camera's own level
        assert rest.update(k * FRAME_S, rng.normal(0.0, sigma, 2))
    assert rest.rest_s(299 * FRAME_S) == pytest.approx(299 * FRAME_S)


def test_a_capsule_that_moves_off_stops_resting_and_rests_again_once_still(scenario):
    contact = RestDetector(scenario.camera.noise_std_m, MOVING_MPS)
    assert contact.update(0.0, np.zeros(2))
    t, pos = 0.0, np.zeros(2)
    moved_at = None
    for _ in range(20):  # sliding at 20 mm/s
        t += FRAME_S
        pos = pos + np.array([0.02 * FRAME_S, 0.0])
        if not contact.update(t, pos) and moved_at is None:
            moved_at = t
    assert moved_at is not None and moved_at <= 6 * FRAME_S + 1e-9  # seen within 0.2 s at 20 mm/s
    stop = t
    rested_at = None
    while t < stop + 1.0:
        t += FRAME_S
        if contact.update(t, pos):
            rested_at = t
            break
    assert rested_at is not None and rested_at <= stop + REST_WINDOW_S + 2 * FRAME_S
    # The rest counts from the start of the still window, not from when it was recognised.
    assert contact.rest_s(rested_at) >= REST_WINDOW_S - 1e-9


@settings(max_examples=50, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    speed=st.floats(0.0, 0.05),
    frames=st.integers(4, 20),
)
def test_the_rest_speed_is_the_least_squares_line_of_fit_window(seed, speed, frames):
    """The detector's closed-form slope against fit_window's least-squares line on the same frames."""
    from collections import deque

    from capsule_mpc.estimation import fit_window

    rng = np.random.default_rng(seed)
    times = 5.0 + FRAME_S * np.arange(frames) + rng.normal(0.0, 1e-3, frames)
    pos = [np.array([speed * t, 0.5 * speed * t]) + rng.normal(0.0, 3e-4, 2) for t in times]
    rest = RestDetector(3e-4, MOVING_MPS)
    rest._recent = deque(zip(times.tolist(), pos, strict=True))
    fit = fit_window(rest._recent, float(times.max()), 10.0)
    assert fit is not None
    assert rest._speed_mps() == pytest.approx(float(np.linalg.norm(fit.velocity_mps)), rel=1e-9, abs=1e-12)
