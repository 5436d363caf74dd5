"""The UR5 backend's contract, against a fake robot behind fakes of ur-rtde's interfaces
(tests/fake_rtde.py): the rate, the pre-flight, servoJ streaming of the arm stack's setpoints, the
watchdog, the stops, the calibration file, and a closed loop run to its end."""

from __future__ import annotations

import inspect
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from capsule_mpc import Scenario, load_config
from capsule_mpc.arm import ArmKinematics
from capsule_mpc.arm.calibration import (
    UR5Calibration,
    apply_calibration,
    calibration_of,
    load_calibration,
    write_calibration,
)
from capsule_mpc.arm.ur5_rtde import (
    UR5DependencyError,
    UR5Error,
    UR5RtdeActuator,
    UR5Settings,
    rtde_factories,
)
from capsule_mpc.errors import ConfigError
from capsule_mpc.paths import rectangle
from capsule_mpc.sim.loop import ClosedLoop
from fake_rtde import FakeControl, FakeReceive, FakeRobot

#: A documentation address (RFC 5737): nothing is ever contacted.
HOST = "192.0.2.10"
QUICK = Path(__file__).resolve().parent / "data" / "rectangle_quick.yaml"
PLANT_DT = 1e-3
FRAME_S = 1.0 / 30.0


def _start(scenario: Scenario) -> np.ndarray:
    return np.array([0.0, 0.0, scenario.plate.epm_height_m])


def _q_at(scenario: Scenario, position_m: np.ndarray) -> np.ndarray:
    kin = ArmKinematics(scenario.arm)
    return kin.solve(np.asarray(position_m, dtype=float), np.array(scenario.arm.q_seed_rad), 300).q


def _robot(scenario: Scenario, **kw) -> FakeRobot:
    """A robot parked 6 cm above the start (the slow move brings it down)."""
    return FakeRobot(_q_at(scenario, _start(scenario) + np.array([0.01, -0.01, 0.06])), **kw)


def _connect(scenario: Scenario, robot: FakeRobot, *, calibration=None, **kw) -> UR5RtdeActuator:
    return UR5RtdeActuator(
        scenario,
        UR5Settings(host=HOST, **kw),
        calibration=calibration,
        control_factory=robot.control_factory,
        receive_factory=robot.receive_factory,
    )


def _drive(act: UR5RtdeActuator, velocity_mps, duration_s: float, t0: float = 0.0) -> float:
    """Send ``velocity_mps`` once per camera frame (None: send nothing) and step the plant clock."""
    n = round(duration_s / PLANT_DT)
    per_frame = round(FRAME_S / PLANT_DT)
    for k in range(n):
        if velocity_mps is not None and k % per_frame == 0:
            act.set_velocity_command(t0 + k * PLANT_DT, np.asarray(velocity_mps, dtype=float))
        act.step_xyz(PLANT_DT)
    return t0 + n * PLANT_DT


def _servo_targets(robot: FakeRobot) -> np.ndarray:
    return np.array([c.args[0] for c in robot.named("servoJ")])


@pytest.fixture(scope="module")
def armed(scenario):
    """A 500 Hz robot driven for 1.5 s (a move, then zero commands) after its pre-flight."""
    robot = _robot(scenario)
    act = _connect(scenario, robot)
    act.reset(_start(scenario))
    t = _drive(act, (0.03, -0.02, 0.005), 1.0)
    _drive(act, (0.0, 0.0, 0.0), 0.5, t)
    return act, robot


# -- streaming --------------------------------------------------------------------------------


def test_a_slow_movej_to_the_start_comes_before_any_servoj(armed, scenario):
    act, robot = armed
    names = robot.names()
    assert names.count("moveJ") == 1 and names.index("moveJ") < names.index("servoJ")
    (move,) = robot.named("moveJ")
    q, speed, acceleration, asynchronous = move.args
    np.testing.assert_allclose(q, act.joint_trajectory().q_rad[0], atol=1e-12)  # the start's IK
    assert (speed, acceleration, asynchronous) == (0.2, 0.4, False)
    assert robot.named("RTDEControlInterface")[0].args == (HOST, -1.0)
    assert robot.named("RTDEReceiveInterface")[0].args == (HOST, -1.0)


