"""The compiled arm ticks against Pinocchio, Ruckig and the actuator's Python ticks."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import ruckig
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc.arm import compiled as comp
from capsule_mpc.arm import tick_kernel as tk
from capsule_mpc.arm.kinematics import ArmKinematics
from capsule_mpc.arm.robot_actuator import RobotArmActuator

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@pytest.fixture(scope="module")
def kin(lab_scenario):
    return ArmKinematics(lab_scenario.arm)


@settings(max_examples=30, deadline=None)
@given(q=st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6))
def test_forward_kinematics_and_jacobian_are_pinocchios(kin, q):
    q = np.array(q)
    chain = comp.chain_arrays(kin)
    _, _, r_f, p_f = tk.fk(chain, q)
    placement = kin.epm_placement(q)
    np.testing.assert_allclose(p_f, placement.translation, atol=1e-14)
    np.testing.assert_allclose(r_f, placement.rotation, atol=1e-14)
    jac = pin.computeFrameJacobian(kin.model, kin.data, q, kin.frame_id, LWA)
    np.testing.assert_allclose(tk.jacobian(chain, q), jac, atol=1e-13)


@settings(max_examples=30, deadline=None)
@given(axis=st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3), angle=st.floats(0.0, 0.5))
def test_log3_is_pinocchios(axis, angle):
    axis = np.array(axis)
    if np.linalg.norm(axis) < 1e-3:
        axis = np.array([0.0, 0.0, 1.0])
    rot = pin.exp3(angle * axis / np.linalg.norm(axis))
    np.testing.assert_allclose(tk.log3(rot), pin.log3(rot), atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_the_linear_solve_is_lapacks(seed):
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(6, 6)), rng.normal(size=(6, 2))
    ok, x = tk._lu_solve(a, b)
    assert ok
    np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-9, atol=1e-10)
    assert not tk._lu_solve(np.zeros((6, 6)), b)[0]


@pytest.mark.parametrize("seed", range(4))
def test_sampled_trajectories_are_ruckigs_online_updates(seed):
    rng = np.random.default_rng(seed)
    inp = ruckig.InputParameter(3)
    inp.control_interface = ruckig.ControlInterface.Velocity
    inp.synchronization = ruckig.Synchronization.No
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [0.05] * 3, [0.5] * 3, [5.0] * 3
    inp.current_position = rng.uniform(-0.1, 0.1, 3).tolist()
    inp.current_velocity = rng.uniform(-0.04, 0.04, 3).tolist()
    inp.current_acceleration = rng.uniform(-0.7, 0.7, 3).tolist()  # beyond the limit: a brake phase
    inp.target_velocity = rng.uniform(-0.045, 0.045, 3).tolist()
    trajectory = ruckig.Trajectory(3)
    ruckig.Ruckig(3).calculate(inp, trajectory)
    rows, duration = comp.pack_trajectory(trajectory)
    otg, out, sample, time = ruckig.Ruckig(3, 0.002), ruckig.OutputParameter(3), np.empty((3, 3)), 0.0
    for _ in range(150):
        otg.update(inp, out)
        out.pass_to_input(inp)
        time += 0.002
        tk.sample_profile(rows, duration, time, sample)
        want = np.array([out.new_position, out.new_velocity, out.new_acceleration])
        assert np.array_equal(sample, want)  # bit for bit


def commands(n_frames: int, speed_mps: float, drift_mps: float) -> list[np.ndarray]:
    rng = np.random.default_rng(1)
    wave = [np.array([np.sin(f / 9), np.cos(f / 13), 0.1 * rng.uniform(-1, 1)]) for f in range(n_frames)]
    return [speed_mps * w + np.array([drift_mps, 0.0, 0.0]) for w in wave]


@pytest.mark.parametrize(("servo_hz", "drift"), [(None, 0.0), (6.0, 0.0), (6.0, 0.04)])
def test_compiled_ticks_are_the_python_ticks_on_a_recorded_sequence(lab_scenario, servo_hz, drift):
    """Frames of 33 plant steps with a new command each; the drifting case drives the EPM into
    the workspace box's face, where the guard's ticks run in Python."""
    arms = [RobotArmActuator(lab_scenario, servo_bandwidth_hz=servo_hz) for _ in range(2)]
    for arm in arms:
        arm.reset(np.array([-0.017, 0.0, 0.095]))
    python, compiled = arms
    for f, cmd in enumerate(commands(150, 0.02, drift)):
        for arm in arms:
            arm.set_velocity_command(f * 0.033, cmd)
        want = np.array([python.step_xyz(1e-3) for _ in range(33)])
        got = np.empty((33, 3))
        compiled.advance_xyz(1e-3, got)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert python.limit_counts() == compiled.limit_counts()
    ja, jb = python.joint_trajectory(), compiled.joint_trajectory()
    np.testing.assert_allclose(jb.t_s, ja.t_s, rtol=0, atol=1e-15)
    np.testing.assert_allclose(jb.q_rad, ja.q_rad, rtol=0, atol=1e-10)
    np.testing.assert_allclose(jb.dq_radps, ja.dq_radps, rtol=0, atol=1e-9)
    assert jb.stats.n_points == ja.stats.n_points
    if drift:
        assert python.limit_counts()["workspace_braking_ticks"] > 0
