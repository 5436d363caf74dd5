"""The simple arm's servo lag (``servo_bandwidth_hz``): first-order tracking within the limits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc import Scenario
from capsule_mpc.sim.actuation import SimpleArm

DT = 1e-3  # the plant step, s (sim.plant_rate_hz = 1000)
START = np.array([0.0, 0.0, 0.095])  # mid-workspace, m


class OldSimpleArm:
    """The simple arm's step without a servo, written out independently: the bit-for-bit reference."""

    def __init__(self, scenario: Scenario, start: np.ndarray) -> None:
        lim = scenario.limits
        self.accel, self.vmax = float(lim.accel_mps2), float(lim.speed_mps)
        self.lo, self.hi = [float(v) for v in lim.workspace_min_m], [float(v) for v in lim.workspace_max_m]
        self.pos, self.vel, self.cmd = [float(v) for v in start], [0.0] * 3, [0.0] * 3

    def command(self, v: np.ndarray) -> None:
        self.cmd = [min(max(float(c), -self.vmax), self.vmax) for c in v]

    def step(self, dt_s: float) -> tuple[float, ...]:
        dv_max = self.accel * dt_s
        for i in range(3):
            dv = min(max(self.cmd[i] - self.vel[i], -dv_max), dv_max)
            v = self.vel[i] + dv
            p = self.pos[i] + v * dt_s
            if p < self.lo[i] or p > self.hi[i]:
                p, v = (self.lo[i] if p < self.lo[i] else self.hi[i]), 0.0
            self.vel[i], self.pos[i] = v, p
        return tuple(self.pos)


def velocities(arm: SimpleArm, n: int) -> np.ndarray:
    """The arm's velocity (n, 3), m/s, after each of n plant steps."""
    out = []
    for _ in range(n):
        arm.step_xyz(DT)
        out.append(arm.velocity_mps)
    return np.array(out)


def test_step_response_is_first_order(scenario):
    # 2 Hz: tau = 79.6 ms. A 20 mm/s step then needs at most 20 mm/s / tau = 0.25 m/s^2, half the
    # acceleration limit (0.5 m/s^2), so the limit never binds and the response is the filter's.
    f, cmd = 2.0, np.array([0.02, -0.01, 0.0])
    arm = SimpleArm(scenario, servo_bandwidth_hz=f)
    tau = arm.servo_time_constant_s
    assert tau == pytest.approx(1 / (2 * math.pi * f))
    arm.reset(START)
    arm.set_velocity_command(0.0, cmd)
    v = velocities(arm, 1000)
    assert arm.limit_counts()["accel_limited_steps"] == 0
    t = DT * np.arange(1, 1001)
    np.testing.assert_allclose(v, np.outer(1 - np.exp(-t / tau), cmd), rtol=1e-9, atol=1e-15)
    k63 = int(np.argmax(v[:, 0] >= (1 - math.exp(-1)) * cmd[0]))  # first step at 63 %
    assert abs(t[k63] - tau) <= DT
    assert np.all(np.diff(v[:, 0]) > 0)  # monotone, no overshoot
    # reset() puts the filter at rest again: the same response from the start.
    arm.reset(START)
    arm.set_velocity_command(0.0, cmd)
    arm.step_xyz(DT)
    np.testing.assert_allclose(arm.velocity_mps, v[0], rtol=1e-15)


def test_fast_servo_is_still_acceleration_limited(scenario):
    arm = SimpleArm(scenario, servo_bandwidth_hz=50.0)  # tau = 3.2 ms: 0.08 m/s needs 25 m/s^2
    arm.reset(START)
    arm.set_velocity_command(0.0, np.array([0.08, 0.0, 0.0]))
    v = velocities(arm, 400)[:, 0]
    assert np.max(np.diff([0.0, *v])) <= scenario.limits.accel_mps2 * DT * (1 + 1e-12)
    assert arm.limit_counts()["accel_limited_steps"] > 0
    assert v[-1] == pytest.approx(0.08, rel=1e-9)


def test_no_bandwidth_reproduces_the_old_arm_bit_for_bit(scenario):
    rng = np.random.default_rng(0)
    arm, old = SimpleArm(scenario, servo_bandwidth_hz=None), OldSimpleArm(scenario, START)
    arm.reset(START)
    for k in range(4000):
        if k % 33 == 0:  # a new command every camera frame, often beyond the limits
            cmd = rng.uniform(-0.2, 0.2, 3)
            arm.set_velocity_command(k * DT, cmd)
            old.command(cmd)
        assert arm.step_xyz(DT) == old.step(DT)
        assert arm.velocity_mps.tolist() == old.vel
    assert arm.limit_counts()["workspace_clamped_steps"] > 0  # the clamp was exercised too


@settings(max_examples=40, deadline=None)
@given(
    st.one_of(st.none(), st.floats(0.05, 500.0)),
    st.lists(st.tuples(*[st.floats(-0.3, 0.3)] * 3), min_size=1, max_size=6),
)
def test_limits_hold_for_any_bandwidth_and_commands(scenario, bandwidth_hz, commands):
    lim = scenario.limits
    lo, hi = np.array(lim.workspace_min_m), np.array(lim.workspace_max_m)
    arm = SimpleArm(scenario, servo_bandwidth_hz=bandwidth_hz)
    arm.reset(np.array([0.17, -0.12, 0.1]))  # near a corner, so the clamp is met
    prev_v = arm.velocity_mps
    for cmd in commands:
        arm.set_velocity_command(0.0, np.array(cmd))
        for _ in range(60):
            pos = np.array(arm.step_xyz(DT))
            v = arm.velocity_mps
            assert np.all(np.abs(v) <= lim.speed_mps + 1e-15)
            assert np.all(pos >= lo) and np.all(pos <= hi)
            # The workspace clamp stops an axis at its face (v = 0): the one change beyond accel * dt.
            clamped = (pos == lo) | (pos == hi)
            assert np.all((np.abs(v - prev_v) <= lim.accel_mps2 * DT + 1e-15) | clamped)
            prev_v = v


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_bad_bandwidth_is_rejected(scenario, bad):
    with pytest.raises(ValueError, match=r"servo_bandwidth_hz: must be a finite value > 0 or None"):
        SimpleArm(scenario, servo_bandwidth_hz=bad)