def test_servoj_streams_the_stack_setpoints_once_per_rtde_period(armed):
    act, robot = armed
    paced = [
        n
        for n in robot.names()[robot.names().index("moveJ") :]
        if n in ("initPeriod", "servoJ", "waitPeriod")
    ]
    n = paced.count("servoJ")
    assert n == round(1.5 * 500) and paced == ["initPeriod", "servoJ", "waitPeriod"] * n
    for call in robot.named("servoJ"):
        assert call.args[1:] == (0.0, 0.0, 1.0 / 500.0, 0.1, 300.0)  # unused speed/accel, dt, lookahead, gain
    # exactly what the arm stack computed and checked, tick by tick, one period of robot time each
    np.testing.assert_array_equal(_servo_targets(robot), act.joint_trajectory().q_rad[1:])
    times = np.array([c.robot_s for c in robot.named("servoJ")])
    np.testing.assert_allclose(np.diff(times), 1.0 / 500.0, rtol=1e-9)


def test_consecutive_targets_stay_within_the_joint_limits_speeds_and_accelerations(armed):
    act, robot = armed
    q = _servo_targets(robot)
    kin, dt = act.kin, act.tick_s
    assert np.all(q >= kin.lower_rad) and np.all(q <= kin.upper_rad)
    assert np.all(np.abs(np.diff(q, axis=0)) / dt <= kin.velocity_limit_radps)
    accel = np.abs(np.diff(q, n=2, axis=0)) / dt**2
    assert accel.max() <= act.settings.max_joint_acceleration_radps2
    assert np.abs(np.diff(q, axis=0)).max() > 1e-5  # it did move


def test_the_measured_epm_follows_the_commands(armed, scenario):
    act, _robot = armed
    assert act.stopped is None and act.events[-1].kind == "armed"
    moved = act.position_m - _start(scenario)
    np.testing.assert_allclose(moved, [0.03, -0.02, 0.005], atol=0.002)  # ~1 s at the commanded speed
    np.testing.assert_allclose(act.position_m, act.cartesian_trajectory().position_m[-1], atol=1e-4)
    counts = act.limit_counts()
    assert all(counts[f"ur5_{k}"] == 0 for k in ("watchdog", "limit", "pose_mismatch", "protective_stop"))


def test_waitperiod_paces_the_stream_to_the_wall_clock(scenario):
    robot = _robot(scenario, realtime=True)
    act = _connect(scenario, robot)
    act.reset(_start(scenario))
    _drive(act, (0.01, 0.0, 0.0), 0.4)
    starts = np.array([c.wall_s for c in robot.named("initPeriod")])
    assert len(starts) == len(robot.named("servoJ")) == 200
    # a period never starts before the previous one is over (a loaded machine may start it late)
    assert np.diff(starts).min() >= 0.002 - 1e-6
    assert np.median(np.diff(starts)) < 0.002 * 3


# -- the rate ---------------------------------------------------------------------------------


@pytest.mark.parametrize("reports_step_time", [True, False], ids=["step_time", "timestamps"])
@pytest.mark.parametrize("rate", [500.0, 125.0], ids=["e-series", "cb3"])
def test_the_rtde_rate_is_detected_and_the_stack_runs_at_it(scenario, rate, reports_step_time):
    robot = _robot(scenario, rate_hz=rate, reports_step_time=reports_step_time)
    act = _connect(scenario, robot)
    assert act.rate_hz == rate and act.tick_s == 1.0 / rate
    assert act.scenario.arm.arm_rate_hz == rate and act.arm.tick_s == 1.0 / rate
    assert ("getTimestamp" in robot.names()) is not reports_step_time
    act.reset(_start(scenario))
    _drive(act, (0.01, 0.0, 0.0), 0.2)
    calls = robot.named("servoJ")
    assert len(calls) == round(0.2 * rate) and all(c.args[3] == 1.0 / rate for c in calls)


