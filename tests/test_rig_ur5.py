"""The rig node with ``--backend ur5`` as a hardware-in-the-loop dry run, against the fake robot
(tests/fake_rtde.py) paced on the wall clock: the UR5 streams servoJ from its own thread at the
RTDE rate while the rig node's loop runs the simulated capsule on the EPM the robot measured; a
stop of the arm ends the run with its reason; the stream and the connection are closed at the end."""

from __future__ import annotations

import os
import sys
import threading
import time
import uuid
from types import SimpleNamespace

import numpy as np
import pytest

from capsule_mpc.arm import ArmKinematics
from capsule_mpc.arm.ur5_rtde import STOP_KINDS, UR5RtdeActuator, UR5Settings
from capsule_mpc.experiments.runs import prepare_run
from capsule_mpc.nodes.controller import ControllerNode, ControlOptions
from capsule_mpc.nodes.rig import RigOptions, serve_rig
from capsule_mpc.nodes.streaming import StreamingActuator
from capsule_mpc.nodes.transport import Transport
from capsule_mpc.sim import simulate
from capsule_mpc.sim.loop import ClosedLoop, Observer
from capsule_mpc.sim.runner import realtime_scenario
from fake_rtde import FakeRobot
from nodes_support import QUICK, free_endpoint, waypoints

#: A documentation address (RFC 5737): nothing is ever contacted.
HOST = "192.0.2.10"
RATE_HZ = 500.0
#: The path: 15 mm along x.
POINTS = [(-0.05, -0.03), (-0.035, -0.03)]


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """The quick rectangle's scenario (ideal plant) on the short path."""
    wp = waypoints(tmp_path_factory.mktemp("rig_ur5"), POINTS)
    scenario, path, _meta = prepare_run(QUICK, wp, None, "ideal")
    return scenario, path


def _robot_and_arm(scenario):
    """A fake robot on the wall clock, parked 5 cm above the start, and the UR5 backend on it."""
    kin = ArmKinematics(scenario.arm)
    start = np.array([*POINTS[0], scenario.plate.epm_height_m + 0.05])
    robot = FakeRobot(kin.solve(start, np.array(scenario.arm.q_seed_rad), 300).q, realtime=True)
    arm = UR5RtdeActuator(
        scenario,
        UR5Settings(host=HOST),
        control_factory=robot.control_factory,
        receive_factory=robot.receive_factory,
    )
    return robot, arm


class InjectMismatch(Observer):
    """From rig time ``t_s`` on, the robot reports its TCP 8 mm off the model's EPM (a calibration
    gone wrong: the joints, and so the EPM the plant reads, are the robot's own)."""

    def __init__(self, robot: FakeRobot, t_s: float) -> None:
        self.robot, self.t_s, self.wall_s = robot, t_s, None

    def frame_end(self, loop: ClosedLoop, frame) -> None:
        if frame.t_s >= self.t_s and self.wall_s is None:
            self.robot.tcp_reading_offset[:] = (0.008, 0.0, 0.0)
            self.wall_s = frame.t_s


def _serve(scenario, path, actuator, observers=()):
    """The rig node with ``actuator`` and a ``follow`` controller node in a thread of this process."""
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    status: dict[str, object] = {}

    def run_node() -> None:
        try:
            status["rc"] = node.run()
        except Exception as exc:  # its session closed under it: the rig's run was interrupted
            status["rc"] = exc

    with Transport(prefix, listen=[endpoint]) as rig_t, Transport(prefix, connect=[endpoint]) as ctl_t:
        node = ControllerNode(ctl_t, scenario, "follow", ControlOptions(wait_s=60), say=lambda _t: None)
        thread = threading.Thread(target=run_node, daemon=True)
        thread.start()
        result, events = serve_rig(
            scenario,
            path,
            2,
            rig_t,
            actuator=actuator,
            say=lambda _t: None,
            options=RigOptions(watchdog_timeout_s=5.0, wait_controller_s=60),
            observers=observers,
        )
        thread.join(10)
    return result, events, status.get("rc")


def _stream_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "ur5-stream"]


#: Runs the rate test tries before it gives up on the stream keeping its rate (on a loaded machine
#: the process may be descheduled for many RTDE periods; the fake robot then moves late too).
ATTEMPTS = 3


def _rate_problems(robot: FakeRobot, result) -> list[str]:
    """How servoJ missed the RTDE rate on the wall clock during the run (empty: it kept it)."""
    wall = np.array([c.wall_s for c in robot.named("servoJ")])
    span = wall[-1] - wall[0]
    problems = []
    if span < 0.9 * result.sim_time_s:
        problems.append(f"servoJ over {span:.3f} s of a {result.sim_time_s:.3f} s run")
    median = float(np.median(np.diff(wall)))
    if abs(median * RATE_HZ - 1.0) > 0.25:
        problems.append(f"median period {median * 1e3:.3f} ms")
    # a loaded machine wakes the stream late: the fake's periods (and ur-rtde's) then last longer
    if len(wall) < 0.6 * span * RATE_HZ or result.metrics["ur5_stream_rate_hz"] < 0.6 * RATE_HZ:
        problems.append(f"{len(wall)} servoJ in {span:.3f} s")
    # throughout: no tenth of a second of the run without a quarter of its periods
    fewest = int(np.histogram(wall, bins=np.arange(wall[0], wall[-1], 0.1))[0].min())
    if fewest < 0.25 * 0.1 * RATE_HZ:
        problems.append(f"{fewest} servoJ in a tenth of a second")
    return problems


