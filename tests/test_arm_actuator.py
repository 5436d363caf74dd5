"""The robot arm in the simulated loop: ``sim.actuator: robot`` (Ruckig + Pinocchio, FK to the plant)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from capsule_mpc import Scenario
from capsule_mpc.arm import ArmKinematics, CartesianLimits, RobotArmActuator, UnreachableTargetError
from capsule_mpc.config import config_from_dict
from capsule_mpc.interfaces import make_actuator
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import simulate

PLANT_DT = 1e-3
ARM_DT = 1.0 / 500.0


def robot_scenario(scenario: Scenario, **arm: object) -> Scenario:
    data = scenario.model_dump(mode="json")
    data["sim"]["actuator"] = "robot"
    data["arm"].update(arm)
    return config_from_dict(data)


@pytest.fixture(scope="module")
def robot(scenario: Scenario) -> Scenario:
    return robot_scenario(scenario)


def test_factory_builds_the_robot_arm(robot):
    act = make_actuator(robot)
    assert isinstance(act, RobotArmActuator)


def test_epm_is_the_forward_kinematics_held_between_arm_ticks(robot):
    act = RobotArmActuator(robot)
    start = np.array([0.0, 0.0, 0.095])
    act.reset(start)
    cmd = np.array([0.02, -0.01, 0.0])
    act.set_velocity_command(0.0, cmd)
    kin = ArmKinematics(robot.arm)
    positions = []
    for k in range(1, 2001):
        x = act.step(PLANT_DT)
        positions.append(x)
        if k % 250 == 0:
            np.testing.assert_allclose(x, kin.epm_position(act.q_rad), atol=1e-12)  # FK of the joints
    positions = np.array(positions)
    # Zero-order hold: with a 1 kHz plant and a 500 Hz arm, the position changes every other step.
    moved = np.any(np.diff(positions, axis=0) != 0, axis=1)
    assert not moved[1::2].any() and moved[::2].all()
    np.testing.assert_allclose(act.velocity_mps, cmd, atol=1e-12)  # reached and held
    # Travelled distance: the command from t = 0, minus the jerk-limited ramp's lag.
    lim = CartesianLimits.from_scenario(robot)
    ramp_lag = np.sqrt(np.abs(cmd) / lim.jerk_mps3)  # half the ramp time 2 sqrt(dv / j)
    np.testing.assert_allclose(positions[-1], start + cmd * (2.0 - ramp_lag), atol=1e-6)
    assert act.limit_counts() == {"speed_clipped_frames": 0, "workspace_braking_ticks": 0}


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    commands=st.lists(
        st.tuples(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(-0.03, 0.03)), min_size=1, max_size=15
    )
)
def test_robot_arm_property(robot, commands):
    """Random frame commands: joint commands within limits, setpoints jerk-limited, FK = setpoint."""
    act = RobotArmActuator(robot)
    act.reset(np.array([0.15, 0.1, 0.1]))
    t = 0.0
    for cmd in commands:
        act.set_velocity_command(t, np.array(cmd))
        for _ in range(33):  # one camera frame at 1 kHz
            act.step(PLANT_DT)
            t += PLANT_DT
    cart, joints = act.cartesian_trajectory(), act.joint_trajectory()
    lim = CartesianLimits.from_scenario(robot)
    lo, hi = np.array(robot.limits.workspace_min_m), np.array(robot.limits.workspace_max_m)
    p = cart.position_m
    assert np.all(p >= lo - 1e-12) and np.all(p <= hi + 1e-12)
    assert np.all(np.abs(cart.velocity_mps) <= lim.velocity_mps * (1 + 1e-9))
    assert np.all(np.abs(cart.acceleration_mps2) <= lim.acceleration_mps2 * (1 + 1e-9))
    if len(p) > 3:
        assert np.all(np.abs(np.diff(p, 3, axis=0)) / ARM_DT**3 <= lim.jerk_mps3 * 1.01)
    assert np.abs(joints.epm_position_m - p).max() < 1e-6
    assert np.all(joints.q_rad >= joints.lower_rad) and np.all(joints.q_rad <= joints.upper_rad)
    assert np.all(np.abs(joints.dq_radps) <= joints.velocity_limit_radps)
    np.testing.assert_allclose(np.diff(joints.t_s), ARM_DT, atol=1e-9)


def test_trajectory_times_follow_the_simulator_clock(robot):
    act = RobotArmActuator(robot)
    act.reset(np.array([0.0, 0.0, 0.095]))
    for _ in range(500):  # a settle phase before the first command, as the runner does
        act.step(PLANT_DT)
    act.set_velocity_command(-0.5, np.array([0.01, 0.0, 0.0]))
    for _ in range(500):
        act.step(PLANT_DT)
    t = act.joint_trajectory().t_s
    assert t[0] == pytest.approx(-1.0) and t[-1] == pytest.approx(0.0)


def test_unreachable_in_the_loop_names_time_and_position(scenario):
    # A base far from the plate: the arm cannot reach the workspace.
    far = robot_scenario(scenario, base_xyz_m=[0.0, -1.5, 0.0])
    with pytest.raises(UnreachableTargetError, match=r"EPM position .* at t = 0\.0000 s is not reachable"):
        RobotArmActuator(far)


def test_closed_loop_with_the_robot_arm(robot):
    """A short follow run on the plant: the capsule feels the arm's FK and keeps up."""
    path = ReferencePath(np.array([[0.0, 0.0], [0.02, 0.0]]), False, 0.02)
    act = RobotArmActuator(robot)
    res = simulate(robot, "follow", path, seed=0, actuator=act)
    assert res.flags.completed and not res.flags.decoupled and not res.flags.dropped
    joints = act.joint_trajectory()
    log = res.log
    # The logged EPM positions are the arm's forward kinematics at the latest arm tick (held).
    latest = np.searchsorted(joints.t_s, log["t_s"] + 1e-9, side="right") - 1
    fk_at_log = joints.epm_position_m[latest]
    epm_log = np.column_stack([log["epm_x_m"], log["epm_y_m"], log["epm_z_m"]])
    np.testing.assert_allclose(epm_log, fk_at_log, atol=1e-9)
    assert (
        np.abs(np.diff(joints.epm_position_m, 3, axis=0)).max() / ARM_DT**3 <= robot.limits.jerk_mps3 * 1.01
    )