def test_a_rate_neither_500_nor_125_hz_is_refused_and_disconnected(scenario):
    robot = _robot(scenario, rate_hz=250.0)
    with pytest.raises(UR5Error, match=r"250\.0 Hz .* neither 500 Hz \(e-Series\) nor 125 Hz \(CB3\)"):
        _connect(scenario, robot)
    assert [c.iface for c in robot.named("disconnect")] == ["control", "receive"]


def test_a_required_rate_the_robot_does_not_have_is_refused(scenario):
    robot = _robot(scenario, rate_hz=125.0)
    with pytest.raises(
        UR5Error, match=r"rtde_rate_hz: the robot streams at 125 Hz, the settings require 500"
    ):
        _connect(scenario, robot, rtde_rate_hz=500)
    assert robot.named("RTDEControlInterface")[0].args == (HOST, 500.0)


# -- the watchdog -----------------------------------------------------------------------------


def test_the_watchdog_brakes_within_the_limits_then_stops_and_refuses_motion(scenario):
    robot = _robot(scenario)
    act = _connect(scenario, robot)
    act.reset(_start(scenario))
    t = _drive(act, (0.04, 0.0, 0.0), 0.6)
    n_commanded = len(robot.named("servoJ"))
    _drive(act, None, 1.5, t)  # the controller went silent
    kinds = [e.kind for e in act.events]
    assert kinds.count("watchdog") == 1 and kinds[-1] == "stopped" and act.stopped == "watchdog"
    watchdog = next(e for e in act.events if e.kind == "watchdog")
    last_command_s = (599 // 33) * 33 * PLANT_DT  # the last frame's command before the silence
    assert last_command_s + 0.25 < watchdog.t_s <= last_command_s + 0.25 + 3 * act.tick_s
    # braked by the arm stack: acceleration and jerk within the Ruckig limits, to rest
    cart = act.cartesian_trajectory()
    limits = act.arm.smoother.limits
    acc, jerk = limits.acceleration_mps2, limits.jerk_mps3
    assert np.all(np.abs(cart.acceleration_mps2) <= acc * (1 + 1e-9))
    assert np.all(np.abs(np.diff(cart.acceleration_mps2, axis=0)) / act.tick_s <= jerk * (1 + 1e-6))
    np.testing.assert_allclose(cart.velocity_mps[-1], 0.0, atol=1e-9)
    stop = next(e for e in act.events if e.kind == "stopped")
    assert stop.t_s - watchdog.t_s <= 0.04 / acc[0] + acc[0] / jerk[0] + 2 * act.tick_s
    assert len(robot.named("servoJ")) > n_commanded  # setpoints streamed while braking
    names = robot.names()
    last_servo = len(names) - 1 - names[::-1].index("servoJ")
    assert names.count("servoStop") == 1 and names.index("servoStop") > last_servo
    assert robot.named("servoStop")[0].args == (0.5,)
    # motion refused until reset, every refusal counted, the first logged
    n_servo = len(robot.named("servoJ"))
    _drive(act, (0.02, 0.0, 0.0), 0.2, t + 1.5)
    assert len(robot.named("servoJ")) == n_servo
    assert (
        act.limit_counts()["ur5_refused_commands"] == 7 and [e.kind for e in act.events].count("refused") == 1
    )
    assert act.limit_counts()["ur5_watchdog"] == 1
    # reset runs the pre-flight again and streams from where the EPM stands
    act.reset(act.position_m)
    assert act.stopped is None and robot.names().count("moveJ") == 1  # already there: no move
    _drive(act, (0.02, 0.0, 0.0), 0.1)
    assert len(robot.named("servoJ")) == n_servo + 50


def test_the_rtde_watchdog_is_armed_and_kicked_when_asked(scenario):
    robot = _robot(scenario)
    act = _connect(scenario, robot, rtde_watchdog_hz=20.0)
    act.reset(_start(scenario))
    _drive(act, (0.01, 0.0, 0.0), 0.1)
    assert robot.named("setWatchdog")[0].args == (20.0,)
    assert robot.names().index("setWatchdog") > robot.names().index("moveJ")
    assert len(robot.named("kickWatchdog")) == len(robot.named("servoJ")) == 50


# -- stops ------------------------------------------------------------------------------------


def _stopped_after(act: UR5RtdeActuator, robot: FakeRobot, kind: str) -> None:
    """The actuator latched a stop of ``kind``: counted once, servoStop sent once, no servoJ since."""
    assert act.stopped == kind
    assert act.limit_counts()[f"ur5_{kind}"] == 1
    assert [e.kind for e in act.events].count(kind) == 1
    names = robot.names()
    assert names.count("servoStop") == 1
    assert "servoJ" not in names[names.index("servoStop") :]


@pytest.mark.parametrize(
    ("fault", "detail"),
    [
        ("joint", r"joint 3 \(elbow_joint\) is 0\.0[78]\d\d rad from its setpoint"),
        ("tcp", r"the controller's TCP is 8\.00 mm .* from the model's EPM frame"),
    ],
)
def test_a_pose_mismatch_stops_the_robot_and_is_counted(scenario, fault, detail):
    robot = _robot(scenario)
    act = _connect(scenario, robot)
    act.reset(_start(scenario))
    t = _drive(act, (0.02, 0.01, 0.0), 0.3)
    n_before = len(robot.named("servoJ"))
    if fault == "joint":
        robot.q_reading_offset[2] = 0.08
    else:
        robot.tcp_reading_offset[:] = (0.008, 0.0, 0.0)
    _drive(act, (0.02, 0.01, 0.0), 0.3, t)
    _stopped_after(act, robot, "pose_mismatch")
    assert len(robot.named("servoJ")) == n_before
    event = next(e for e in act.events if e.kind == "pose_mismatch")
    assert re.search(detail, event.detail)


def test_a_protective_stop_stops_the_stream(scenario):
    robot = _robot(scenario, protective_speed_radps=0.05)  # a robot stricter than the arm stack
    act = _connect(scenario, robot)
    act.reset(_start(scenario))
    _drive(act, (0.08, 0.08, 0.0), 0.5)
    _stopped_after(act, robot, "protective_stop")
    assert "safety mode 3" in next(e.detail for e in act.events if e.kind == "protective_stop")
    with pytest.raises(UR5Error, match="safety mode 3, not NORMAL"):
        act.reset(act.position_m)  # the pre-flight wants the stop cleared on the pendant


def test_a_joint_acceleration_beyond_the_limit_is_never_sent(scenario):
    robot = _robot(scenario)
    act = _connect(scenario, robot, max_joint_acceleration_radps2=0.05)
    act.reset(_start(scenario))
    _drive(act, (0.05, 0.0, 0.0), 0.3)
    _stopped_after(act, robot, "limit")
    detail = next(e.detail for e in act.events if e.kind == "limit")
    assert "setpoint not sent" in detail and "max_joint_acceleration_radps2 0.05" in detail
    q = _servo_targets(robot)
    assert len(q) < 3 or (np.abs(np.diff(q, n=2, axis=0)) / act.tick_s**2).max() <= 0.05


def test_a_setpoint_the_ik_refuses_stops_the_robot(scenario):
    slow = scenario.model_copy(
        update={"arm": scenario.arm.model_copy(update={"joint_velocity_fraction": 0.02})}
    )
    robot = _robot(slow)
    act = _connect(slow, robot)
    act.reset(_start(slow))
    _drive(act, (0.08, 0.0, 0.0), 0.5)
    _stopped_after(act, robot, "limit")
    assert "not reachable by the arm" in next(e.detail for e in act.events if e.kind == "limit")


@pytest.mark.parametrize("how", ["isConnected", "servoJ raises"])
def test_a_lost_connection_stops(scenario, how):
    robot = _robot(scenario)
    act = _connect(scenario, robot)
    act.reset(_start(scenario))
    t = _drive(act, (0.02, 0.0, 0.0), 0.2)
    if how == "isConnected":
        robot.drop_connection()
    else:
        robot.servo_raises = True
    _drive(act, (0.02, 0.0, 0.0), 0.1, t)
    assert act.stopped == "disconnect" and act.limit_counts()["ur5_disconnect"] == 1
    assert robot.names().count("servoStop") == 1  # tried all the same


# -- pre-flight -------------------------------------------------------------------------------


def _refused(scenario, robot, match, exc=UR5Error, **kw):
    act = _connect(scenario, robot, **kw)
    with pytest.raises(exc, match=match):
        act.reset(_start(scenario))
    assert "servoJ" not in robot.names() and act.stopped == "not armed"
    assert act.limit_counts()["ur5_preflight_failures"] == 1
    with pytest.raises(RuntimeError, match=r"reset\(\) first"):
        act.step_xyz(PLANT_DT)
    return act


def test_a_robot_far_from_the_start_is_not_moved(scenario):
    q0 = _q_at(scenario, _start(scenario))
    q0[0] += 1.0
    robot = FakeRobot(q0)
    _refused(scenario, robot, r"joint 1 \(shoulder_pan_joint\) is 1\.000 rad .* premove_max_joint_rad 0\.8")
    assert "moveJ" not in robot.names()


def test_a_move_that_would_dip_the_epm_below_the_workspace_is_refused(scenario):
    robot = FakeRobot(_q_at(scenario, _start(scenario) - np.array([0.0, 0.0, 0.04])))
    _refused(scenario, robot, r"EPM down to 0\.05\d+ m, below the workspace's lowest height 0\.085 m")
    assert "moveJ" not in robot.names()


@pytest.mark.parametrize(
    ("state", "match"),
    [
        ({"robot_mode": 5}, r"robot mode 5, not RUNNING \(7\)"),
        ({"safety_mode": 3}, r"safety mode 3, not NORMAL \(1\)"),
        ({"connected": False}, r"not connected"),
    ],
)
def test_a_robot_not_ready_is_refused(scenario, state, match):
    robot = _robot(scenario)
    for key, value in state.items():
        setattr(robot, key, value)
    _refused(scenario, robot, match)
    assert "moveJ" not in robot.names()


def test_a_start_pose_mismatch_after_the_move_is_refused(scenario):
    robot = _robot(scenario)
    robot.tcp_reading_offset[:] = (0.0, 0.0, 0.006)
    _refused(scenario, robot, r"pre-flight: the controller's TCP is 6\.00 mm")
    assert robot.names().count("moveJ") == 1


def test_a_start_outside_the_workspace_is_refused(scenario):
    robot = _robot(scenario)
    act = _connect(scenario, robot)
    with pytest.raises(ValueError, match=r"position_m\[2\]: must lie in the workspace"):
        act.reset(_start(scenario) + np.array([0.0, 0.0, 0.05]))
    assert "moveJ" not in robot.names()


def test_a_stopped_control_script_is_uploaded_again_with_its_tcp(scenario):
    robot = _robot(scenario)
    act = _connect(scenario, robot)
    robot.program_running = False
    act.reset(_start(scenario))
    names = robot.names()
    assert names.count("reuploadScript") == 1 and names.count("setTcp") == 2
    assert names.index("reuploadScript") < len(names) - 1 - names[::-1].index("setTcp") < names.index("moveJ")


def test_nothing_moves_before_reset(scenario):
    robot = _robot(scenario)
    act = _connect(scenario, robot)
    act.set_velocity_command(0.0, np.array([0.01, 0.0, 0.0]))
    assert act.limit_counts()["ur5_refused_commands"] == 1
    with pytest.raises(RuntimeError, match=r"reset\(\) first"):
        act.step(PLANT_DT)
    assert not {"moveJ", "servoJ", "initPeriod"} & set(robot.names())


def test_close_stops_servoing_and_the_control_script(scenario):
    robot = _robot(scenario)
    with _connect(scenario, robot) as act:
        act.reset(_start(scenario))
        _drive(act, (0.01, 0.0, 0.0), 0.1)
    assert robot.names()[-4:] == ["servoStop", "stopScript", "disconnect", "disconnect"]
    assert act.events[-1].kind == "closed"
    with pytest.raises(RuntimeError, match=r"reset\(\) first"):
        act.step_xyz(PLANT_DT)


def test_a_missing_ur_rtde_names_the_extra(scenario, monkeypatch):
    monkeypatch.setitem(sys.modules, "rtde_control", None)  # import fails as if not installed
    with pytest.raises(UR5DependencyError, match=r"needs ur-rtde.*pip install 'capsule_mpc\[ur\]'"):
        rtde_factories()
    with pytest.raises(ImportError, match=r"capsule_mpc\[ur\]"):
        UR5RtdeActuator(scenario, UR5Settings(host=HOST))


def test_settings_are_validated_naming_the_field():
    with pytest.raises(ValueError, match="servo_lookahead_s"):
        UR5Settings(host=HOST, servo_lookahead_s=0.5)
    with pytest.raises(ValueError, match="servo_gain"):
        UR5Settings(host=HOST, servo_gain=50)
    with pytest.raises(ValueError, match="rtde_rate_hz"):
        UR5Settings(host=HOST, rtde_rate_hz=250)


# -- the calibration file ---------------------------------------------------------------------


def test_the_default_placement_round_trips_through_a_calibration_file(scenario, tmp_path):
    calibration = calibration_of(scenario.arm)
    # the controller's base is the URDF's base_link turned half a turn: facing +y means yaw -pi/2
    assert calibration.base.rpy_rad[2] == pytest.approx(-math.pi / 2)
    loaded = load_calibration(write_calibration(calibration, tmp_path / "ur5.yaml"))
    placed = apply_calibration(scenario, loaded)
    q = np.array(scenario.arm.q_seed_rad)
    a, b = ArmKinematics(scenario.arm).epm_placement(q), ArmKinematics(placed.arm).epm_placement(q)
    np.testing.assert_allclose(b.homogeneous, a.homogeneous, atol=1e-12)


def test_a_calibrated_rig_agrees_with_the_controller(scenario):
    """A base 1 cm and 0.03 rad off the defaults and a longer adapter: the TCP the controller
    computes (URDF base -> tool0 with the offset given to setTcp) matches the model's EPM."""
    calibration = UR5Calibration(
        base={"xyz_m": (0.01, -0.46, 0.002), "rpy_rad": (0.0, 0.0, -math.pi / 2 + 0.03)},
        tool={"xyz_m": (0.001, 0.0, 0.064), "rpy_rad": (math.pi, 0.0, 0.0)},
    )
    placed = apply_calibration(scenario, calibration)
    robot = FakeRobot(_q_at(placed, _start(placed) + np.array([0.0, 0.0, 0.05])))
    act = _connect(scenario, robot, calibration=calibration)
    assert robot.named("setTcp")[0].args[0] == pytest.approx([0.001, 0.0, 0.064, math.pi, 0.0, 0.0])
    act.reset(_start(scenario))
    _drive(act, (0.01, 0.01, 0.0), 0.3)
    assert act.stopped is None
    np.testing.assert_allclose(act.position_m, _start(scenario) + np.array([0.003, 0.003, 0.0]), atol=1e-3)
    np.testing.assert_allclose(act.velocity_mps, [0.01, 0.01, 0.0], atol=2e-4)  # from the measured joints
    assert act.scenario.arm.base_xyz_m == pytest.approx((0.01, -0.46, 0.002))


_VALID = {
    "version": 1,
    "base": {"xyz_m": [0.0, -0.45, 0.0], "rpy_rad": [0.0, 0.0, -1.5707963]},
    "tool": {"xyz_m": [0.0, 0.0, 0.06], "rpy_rad": [3.1415927, 0.0, 0.0]},
}
_RANGES = {
    ("base", "xyz_m"): (2.0, "[-2, 2] m"),
    ("tool", "xyz_m"): (0.3, "[-0.3, 0.3] m"),
    ("base", "rpy_rad"): (2 * math.pi, "[-6.28319, 6.28319] rad"),
    ("tool", "rpy_rad"): (2 * math.pi, "[-6.28319, 6.28319] rad"),
}


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    field=st.sampled_from(sorted(_RANGES)),
    index=st.integers(0, 2),
    value=st.floats(-20.0, 20.0, allow_nan=False),
)
def test_calibration_values_are_checked_against_their_ranges(tmp_path, field, index, value):
    data = yaml.safe_load(yaml.safe_dump(_VALID))
    section, key = field
    data[section][key][index] = value
    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    bound, text = _RANGES[field]
    if abs(value) <= bound:
        assert getattr(getattr(load_calibration(path), section), key)[index] == value
    else:
        with pytest.raises(ConfigError) as info:
            load_calibration(path)
        message = str(info.value)
        assert f"{section}.{key}: " in message and f"must lie in {text}" in message and str(path) in message


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d["base"].pop("rpy_rad"), r"base\.rpy_rad: required field is missing"),
        (lambda d: d["tool"].update(xyz_mm=[0, 0, 60]), r"tool\.xyz_mm: unknown key"),
        (lambda d: d.update(version=2), r"version: "),
        (lambda d: d["tool"].update(xyz_m=[0, 0]), r"tool\.xyz_m"),
        (lambda d: d["base"].update(xyz_m=[0, "-0.45", 0]), r"base\.xyz_m\.1: must be a number"),
    ],
)
def test_a_malformed_calibration_file_is_refused_naming_the_field(tmp_path, edit, match):
    data = yaml.safe_load(yaml.safe_dump(_VALID))
    edit(data)
    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    with pytest.raises(ConfigError, match=match):
        load_calibration(path)


