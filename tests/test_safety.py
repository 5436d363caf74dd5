"""The safety layer (:mod:`capsule_mpc.safety`) under any input: NaN, inf, huge values."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc.safety import SafetyFilter, braking_speed_mps, safe_command

DT = 1 / 30
#: Any float at all: NaN, +-inf, huge and tiny values.
ANY = st.floats(allow_nan=True, allow_infinity=True)
#: An EPM position inside the default workspace.
INSIDE = st.tuples(st.floats(-0.18, 0.18), st.floats(-0.13, 0.13), st.floats(0.085, 0.105))


@settings(max_examples=300, deadline=None)
@given(
    u=st.lists(ANY, min_size=3, max_size=3),
    u_prev=st.lists(ANY, min_size=3, max_size=3),
    pos=st.lists(ANY, min_size=3, max_size=3),
)
def test_the_command_is_finite_and_within_the_speed_limit_whatever_comes_in(scenario, u, u_prev, pos):
    out, _ = safe_command(np.array(u), np.array(u_prev), np.array(pos), scenario, DT)
    assert out.shape == (3,)
    assert np.all(np.isfinite(out))
    assert np.abs(out).max() <= scenario.limits.speed_mps
    assert out[2] == 0.0  # no height control


@settings(max_examples=300, deadline=None)
@given(
    u=st.lists(ANY, min_size=3, max_size=3),
    pos=INSIDE,
    prev=st.lists(st.floats(-1, 1), min_size=3, max_size=3),
)
def test_from_inside_the_braking_envelope_no_jump_and_the_workspace_is_kept(scenario, u, pos, prev):
    lim = scenario.limits
    pos_a = np.array(pos)
    lo, hi = np.asarray(lim.workspace_min_m), np.asarray(lim.workspace_max_m)
    # A previous command the layer could have sent: within the speed limit and the envelope.
    up, down = (
        braking_speed_mps(hi - pos_a, lim.accel_mps2, DT),
        braking_speed_mps(pos_a - lo, lim.accel_mps2, DT),
    )
    u_prev = np.clip(
        np.array(prev) * lim.speed_mps, -np.minimum(down, lim.speed_mps), np.minimum(up, lim.speed_mps)
    )
    u_prev[2] = 0.0
    out, _ = safe_command(np.array(u), u_prev, pos_a, scenario, DT)
    assert np.all(np.abs(out - u_prev) <= lim.accel_mps2 * DT + 1e-12)
    nxt = pos_a + DT * out
    assert np.all(nxt >= lo - 1e-12) and np.all(nxt <= hi + 1e-12)
    # And the next command can be inside the envelope again, within the acceleration limit.
    da = lim.accel_mps2 * DT
    assert np.all(out - da <= braking_speed_mps(hi - nxt, lim.accel_mps2, DT) + 1e-9)
    assert np.all(-out - da <= braking_speed_mps(nxt - lo, lim.accel_mps2, DT) + 1e-9)


def test_full_speed_toward_a_face_brakes_within_the_acceleration_limit_and_stops_on_it(scenario):
    lim = scenario.limits
    pos = np.array([0.0, 0.0, scenario.plate.epm_height_m])
    u = np.zeros(3)
    steps = []
    for _ in range(200):
        out, _ = safe_command(np.array([1e9, 0.0, 0.0]), u, pos, scenario, DT)
        steps.append(abs(out[0] - u[0]))
        pos = pos + DT * out
        u = out
    assert max(steps) <= lim.accel_mps2 * DT + 1e-12
    assert pos[0] <= lim.workspace_max_m[0] + 1e-12
    assert pos[0] == pytest.approx(lim.workspace_max_m[0], abs=2e-3)  # it gets there


def test_a_nan_command_brakes_and_an_unknown_position_brakes(scenario):
    da = scenario.limits.accel_mps2 * DT
    u_prev = np.array([0.05, -0.05, 0.0])
    inside = np.array([0.0, 0.0, 0.095])
    for u, pos in (
        (np.array([math.nan, 0, 0]), inside),
        (np.array([0.05, -0.05, 0]), np.array([math.nan] * 3)),
    ):
        out, clipped = safe_command(u, u_prev, pos, scenario, DT)
        assert clipped
        assert out == pytest.approx([0.05 - da, -0.05 + da, 0.0])


@settings(max_examples=30, deadline=None)
@given(wanted=st.lists(st.tuples(*[st.floats(-0.2, 0.2)] * 3), min_size=1, max_size=40))
def test_the_filter_is_safe_command_chained_and_counts_what_it_clipped(scenario, wanted):
    """Each command is safe_command's given the previous one sent and its slope; the count is the
    commands that differ from what was asked."""
    dt = 1 / 30
    epm = np.array([0.0, 0.0, scenario.plate.epm_height_m])
    filt = SafetyFilter(scenario, dt)
    prev, slope, clipped = np.zeros(3), np.zeros(3), 0
    for u in wanted:
        expected, was = safe_command(np.array(u), prev, epm, scenario, dt, slope)
        cmd, flag = filt.apply(np.array(u), epm)
        np.testing.assert_array_equal(cmd, expected)
        assert flag == was
        slope, prev, clipped = (cmd - prev) / dt, cmd, clipped + int(was)
    assert filt.clipped == clipped
    assert np.array_equal(filt.u_prev, prev) and np.array_equal(filt.slope_prev, slope)


@settings(max_examples=200, deadline=None)
@given(wanted=st.lists(st.tuples(*[st.floats(-1.0, 1.0)] * 2), min_size=3, max_size=80))
def test_away_from_the_faces_a_filtered_stream_never_breaks_the_jerk_limit(scenario, wanted):
    """Whatever is asked (beyond the speed limit too), the commands sent from rest at the workspace's
    centre keep every second difference within the jerk limit: the speed limit is approached with a
    shrinking change, never reached at full acceleration and stopped there."""
    lim = scenario.limits
    epm = np.array([0.0, 0.0, scenario.plate.epm_height_m])
    filt = SafetyFilter(scenario, DT)
    sent = [np.zeros(3), np.zeros(3)]
    for ux, uy in wanted:
        cmd, _ = filt.apply(np.array([ux, uy, 0.0]), epm)  # the EPM held at the centre: no face near
        sent.append(cmd)
    cmd = np.array(sent)
    assert np.abs(cmd).max() <= lim.speed_mps
    assert np.abs(np.diff(cmd, axis=0)).max() <= lim.accel_mps2 * DT + 1e-12
    assert (np.abs(np.diff(cmd, n=2, axis=0)) / DT**2).max() <= lim.jerk_mps3 * (1 + 1e-9)


def test_full_speed_wanted_from_rest_reaches_the_speed_limit(scenario):
    """The jerk-limited approach still gets to the speed limit (it is not held below it)."""
    epm = np.array([0.0, 0.0, scenario.plate.epm_height_m])
    filt = SafetyFilter(scenario, DT)
    for _ in range(300):
        cmd, _ = filt.apply(np.array([1.0, -1.0, 0.0]), epm)
    speed = scenario.limits.speed_mps
    assert cmd[0] == pytest.approx(speed, rel=1e-6) and cmd[1] == pytest.approx(-speed, rel=1e-6)
