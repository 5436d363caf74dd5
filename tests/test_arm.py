"""Arm side: Ruckig smoothing, Pinocchio IK along a plan, the export files and the CLI."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from capsule_mpc import ConfigError, Scenario, dump_config, load_config
from capsule_mpc.arm import (
    ArmError,
    ArmKinematics,
    CartesianLimits,
    EPMTrajectoryError,
    ExportCheckError,
    IKTracker,
    SmoothingError,
    UnreachableTargetError,
    VelocitySmoother,
    check_epm_plan,
    check_workspace,
    default_max_deviation_m,
    export_arm_trajectory,
    joint_figure,
    read_epm_plan_csv,
    read_joint_trajectory_csv,
    read_joint_trajectory_yaml,
    smooth_waypoints,
    solve_trajectory,
    verify_arm_trajectory,
)
from capsule_mpc.arm.export import thin_waypoints
from capsule_mpc.cli import main
from capsule_mpc.config import config_from_dict, packaged_config_path

RATE_HZ = 500.0
DT = 1.0 / RATE_HZ
#: Tolerance of the finite-difference jerk against its limit (1 %).
JERK_TOL = 1.01
#: How close Ruckig lands on a target position, m (its numerical precision).
RUCKIG_PRECISION_M = 1e-8
#: Tolerance of analytic velocities/accelerations against their limits (rounding only).
LIMIT_TOL = 1.0 + 1e-9


def tweak(scenario: Scenario, limits: dict[str, object] | None = None, **arm: object) -> Scenario:
    data = scenario.model_dump(mode="json")
    data["arm"].update(arm)
    data["limits"].update(limits or {})
    return config_from_dict(data)


def rectangle_plan(speed: float, rate_hz: float = 30.0, z: float = 0.095) -> tuple[np.ndarray, np.ndarray]:
    """The 100 x 60 mm rectangle at constant speed sampled at the camera rate (velocity steps at corners)."""
    corners = np.array([[-0.05, -0.03], [0.05, -0.03], [0.05, 0.03], [-0.05, 0.03], [-0.05, -0.03]])
    t_c = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(corners, axis=0), axis=1))] / speed
    t = np.r_[np.arange(0.0, t_c[-1], 1.0 / rate_hz), t_c[-1]]
    xy = np.column_stack([np.interp(t, t_c, corners[:, i]) for i in range(2)])
    return t, np.column_stack([xy, np.full(t.shape, z)])


def assert_within_limits(position: np.ndarray, velocity: np.ndarray, accel: np.ndarray, lim: CartesianLimits):
    """Analytic v and a within the limits; finite differences continuous with jerk <= limit (+1 %)."""
    assert np.all(np.abs(velocity) <= lim.velocity_mps * LIMIT_TOL)
    assert np.all(np.abs(accel) <= lim.acceleration_mps2 * LIMIT_TOL)
    if len(position) > 3:
        jerk = np.diff(position, 3, axis=0) / DT**3
        assert np.all(np.abs(jerk) <= lim.jerk_mps3 * JERK_TOL), np.abs(jerk).max(axis=0)
    # Continuity: no step in position, velocity or acceleration between consecutive setpoints.
    assert np.all(np.abs(np.diff(position, axis=0)) <= lim.velocity_mps * DT * JERK_TOL)
    assert np.all(np.abs(np.diff(velocity, axis=0)) <= lim.acceleration_mps2 * DT * JERK_TOL)
    assert np.all(np.abs(np.diff(accel, axis=0)) <= lim.jerk_mps3 * DT * JERK_TOL)


@pytest.fixture(scope="module")
def limits(scenario: Scenario) -> CartesianLimits:
    return CartesianLimits.from_scenario(scenario)


@pytest.fixture(scope="module")
def kin(scenario: Scenario) -> ArmKinematics:
    return ArmKinematics(scenario.arm)


# --- config ---------------------------------------------------------------------------------------


def test_arm_limits_default_to_the_scenario_limits(scenario, limits):
    lim = scenario.limits
    np.testing.assert_array_equal(limits.velocity_mps, [lim.speed_mps] * 3)
    np.testing.assert_array_equal(limits.acceleration_mps2, [lim.accel_mps2] * 3)
    np.testing.assert_array_equal(limits.jerk_mps3, [lim.jerk_mps3] * 3)
    own = CartesianLimits.from_scenario(tweak(scenario, max_jerk_mps3=[1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(own.jerk_mps3, [1.0, 2.0, 3.0])


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("max_jerk_mps3", [1.0, 2.0, 50.0], r"arm: max_jerk_mps3: every axis must be <= limits\.jerk_mps3"),
        ("max_velocity_mps", [0.05, 0.5, 0.05], r"max_velocity_mps: every axis must be <= limits\.speed_mps"),
        ("max_acceleration_mps2", [0.1, -0.1, 0.1], r"every axis limit must be > 0"),
        ("arm_rate_hz", 20.0, r"arm_rate_hz: must be >= camera\.rate_hz"),
        ("epm_rpy_rad", [0.1, 0.0, 0.0], r"strong face -z toward the plate"),
        ("ik_damping", -1.0, r"arm\.ik_damping: must be >= 0"),
    ],
)
def test_arm_config_errors_name_the_field(scenario, field, value, message):
    with pytest.raises(ConfigError, match=message):
        tweak(scenario, **{field: value})


# --- Ruckig: plan (position interface) ------------------------------------------------------------


@pytest.mark.parametrize("speed", [0.02, 0.045])
def test_plan_smoothing_is_jerk_limited_and_starts_and_ends_at_rest(limits, speed):
    t, p = rectangle_plan(speed)  # velocity steps at the start and at every corner
    cart = smooth_waypoints(t, p, limits, RATE_HZ)
    np.testing.assert_allclose(np.diff(cart.t_s), DT, rtol=0, atol=1e-12)
    assert cart.t_s[0] == t[0]
    assert_within_limits(cart.position_m, cart.velocity_mps, cart.acceleration_mps2, limits)
    np.testing.assert_array_equal(cart.position_m[0], p[0])
    np.testing.assert_allclose(cart.position_m[-1], p[-1], rtol=0, atol=RUCKIG_PRECISION_M)
    np.testing.assert_array_equal(cart.velocity_mps[[0, -1]], 0.0)
    np.testing.assert_array_equal(cart.acceleration_mps2[[0, -1]], 0.0)
    np.testing.assert_allclose(cart.position_m[:, 2], 0.095, atol=1e-12)  # the height is not disturbed
    # The corners cannot be taken at speed: the setpoints round them, but stay near the plan's clock.
    assert cart.stats is not None
    assert cart.stats.max_deviation_m < 0.1 * speed / 0.02 * 0.05  # < 5 mm at 0.02 m/s
    # Stopping from the plan's speed at the end takes 2 sqrt(v / j) at least, plus the look-ahead.
    assert cart.stats.end_lag_s < 0.2 + 2 * math.sqrt(speed / limits.jerk_mps3[0])


def test_feasible_plan_is_reproduced(limits):
    # x(t) = A (1 - cos(2 pi t / T)) / 2: speed, acceleration and jerk far inside the limits.
    t = np.arange(0.0, 10.0 + 1e-9, 1.0 / 30.0)
    amp = 0.05
    x = amp * (1 - np.cos(2 * np.pi * t / 10.0)) / 2
    p = np.column_stack([x, 0.5 * x, np.full(t.shape, 0.095)])
    cart = smooth_waypoints(t, p, limits, RATE_HZ)
    assert cart.stats is not None
    assert cart.stats.max_deviation_m < 1e-5, cart.stats  # the 30 Hz interpolation error is 1.4 um
    assert cart.stats.end_lag_s < 0.05
    v_exact = amp * np.pi / 10.0 * np.sin(2 * np.pi * cart.t_s / 10.0)
    np.testing.assert_allclose(cart.velocity_mps[:, 0], v_exact, atol=5e-4)


waypoint_sequences = st.lists(
    st.tuples(
        st.floats(1 / 30, 0.4),
        st.floats(-0.18, 0.18),
        st.floats(-0.13, 0.13),
        st.floats(0.085, 0.105),
    ),
    min_size=1,
    max_size=12,
)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seq=waypoint_sequences)
# Found by hypothesis: Ruckig ends 6 nm short of the target; snapping onto it broke the jerk limit.
@example(seq=[(0.25, 0.0, 0.0, 0.09375), (0.125, 0.0, 0.0, 0.09375)])
# Found by hypothesis: Ruckig's synchronisation failed on a target a rounding inside two limits.
@example(
    seq=[
        (0.36681529243473904, 0.02424798778709336, 0.023928196501220106, 0.09375),
        (0.1685540630985797, 0.0, 4.328584527607916e-07, 0.09375),
        (0.265625, 0.0, 0.0, 0.09375),
        (0.0625, 0.09608230591248396, 0.015625, 0.09375),
        (0.20293066955766473, -0.17701045722263503, -0.12999999999999998, 0.09375),
        (0.1685540630985797, 0.0, 0.0, 0.09375),
    ]
)
def test_plan_smoothing_property(limits, seq):
    t = np.cumsum([0.0] + [s[0] for s in seq])
    p = np.array([[0.0, 0.0, 0.095]] + [list(s[1:]) for s in seq])
    cart = smooth_waypoints(t, p, limits, RATE_HZ)
    assert_within_limits(cart.position_m, cart.velocity_mps, cart.acceleration_mps2, limits)
    np.testing.assert_allclose(cart.position_m[-1], p[-1], rtol=0, atol=RUCKIG_PRECISION_M)
    assert cart.t_s[-1] >= t[-1]


def test_plan_input_errors_name_the_row(limits):
    t = np.array([0.0, 0.1, 0.1, 0.3])
    p = np.zeros((4, 3))
    with pytest.raises(ValueError, match=r"t_s\[2\]: must be > t_s\[1\]"):
        smooth_waypoints(t, p, limits, RATE_HZ)
    p[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"positions_m\[3\]: must be finite"):
        smooth_waypoints(np.arange(4.0), p, limits, RATE_HZ)
    with pytest.raises(ValueError, match=r"positions_m: must have shape \(4, 3\)"):
        smooth_waypoints(np.arange(4.0), np.zeros((4, 2)), limits, RATE_HZ)
    with pytest.raises(ValueError, match=r"lookahead_s"):
        smooth_waypoints(np.arange(4.0), np.zeros((4, 3)), limits, RATE_HZ, lookahead_s=-1.0)


def test_ruckig_failure_is_a_smoothing_error_with_time_and_position(limits, monkeypatch):
    import ruckig

    def fail(self, inp, traj):
        return ruckig.Result.ErrorInvalidInput

    monkeypatch.setattr(ruckig.Ruckig, "calculate", fail)
    with pytest.raises(SmoothingError, match=r"Ruckig failed at t = 1\.0000 s, EPM target \(\+0\.0100"):
        smooth_waypoints(np.array([0.0, 1.0]), np.array([[0, 0, 0.095], [0.01, 0, 0.095]]), limits, RATE_HZ)


# --- Ruckig: online velocity interface ------------------------------------------------------------


@pytest.mark.parametrize("dv", [0.02, 0.08])
def test_velocity_step_takes_the_jerk_limited_minimum_time(limits, dv):
    sm = VelocitySmoother(limits, RATE_HZ)
    sm.reset(np.array([0.0, 0.0, 0.095]))
    sm.set_target_velocity(np.array([dv, 0.0, 0.0]))
    a, j = limits.acceleration_mps2[0], limits.jerk_mps3[0]
    # Closed form from rest: 2 sqrt(dv / j) if the acceleration limit is not reached, else dv/a + a/j.
    t_min = 2 * math.sqrt(dv / j) if dv <= a * a / j else dv / a + a / j
    ticks = 0
    while sm.step()[1][0] < dv * (1 - 1e-8):  # targets are kept 1e-9 inside the limits
        ticks += 1
        assert ticks < 10 * t_min / DT
    assert abs((ticks + 1) * DT - t_min) <= DT
    np.testing.assert_allclose(sm.velocity_mps, [dv, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(sm.acceleration_mps2, 0.0, atol=1e-12)


def test_velocity_commands_beyond_the_limit_are_clipped_and_counted(limits):
    sm = VelocitySmoother(limits, RATE_HZ)
    used = sm.set_target_velocity(np.array([1.0, -1.0, 0.01]))
    np.testing.assert_allclose(used, [0.08, -0.08, 0.01], rtol=1e-8)
    assert sm.clipped_commands == 1
    with pytest.raises(ValueError, match="velocity_mps: must be 3 finite values"):
        sm.set_target_velocity(np.array([np.nan, 0.0, 0.0]))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    commands=st.lists(
        st.tuples(st.floats(-0.12, 0.12), st.floats(-0.12, 0.12), st.floats(-0.05, 0.05)),
        min_size=1,
        max_size=40,
    )
)
def test_velocity_interface_property(scenario, limits, commands):
    lo, hi = (np.asarray(c) for c in (scenario.limits.workspace_min_m, scenario.limits.workspace_max_m))
    sm = VelocitySmoother(limits, RATE_HZ, (lo, hi))
    sm.reset(np.array([0.17, -0.12, 0.09]))  # near a corner of the box
    p, v, a = [sm.position_m], [sm.velocity_mps], [sm.acceleration_mps2]
    for cmd in commands:  # one command per camera frame, ~17 arm ticks each
        sm.set_target_velocity(np.array(cmd))
        for _ in range(17):
            pi, vi, ai = sm.step()
            p.append(pi)
            v.append(vi)
            a.append(ai)
    p, v, a = np.array(p), np.array(v), np.array(a)
    assert_within_limits(p, v, a, limits)
    assert np.all(p >= lo - 1e-12) and np.all(p <= hi + 1e-12)


def test_workspace_guard_brakes_before_the_face(scenario, limits):
    lo, hi = (np.asarray(c) for c in (scenario.limits.workspace_min_m, scenario.limits.workspace_max_m))
    sm = VelocitySmoother(limits, RATE_HZ, (lo, hi))
    sm.reset(np.array([0.0, 0.0, 0.095]))
    sm.set_target_velocity(np.array([0.08, 0.0, 0.0]))
    xs = [sm.step()[0][0] for _ in range(int(5.0 / DT))]
    assert max(xs) <= hi[0] and xs[-1] > hi[0] - 1e-3  # pressed against the face, not through it
    assert sm.braking_ticks > 0
    with pytest.raises(ValueError, match=r"position_m\[2\]: must lie in the workspace"):
        sm.reset(np.array([0.0, 0.0, 0.2]))


# --- Pinocchio: model and IK ----------------------------------------------------------------------


def test_model_places_the_base_and_the_epm_mount(scenario, kin):
    arm = scenario.arm
    q = np.asarray(arm.q_seed_rad)
    assert kin.joint_names == (
        "shoulder_pan_joint",
        "shoulder_lift_joint",
        "elbow_joint",
        "wrist_1_joint",
        "wrist_2_joint",
        "wrist_3_joint",
    )
    np.testing.assert_allclose(kin.joint_origins(q)[0, :2], arm.base_xyz_m[:2], atol=1e-12)
    pin.forwardKinematics(kin.model, kin.data, q)
    pin.updateFramePlacements(kin.model, kin.data)
    flange = kin.data.oMf[kin.model.getFrameId("tool0")]
    epm = kin.data.oMf[kin.frame_id]
    np.testing.assert_allclose(np.linalg.norm(epm.translation - flange.translation), 0.06, atol=1e-12)
    # The flange axis points along the EPM's -z: at the strong face.
    np.testing.assert_allclose(flange.rotation[:, 2], -epm.rotation[:, 2], atol=1e-12)


def test_default_workspace_is_reachable_with_margin(scenario, kin):
    report = check_workspace(scenario, n_per_axis=4, grow_m=0.03)  # the box grown by 3 cm per side
    assert report.n_points == 64
    assert report.min_joint_margin_rad > 0.3
    assert report.min_singular_value > 0.05  # away from singularities
    assert report.max_joint_speed_radps < 0.25 * kin.velocity_limit_radps.min()
    epm_top = scenario.limits.workspace_max_m[2] + scenario.epm.size_m[2] / 2
    assert report.lowest_wrist_z_m > epm_top  # elbow and wrists pass above the magnet


@pytest.fixture(scope="module")
def plan_joints(limits, kin):
    t, p = rectangle_plan(0.045)
    cart = smooth_waypoints(t, p, limits, RATE_HZ)
    return cart, solve_trajectory(kin, cart.t_s, cart.position_m, cart.velocity_mps)


def test_fk_of_ik_is_the_setpoint_along_a_plan(scenario, plan_joints):
    cart, joints = plan_joints
    fresh = ArmKinematics(scenario.arm)  # an independent model and data for the check
    fk = np.array([fresh.epm_placement(q).translation for q in joints.q_rad])
    assert np.abs(fk - cart.position_m).max() < 1e-6
    np.testing.assert_allclose(joints.epm_position_m, fk, atol=1e-12)
    rot_err = max(np.linalg.norm(pin.log3(fresh.epm_placement(q).rotation)) for q in joints.q_rad[::50])
    assert rot_err < scenario.arm.ik_orientation_tolerance_rad  # the EPM orientation is held
    assert joints.stats.max_position_error_m < 1e-6


def test_joint_velocities_and_limits_along_a_plan(scenario, kin, plan_joints):
    cart, joints = plan_joints
    assert np.all(joints.q_rad >= kin.lower_rad) and np.all(joints.q_rad <= kin.upper_rad)
    assert np.all(np.abs(joints.dq_radps) <= kin.velocity_limit_radps)
    # J dq is the Cartesian velocity with no rotation (dq uses the Jacobian at the warm start,
    # ~1e-7 rad from the solution, so to ~1e-7 relative).
    for k in range(0, len(joints), 97):
        twist = kin.jacobian(joints.q_rad[k]) @ joints.dq_radps[k]
        np.testing.assert_allclose(twist, np.r_[cart.velocity_mps[k], 0, 0, 0], atol=1e-8)
    fd = np.gradient(joints.q_rad, joints.t_s, axis=0)
    assert np.abs(fd - joints.dq_radps)[1:-1].max() < 1e-3
    # Continuity of the joint commands: steps bounded by the joint speeds.
    assert np.abs(np.diff(joints.q_rad, axis=0)).max() <= kin.velocity_limit_radps.max() * DT


def test_unreachable_point_is_a_clear_error_before_anything_is_written(scenario, tmp_path):
    t = np.array([0.0, 10.0])
    p = np.array([[0.0, 0.0, 0.095], [0.0, 0.8, 0.095]])  # 1.25 m from the base: beyond the UR5's reach
    out = tmp_path / "out"
    wide = tweak(scenario, limits={"workspace_max_m": [0.18, 0.9, 0.105]})  # else refused as outside
    with pytest.raises(
        UnreachableTargetError, match=r"EPM position \(\+0\.0000, \+0\.\d+, \+0\.0950\) m at t = "
    ) as e:
        export_arm_trajectory(wide, t, p, out)
    assert 0.0 < e.value.t_s < 10.0 and 0.3 < e.value.position_m[1] < 0.8
    assert "not reachable" in str(e.value) and "No joint command was sent" in str(e.value)
    assert not out.exists()


def test_joint_position_limit_is_a_clear_error(scenario):
    # With a 0.5 rad margin the elbow may not bend beyond pi - 0.5 = 2.64 rad; moving the EPM toward
    # the base needs more (2.66 rad at y = -0.2 m).
    kin = ArmKinematics(tweak(scenario, joint_position_margin_rad=0.5).arm)
    t = np.linspace(0.0, 4.0, 2001)
    p = np.column_stack([np.zeros_like(t), -0.05 * t, np.full_like(t, 0.095)])
    v = np.tile([0.0, -0.05, 0.0], (len(t), 1))
    with pytest.raises(UnreachableTargetError, match=r"joint 3 \(elbow_joint\) would be at \+2\.64") as e:
        solve_trajectory(kin, t, p, v)
    assert -0.2 < e.value.position_m[1] < -0.15


def test_joint_velocity_limit_is_a_clear_error(scenario, limits):
    kin = ArmKinematics(tweak(scenario, joint_velocity_fraction=0.01).arm)  # ~0.03 rad/s allowed
    t, p = rectangle_plan(0.045)
    cart = smooth_waypoints(t[:20], p[:20], limits, RATE_HZ)
    with pytest.raises(UnreachableTargetError, match=r"would move at .* rad/s, beyond its allowed 0\.03"):
        solve_trajectory(kin, cart.t_s, cart.position_m, cart.velocity_mps)


def test_batch_and_sequential_ik_agree(kin, plan_joints, monkeypatch):
    cart, joints = plan_joints  # batch (the default)
    args = (kin, cart.t_s[:1500], cart.position_m[:1500], cart.velocity_mps[:1500])
    seq = solve_trajectory(*args, method="sequential")
    np.testing.assert_allclose(seq.q_rad, joints.q_rad[:1500], atol=1e-8)
    np.testing.assert_allclose(seq.dq_radps, joints.dq_radps[:1500], atol=1e-6)
    # A poor interpolated guess (coarse points 1 s apart, one batched Newton step) falls back to
    # solving from the previous point, with the same result.
    monkeypatch.setattr("capsule_mpc.arm.kinematics._COARSE_STEP", 500)
    monkeypatch.setattr("capsule_mpc.arm.kinematics._BATCH_STEPS", 1)
    fallback = solve_trajectory(*args)
    np.testing.assert_allclose(fallback.q_rad, joints.q_rad[:1500], atol=1e-8)
    assert fallback.stats.max_position_error_m <= kin.config.ik_position_tolerance_m
    with pytest.raises(ValueError, match="method: must be 'batch' or 'sequential'"):
        solve_trajectory(*args, method="other")  # type: ignore[arg-type]


def test_tracker_recovers_from_a_poor_warm_start(kin):
    tracker = IKTracker(kin)
    tracker.reset(0.0, np.array([0.0, 0.0, 0.095]))
    # A jump of 5 mm in one tick: the extrapolated guess is far off, more DLS steps are needed.
    q, _ = tracker.track(DT, np.array([0.005, 0.0, 0.095]), np.zeros(3))
    assert tracker.stats.max_iterations > 1
    np.testing.assert_allclose(kin.epm_position(q), [0.005, 0.0, 0.095], atol=1e-9)


# --- export and CLI --------------------------------------------------------------------------------


def test_export_files_yaml_matches_csv(scenario, tmp_path):
    t, p = rectangle_plan(0.02)
    keep = t <= 1.5
    res = export_arm_trajectory(scenario, t[keep], p[keep], tmp_path, plot=True)
    assert set(res.paths) == {"epm_csv", "joint_csv", "joint_yaml", "summary", "joint_png"}
    assert all(path.stat().st_size > 0 for path in res.paths.values())
    csv = read_joint_trajectory_csv(res.paths["joint_csv"])
    msg = read_joint_trajectory_yaml(res.paths["joint_yaml"])
    assert msg["joint_names"] == list(res.joints.joint_names)
    assert set(msg) == {"header", "joint_names", "points"}
    assert len(msg["points"]) == len(csv["t_s"]) == len(res.joints)
    positions = np.array([pt["positions"] for pt in msg["points"]])
    velocities = np.array([pt["velocities"] for pt in msg["points"]])
    np.testing.assert_array_equal(positions, csv["q_rad"])  # exactly the same numbers
    np.testing.assert_array_equal(velocities, csv["dq_radps"])
    np.testing.assert_array_equal(csv["q_rad"], res.joints.q_rad)
    times = np.array(
        [pt["time_from_start"]["sec"] + 1e-9 * pt["time_from_start"]["nanosec"] for pt in msg["points"]]
    )
    np.testing.assert_allclose(times, csv["t_s"] - csv["t_s"][0], atol=1e-9)
    assert all(0 <= pt["time_from_start"]["nanosec"] < 1_000_000_000 for pt in msg["points"])
    epm = np.loadtxt(res.paths["epm_csv"], delimiter=",", skiprows=1)
    np.testing.assert_array_equal(epm[:, 1:4], res.cartesian.position_m)
    np.testing.assert_array_equal(epm[:, 0], csv["t_s"])
    assert res.summary["max_fk_error_m"] < 1e-6
    assert max(res.summary["max_fd_jerk_mps3"]) <= scenario.limits.jerk_mps3 * JERK_TOL


def test_plan_csv_reader_variants_and_errors(tmp_path):
    f = tmp_path / "plan.csv"
    f.write_text("t_s,epm_x_m,epm_y_m,epm_vx_mps\n0,0.0,0.0,0\n0.5,0.01,0.0,0\n")
    t, p = read_epm_plan_csv(f, default_height_m=0.09)
    np.testing.assert_array_equal(p[:, 2], 0.09)
    np.testing.assert_array_equal(t, [0.0, 0.5])
    with pytest.raises(ValueError, match="no z column"):
        read_epm_plan_csv(f)
    f.write_text("t_s,epm_x_m,epm_y_m,epm_z_m\n0,0.0,0.0,0.095\n\n0.5,abc,0.0,0.095\n")
    with pytest.raises(
        ValueError, match=r"plan\.csv: data row 2 \(line 4\), epm_x_m: not a number, got 'abc'"
    ):
        read_epm_plan_csv(f)
    f.write_text("\ufeffx_m,y_m,z_m,t\n0,0,0.09,0\n0.001,0,0.09,0.5\n")  # byte-order mark, other names
    t, p = read_epm_plan_csv(f)
    np.testing.assert_array_equal(p[1], [0.001, 0.0, 0.09])
    f.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff")
    with pytest.raises(ValueError, match=r"plan\.csv: not a UTF-8 text CSV"):
        read_epm_plan_csv(f)
    f.write_text("time,a,b\n0,1,2\n")
    with pytest.raises(ValueError, match="needs a time column"):
        read_epm_plan_csv(f)


def test_thin_waypoints_keeps_ends_and_spacing():
    t = np.arange(0.0, 1.0005, 0.001)
    keep = thin_waypoints(t, 30.0)
    assert keep[0] == 0 and keep[-1] == len(t) - 1
    assert np.all(np.diff(t[keep])[:-1] >= 1 / 30 - 1e-9)
    assert len(keep) == 31


def test_cli_arm_export(tmp_path, capsys):
    t, p = rectangle_plan(0.02)
    keep = t <= 1.0
    plan = tmp_path / "epm_plan.csv"
    np.savetxt(
        plan,
        np.column_stack([t[keep], p[keep]]),
        delimiter=",",
        header="t_s,epm_x_m,epm_y_m,epm_z_m",
        comments="",
    )
    (tmp_path / "config.yaml").write_text(dump_config(load_config()))  # as plan and simulate leave it
    assert main(["arm-export", "--plan", str(plan), "--out", str(tmp_path / "o"), "--no-plot"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"config: {tmp_path / 'config.yaml'} (the config beside the plan)\n")
    assert "worst finite-difference jerk" in out and "IK: worst EPM position error" in out
    assert (tmp_path / "o" / "joint_trajectory.yaml").exists()
    assert not (tmp_path / "o" / "joint_trajectory.png").exists()
    far = tmp_path / "far.csv"
    far.write_text("t_s,epm_x_m,epm_y_m,epm_z_m\n0,0,0,0.095\n15,0,0.9,0.095\n")
    paper = str(packaged_config_path("paper"))
    assert main(["arm-export", "--plan", str(far), "--out", str(tmp_path / "far"), "--config", paper]) == 2
    err = capsys.readouterr().err
    assert "far.csv: data row 2 (t_s = 15), epm_y_m: must be in the EPM workspace [-0.13, 0.13] m" in err
    assert not (tmp_path / "far").exists()


# --- checks of the plan and of the exported trajectory ----------------------------------------------


@pytest.mark.parametrize("speed", [0.02, 0.045])
def test_plans_the_arm_rounds_within_the_tolerance_pass_the_row_checks(scenario, speed):
    # Velocity steps at the start and at every corner: beyond the acceleration limit exactly, but
    # within it given the tolerance (the smoothing's deviation: 1.2 / 4.1 mm).
    t, p = rectangle_plan(speed)
    check_epm_plan(scenario, t, p, default_max_deviation_m(scenario))
    assert default_max_deviation_m(scenario) == pytest.approx(0.2 * scenario.limits.max_lead_m)


def test_summary_stores_the_configured_arm_rate(scenario, tmp_path):
    t, p = rectangle_plan(0.02)
    keep = t <= 0.5
    for rate in (500.0, 300.0):
        res = export_arm_trajectory(tweak(scenario, arm_rate_hz=rate), t[keep], p[keep], tmp_path, plot=False)
        assert res.summary["arm_rate_hz"] == rate  # not 1 / median(diff(t)) = 499.99999999999955
        assert json.loads(res.paths["summary"].read_text())["arm_rate_hz"] == rate
        check = res.summary["check"]
        assert check["tolerance_m"] == pytest.approx(0.005)
        assert check["max_deviation_m"] < check["tolerance_m"]
        assert check["max_fk_error_m"] <= scenario.arm.ik_position_tolerance_m


def test_a_deviation_beyond_the_tolerance_is_refused_even_past_the_row_checks(
    scenario, tmp_path, monkeypatch
):
    # A 5 cm step between two rows: the row check refuses it; without that check, the
    # check of the result still does (a 49 mm deviation), and nothing is written.
    t, p = rectangle_plan(0.02)
    keep = t <= 2.0
    t, p = t[keep], p[keep].copy()
    p[30:, 0] += 0.05
    with pytest.raises(
        EPMTrajectoryError, match=r"data row 31 \(t_s = 1\), epm_x_m: moves \+50\.67 mm from data row 30"
    ):
        export_arm_trajectory(scenario, t, p, tmp_path / "a")
    monkeypatch.setattr("capsule_mpc.arm.export.check_epm_plan", lambda *args: None)
    with pytest.raises(ExportCheckError, match=r"between data rows 30 and 31 .* and up to 4\d\.\d\d mm") as e:
        export_arm_trajectory(scenario, t, p, tmp_path / "b")
    assert "the tolerance is 5.00 mm" in str(e.value) and isinstance(e.value, ArmError)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


@pytest.fixture(scope="module")
def short_export(scenario, limits, kin):
    t, p = rectangle_plan(0.02)
    keep = t <= 1.0
    cart = smooth_waypoints(t[keep], p[keep], limits, RATE_HZ)
    return t[keep], p[keep], cart, solve_trajectory(kin, cart.t_s, cart.position_m, cart.velocity_mps)


@pytest.mark.parametrize(
    ("corrupt", "message"),
    [
        ("fk", r"forward kinematics of the joint positions is 0\.001 m from the setpoint"),
        ("joint_limit", r"joint 6 \(wrist_3_joint\) would be at -6\.\d+ rad, outside its limits"),
        ("joint_speed", r"joint 1 \(shoulder_pan_joint\) would move at \+3\.0000 rad/s"),
        ("setpoint_speed", r"setpoint velocity .* beyond the per-axis limit"),
        ("workspace", r"the EPM would be 5\.000 mm outside the workspace"),
        ("nan", r"not finite"),
    ],
)
def test_the_result_is_verified_before_it_is_written(scenario, kin, short_export, corrupt, message):
    t_plan, p_plan, cart, joints = short_export
    q, dq = joints.q_rad.copy(), joints.dq_radps.copy()
    cart_pos, cart_vel = cart.position_m.copy(), cart.velocity_mps.copy()
    k = 200
    if corrupt == "fk":  # the setpoint moved 1 mm, the joints not
        cart_pos[k, 0] += 0.001
    elif corrupt == "joint_limit":  # the same pose a turn of the wrist away: beyond its limit
        q[k, 5] -= 2 * np.pi
    elif corrupt == "joint_speed":
        dq[k, 0] = 3.0
    elif corrupt == "setpoint_speed":
        cart_vel[k, 1] = 0.2
    elif corrupt == "workspace":  # the floor raised 5 mm above the trajectory (z = 0.095 m)
        # A config cannot put the EPM's height outside its workspace (validated on load), so the
        # raised floor is set on a copy without validation: only the output check is under test.
        limits = scenario.limits.model_copy(update={"workspace_min_m": (-0.18, -0.13, 0.1)})
        tweaked = scenario.model_copy(update={"limits": limits})
        with pytest.raises(ExportCheckError, match=message):
            verify_arm_trajectory(tweaked, kin, t_plan, p_plan, cart, joints, 0.005)
        return
    else:
        q[k, 2] = np.nan
    bad_cart = dataclasses.replace(cart, position_m=cart_pos, velocity_mps=cart_vel)
    bad_joints = dataclasses.replace(joints, q_rad=q, dq_radps=dq)
    with pytest.raises(ExportCheckError, match=message) as e:
        verify_arm_trajectory(scenario, kin, t_plan, p_plan, bad_cart, bad_joints, 0.005)
    assert e.value.t_s == pytest.approx(cart.t_s[k])
    verify_arm_trajectory(scenario, kin, t_plan, p_plan, cart, joints, 0.005)  # the original passes


def test_a_failed_write_leaves_no_files(scenario, tmp_path, monkeypatch):
    def broken_plot(joints, path):
        raise OSError(f"{path}: disk full")

    monkeypatch.setattr("capsule_mpc.arm.export.plot_joint_trajectory", broken_plot)
    t, p = rectangle_plan(0.02)
    keep = t <= 0.5
    out = tmp_path / "out"
    with pytest.raises(OSError, match="disk full"):
        export_arm_trajectory(scenario, t[keep], p[keep], out)
    assert not out.exists()


def test_joint_figure_shows_every_limit_with_units(scenario, plan_joints):
    _, joints = plan_joints
    fig = joint_figure(joints)
    axes = np.array(fig.axes).reshape(-1, 2)
    for j, (ax_q, ax_dq) in enumerate(axes):
        assert ax_q.get_ylabel() == f"q{j + 1} (rad)" and ax_dq.get_ylabel() == f"dq{j + 1} (rad/s)"
        v_rated, v_allowed = joints.rated_velocity_radps[j], joints.velocity_limit_radps[j]
        panels = (
            (
                ax_q,
                (
                    joints.rated_lower_rad[j],
                    joints.rated_upper_rad[j],
                    joints.lower_rad[j],
                    joints.upper_rad[j],
                ),
            ),
            (ax_dq, (-v_rated, v_rated, -v_allowed, v_allowed)),
        )
        for ax, limits in panels:
            lo, hi = ax.get_ylim()
            drawn = {round(float(line.get_ydata()[0]), 9) for line in ax.lines[1:]}
            notes = " ".join(text.get_text() for text in ax.texts)
            for value in limits:
                if lo <= value <= hi:
                    assert round(float(value), 9) in drawn  # in view: drawn as a red line
                else:
                    assert f"{value:+.2f}" in notes and "off-scale" in notes  # else named at the edge
    assert "named at the panel edge" in fig._suptitle.get_text()


def test_a_step_longer_than_ruckig_can_plan_names_the_rows_and_the_reason(scenario):
    """Ruckig returns a code its Python binding cannot name (-101, "is not a valid Result"): the error
    names the plan rows of the step and says what the code means."""
    limits = CartesianLimits.from_scenario(scenario)
    t = np.array([0.0, 8000.0, 16000.0])
    p = np.array([[0.0, 0.0, 0.095], [0.01, 0.0, 0.095], [0.02, 0.0, 0.095]])
    with pytest.raises(SmoothingError) as exc:
        smooth_waypoints(t, p, limits, 10.0, rows=np.array([1, 5, 9]))
    assert str(exc.value) == (
        "Ruckig failed at t = 8000.0000 s, EPM target (+0.0100, +0.0000, +0.0950) m: cannot plan the motion "
        "from data row 1 to data row 5 (8000 s at least): Ruckig reports a motion that would last longer "
        "than its numerical limit (about 7600 s) (result -101)"
    )