# -- a closed loop ----------------------------------------------------------------------------


def test_a_closed_loop_runs_to_its_end_with_the_fake_robot_following():
    quick = load_config(QUICK)
    ideal = quick.model_copy(update={"plant": quick.plant.model_copy(update={"preset": "ideal"})})
    full = rectangle((0.10, 0.06), (0.0, 0.0), 0.02)
    side = type(full)(full.vertices_m[:2], closed=False, speed_mps=0.02)  # 0.1 m in 5 s
    robot = FakeRobot(_q_at(ideal, np.array([-0.05, -0.03, ideal.plate.epm_height_m + 0.05])))
    act = _connect(ideal, robot)
    result = ClosedLoop(ideal, "follow", side, seed=0, actuator=act).run()
    assert result.flags.completed and not result.flags.timed_out
    assert act.stopped is None and [e.kind for e in act.events] == ["connected", "premove", "armed"]
    assert len(robot.named("servoJ")) == math.floor(result.sim_time_s * 500 + 1e-6)
    assert result.metrics["arm_ok"] and result.metrics["ur5_pose_mismatch"] == 0
    log = result.log
    epm = np.column_stack([log["epm_x_m"], log["epm_y_m"]])
    assert np.ptp(epm[:, 0]) > 0.09  # the EPM crossed the side with the capsule
    assert result.metrics["final_error_mm"] < 2.0