def _check_dry_run(robot: FakeRobot, arm: UR5RtdeActuator, act: StreamingActuator, result, events, rc):
    """What a dry run must give however loaded the machine: the capsule follows the EPM along the
    path, no stop, every joint target within the limits, closed after braking to rest."""
    assert not _stream_threads()  # the run's end joined the stream
    assert rc == 0
    assert not result.flags.arm_failure and act.stop is None
    assert arm.stopped == "closed" and not [e for e in arm.events if e.kind in STOP_KINDS]
    log = result.log
    assert log["capsule_x_m"][-1] - log["capsule_x_m"][0] > 0.012, result.outcome_text()
    assert np.abs(log["capsule_y_m"] - POINTS[0][1]).max() < 1e-3
    assert result.metrics["final_error_mm"] < 3.0
    kinds = [e["kind"] for e in events]
    assert "run_end" in kinds and "arm_stopped" not in kinds
    m = result.metrics
    assert m["ur5_stream_periods"] >= len(robot.named("servoJ"))
    assert all(m[f"ur5_{k}"] == 0 for k in ("watchdog", "limit", "pose_mismatch", "protective_stop"))
    assert m["arm_ok"] is True  # the setpoints streamed pass the loop's check of a robot arm's
    q = np.array([c.args[0] for c in robot.named("servoJ")])
    assert np.all(q >= arm.kin.lower_rad) and np.all(q <= arm.kin.upper_rad)
    assert robot.safety_mode == 1  # never a protective stop
    # closed: the stream braked to rest, then servoStop, the script stopped, both interfaces closed
    assert robot.names()[-4:] == ["servoStop", "stopScript", "disconnect", "disconnect"]
    np.testing.assert_allclose(arm.cartesian_trajectory().velocity_mps[-1], 0.0, atol=1e-9)


def test_a_dry_run_streams_servoj_at_the_rtde_rate_and_the_capsule_follows(rig):
    scenario, path = rig
    # the simulated arm on the same run: this short run is cut off before the capsule rests
    ref = simulate(realtime_scenario(scenario), "follow", path, 2)
    tries = []
    for _attempt in range(ATTEMPTS):
        robot, arm = _robot_and_arm(scenario)
        with StreamingActuator(arm) as act:
            result, events, rc = _serve(scenario, path, act)
            # the EPM the loop read is the one the robot measured: forward kinematics of its joints
            np.testing.assert_allclose(act.position_m, arm.kin.epm_position(robot.q), atol=2e-4)
        _check_dry_run(robot, arm, act, result, events, rc)
        assert result.flags.timed_out == ref.flags.timed_out
        tries.append(_rate_problems(robot, result))
        if not tries[-1]:
            break
    else:
        pytest.fail(f"servoJ missed the RTDE rate in every run: {tries} (load {os.getloadavg()})")


def test_a_pose_mismatch_mid_run_ends_the_run_with_the_stop_and_its_reason(rig):
    scenario, path = rig
    robot, arm = _robot_and_arm(scenario)
    inject = InjectMismatch(robot, 0.3)
    with StreamingActuator(arm) as act:
        result, events, rc = _serve(scenario, path, act, observers=[inject])
        assert not _stream_threads()
        assert rc == 0
    assert result.failed and not (result.flags.completed or result.flags.decoupled)
    assert result.metrics["outcome"].startswith("arm stopped (pose_mismatch) at t = ")
    assert "the controller's TCP is 8.00 mm" in result.flags.arm_failure
    assert "arm stopped (pose_mismatch)" in result.outcome_text()
    assert result.metrics["ur5_pose_mismatch"] == 1
    # ended within a few frames of the injection, the stop in the rig's events
    assert result.log["t_s"][-1] - inject.wall_s < 0.2
    kinds = [e["kind"] for e in events]
    assert kinds.index("arm_stopped") == kinds.index("run_end") - 1
    # the robot: servoStop once, no servoJ after it; then the script stopped and disconnected
    names = robot.names()
    assert names.count("servoStop") == 1 and "servoJ" not in names[names.index("servoStop") :]
    assert names[-3:] == ["stopScript", "disconnect", "disconnect"]


class Interrupt(Observer):
    """Ctrl-C at rig time ``t_s``: the loop's thread gets ``KeyboardInterrupt``, as the command's
    signal handler raises it."""

    def __init__(self, t_s: float) -> None:
        self.t_s = t_s

    def frame_end(self, loop: ClosedLoop, frame) -> None:
        if frame.t_s >= self.t_s:
            raise KeyboardInterrupt


def test_ctrl_c_mid_run_brakes_joins_the_stream_and_closes_the_robot(rig):
    scenario, path = rig
    robot, arm = _robot_and_arm(scenario)
    act = StreamingActuator(arm)
    with pytest.raises(KeyboardInterrupt), act:
        _serve(scenario, path, act, observers=[Interrupt(0.2)])
    assert not _stream_threads()
    # braked to rest by the arm stack, then servoStop, the script stopped, both interfaces closed
    np.testing.assert_allclose(arm.cartesian_trajectory().velocity_mps[-1], 0.0, atol=1e-9)
    assert robot.names()[-4:] == ["servoStop", "stopScript", "disconnect", "disconnect"]
    assert act.stop is None and not [e for e in arm.events if e.kind in STOP_KINDS]


def test_the_stream_never_waits_on_the_loop_and_the_plant_reads_it_in_real_time(rig):
    """Between the loop's calls the arm streams on; a step to a rig time still ahead waits for the
    wall clock and returns the EPM measured then."""
    scenario, _path = rig
    robot, arm = _robot_and_arm(scenario)
    # Periods the stream sends with no call from the loop: 0.12 s of the RTDE rate. A stream that
    # waited on the loop would send none. How soon they come is the machine's load (the stream's
    # rate is the rate test's), so the loop stays away until they have come, or for 3 s.
    periods = round(0.6 * 0.2 * RATE_HZ)
    with StreamingActuator(arm) as act:
        act.reset(np.array([*POINTS[0], scenario.plate.epm_height_m]))
        loop = SimpleNamespace(realtime=True, wall0=time.perf_counter(), k_first=-300, dt=1e-3)
        act.on_reset(loop)
        act.set_velocity_command(-0.3, np.array([0.02, 0.0, 0.0]))
        give_up = time.perf_counter() + 3.0
        while len(robot.named("servoJ")) < periods and time.perf_counter() < give_up:
            time.sleep(0.01)  # the loop is busy elsewhere: no step, no command
        n_streamed = len(robot.named("servoJ"))
        assert n_streamed >= periods, os.getloadavg()
        x_past = act.step_xyz(0.1)[0]  # rig time 0.1 s after the start: measured in the past
        ahead_s = time.perf_counter() - loop.wall0 + 0.1  # 0.1 s ahead of the wall clock
        x_now = act.step_xyz(ahead_s - 0.1)[0]  # still ahead: waited for
        assert time.perf_counter() - loop.wall0 >= ahead_s
        assert POINTS[0][0] < x_past < x_now < POINTS[0][0] + ahead_s * 0.02
        np.testing.assert_allclose(act.position_m[:2], [x_now, POINTS[0][1]], atol=1e-4)
    assert not _stream_threads()
    assert act.stream_metrics()["ur5_stream_periods"] >= n_streamed


def test_the_streaming_actuator_needs_the_loop_s_clock(rig):
    scenario, path = rig
    robot, arm = _robot_and_arm(scenario)
    with StreamingActuator(arm) as act:
        act.reset(np.array([*POINTS[0], scenario.plate.epm_height_m]))
        with pytest.raises(RuntimeError, match="give the actuator to the loop's observers"):
            act.step_xyz(1e-3)
        with pytest.raises(ValueError, match="must run in real time"):
            ClosedLoop(scenario, "follow", path, 0, actuator=act).run([act])
    assert robot.names()[-3:] == ["stopScript", "disconnect", "disconnect"]
    assert "servoJ" not in robot.names()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--backend", "ur5"], "--ur-host: required with --backend ur5"),
        (["--ur-host", HOST], "--ur-host: only with --backend ur5"),
        (["--backend", "ur5", "--ur-host", ""], "--ur-host: must not be empty"),
        (
            ["--backend", "ur5", "--ur-host", HOST, "--ur-calibration", "/nonexistent/ur5.yaml"],
            "--ur-calibration",
        ),
    ],
)
def test_bad_ur5_options_exit_2_naming_them(args, message, capsys):
    from capsule_mpc.cli import main

    try:
        status = main(["rig", "serve", "--config", str(QUICK), *args])
    except SystemExit as exc:  # argparse refuses an option's value
        status = exc.code
    assert status == 2
    assert message in capsys.readouterr().err


def test_a_missing_ur_rtde_exits_2_naming_the_extra(capsys, monkeypatch):
    from capsule_mpc.cli import main

    monkeypatch.setitem(sys.modules, "rtde_control", None)  # import fails as if not installed
    status = main(["rig", "serve", "--config", str(QUICK), "--backend", "ur5", "--ur-host", HOST])
    assert status == 2
    assert "pip install 'capsule_mpc[ur]'" in capsys.readouterr().err