def _signatures(doc: str, name: str) -> list[list[str]]:
    """The parameters (after self) of every ``name(self: ...)`` signature in a pybind11 docstring."""
    out = []
    for start in [m.end() for m in re.finditer(rf"\b{name}\(self: ", doc)]:
        depth, params, current = 0, [], ""
        for ch in doc[start:]:
            if ch in "([" or (ch == ")" and depth > 0) or ch == "]":
                depth += 1 if ch in "([" else -1
            elif ch == ")":
                break
            if ch == "," and depth == 0:
                params.append(current.strip())
                current = ""
            else:
                current += ch
        params.append(current.strip())
        out.append(params[1:])  # the first is the rest of ``self: <class>``
    return out


@pytest.mark.parametrize(("module", "fake"), [("rtde_control", FakeControl), ("rtde_receive", FakeReceive)])
def test_the_fake_interfaces_are_ur_rtde_s_own(module, fake):
    """Every method the fake offers exists in ur-rtde with a signature that takes the same arguments."""
    real = getattr(
        pytest.importorskip(module),
        {"rtde_control": "RTDEControlInterface"}.get(module, "RTDEReceiveInterface"),
    )
    for name in (n for n in vars(fake) if not n.startswith("_")):
        method = getattr(real, name, None)
        assert method is not None, f"{module} has no {name}"
        ours = len(inspect.signature(getattr(fake, name)).parameters) - 1
        theirs = _signatures(method.__doc__, name)
        fits = [p for p in theirs if sum("=" not in a for a in p) <= ours <= len(p)]
        assert fits, f"{name}: the fake takes {ours} arguments, ur-rtde's signatures are {theirs}"
