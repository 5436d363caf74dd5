"""The rig and the controller as nodes in one process: the same physics as the in-process loop
when the commands come in time; a controller node refusing another scenario; bad options."""

from __future__ import annotations

import os
import threading
import uuid

import pytest

from capsule_mpc.baselines import FollowPath
from capsule_mpc.errors import ConfigError
from capsule_mpc.experiments.runs import prepare_run
from capsule_mpc.nodes import messages as m
from capsule_mpc.nodes.controller import ControllerNode, ControlOptions
from capsule_mpc.nodes.rig import RigOptions, serve_rig
from capsule_mpc.nodes.transport import Transport
from capsule_mpc.sim import simulate
from capsule_mpc.sim.runner import realtime_scenario
from nodes_support import QUICK, free_endpoint, same_physics, waypoints


class LossyTransport(Transport):
    """A controller's transport that loses the camera frames of the indices in ``lost``."""

    def __init__(self, *args, lost: range, **kw) -> None:
        super().__init__(*args, **kw)
        self.lost = lost

    def subscribe(self, topic, callback, *, ordered=True):
        if topic == "frame":
            inner = callback

            def callback(msg):
                if msg.frame_index not in self.lost:
                    inner(msg)

        super().subscribe(topic, callback, ordered=ordered)


def run_in_process(scenario, path, seed, controller, *, watchdog_s=0.5, lost=range(0)):
    """The rig and a controller node as two sessions of this process (the node in a thread); the
    node's transport loses the frames of the indices in ``lost``."""
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    status: dict[str, int] = {}
    with (
        Transport(prefix, listen=[endpoint]) as rig_t,
        LossyTransport(prefix, connect=[endpoint], lost=lost) as ctl_t,
    ):
        node = ControllerNode(ctl_t, scenario, controller, ControlOptions(wait_s=60), say=lambda _t: None)
        thread = threading.Thread(target=lambda: status.setdefault("rc", node.run()), daemon=True)
        thread.start()
        result, events = serve_rig(
            scenario,
            path,
            seed,
            rig_t,
            say=lambda _t: None,
            options=RigOptions(watchdog_timeout_s=watchdog_s, wait_controller_s=60),
        )
        thread.join(10)
    return result, events, status.get("rc"), node


#: Runs over nodes a test tries before it gives up on every command arriving in time (on a loaded
#: machine a process may be descheduled for longer than a frame).
ATTEMPTS = 3


@pytest.mark.parametrize(
    "controller, plant, rate_hz",
    [("follow", "ideal", 10.0), pytest.param("mpc", "lab", 30.0, marks=pytest.mark.slow)],
)
def test_nodes_in_time_give_the_in_process_run(tmp_path, controller, plant, rate_hz):
    wp = waypoints(tmp_path, [(-0.05, -0.03), (-0.035, -0.03)])
    scenario, path, _meta = prepare_run(QUICK, wp, None, plant)
    update = {"camera": scenario.camera.model_copy(update={"rate_hz": rate_hz})}
    if controller == "mpc":
        # uncompiled NLP functions (built in well under a second); a solve deadline no solve on a
        # loaded machine reaches, so the MPC's late-solve fallback, which depends on the wall
        # clock, acts in neither run
        update["mpc"] = scenario.mpc.model_copy(update={"compile_c": False, "deadline_ms": 5000.0})
    scenario = scenario.model_copy(update=update)
    ref = simulate(realtime_scenario(scenario), controller, path, 2)
    misses = []
    for _attempt in range(ATTEMPTS):
        result, events, rc, node = run_in_process(scenario, path, 2, controller, watchdog_s=5.0)
        assert rc == 0 and not node.counts["frames_lost"]
        assert [e["kind"] for e in events][:2] == ["controller_ready", "run_start"]
        assert result.controller == controller
        # a command missed in the settle phase changes nothing: the arm is held still then
        misses.append(result.metrics.get("node_deadline_misses_motion", 0))
        if misses[-1] == 0:
            break
    else:
        pytest.fail(
            f"commands missed their deadlines in motion in every run ({misses}; load {os.getloadavg()})"
        )
    # the commands in time: the in-process run, but for the wall-clock columns (the controller's
    # phases, which it reports with each command, included)
    assert set(ref.log["phase"].tolist()) - {""}
    assert same_physics(result.log, ref.log) == []
    assert result.metrics["tracking_rms_mm"] == ref.metrics["tracking_rms_mm"]


class Failing(FollowPath):
    """``follow`` whose step raises from its fourth on (counted)."""

    def __init__(self) -> None:
        super().__init__()
        self.steps_taken = self.raised = 0

    def step(self, t_s, measurement, epm_position_m):
        if self.steps_taken == 3:
            self.raised += 1
            raise RuntimeError("the controller broke")
        self.steps_taken += 1
        return super().step(t_s, measurement, epm_position_m)


def test_a_quick_controller_answers_frames_on_arrival_and_a_failing_step_ends_the_node(tmp_path):
    wp = waypoints(tmp_path, [(-0.05, -0.03), (-0.045, -0.03)])
    scenario, path, _meta = prepare_run(QUICK, wp, None, "ideal")
    result, _events, rc, node = run_in_process(scenario, path, 2, "follow")
    assert rc == 0
    # frames answered without the hand-off to the node's loop: on a quiet machine all but the
    # first; on a loaded one a frame whose arm state comes after it goes through the loop
    assert node.counts["frames_answered_on_arrival"] >= 1
    assert node.steps == result.realtime.frames

    failing = Failing()
    errors: list[BaseException] = []
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    with Transport(prefix, listen=[endpoint]) as rig_t, Transport(prefix, connect=[endpoint]) as ctl_t:
        node = ControllerNode(ctl_t, scenario, failing, ControlOptions(wait_s=60), say=lambda _t: None)

        def run() -> None:
            try:
                node.run()
            except RuntimeError as exc:
                errors.append(exc)

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        serve_rig(scenario, path, 2, rig_t, say=lambda _t: None, options=RigOptions(watchdog_timeout_s=0.2))
        thread.join(10)
    # the step that raised on Zenoh's thread ended the node's loop at once, with its error
    assert [str(e) for e in errors] == ["the controller broke"] and failing.raised == 1


def test_a_controller_node_coasts_through_lost_frames_one_step_per_frame(tmp_path):
    wp = waypoints(tmp_path, [(-0.05, -0.03), (-0.035, -0.03)])
    scenario, path, _meta = prepare_run(QUICK, wp, None, "ideal")
    lost = range(12, 30)  # 0.6 s of frames at 30 Hz, during the path
    result, events, rc, node = run_in_process(scenario, path, 2, "follow", watchdog_s=5.0, lost=lost)
    assert rc == 0
    assert node.counts["coasting"] == 1
    # every frame was stepped once: as it came, or (lost) as a dropped frame at its expected time
    frames = result.realtime.frames
    assert frames - 2 <= node.steps <= frames
    # the first lost frames went unanswered (the rig held the previous command); the coasted
    # answers that came in time were applied
    held = result.metrics["node_deadline_misses_motion"]
    assert 1 <= held <= len(lost) + 1
    assert [e["kind"] for e in events].count("command_late") >= 1


def test_a_controller_node_refuses_a_rig_with_another_controller_config():
    info = m.RunInfo(
        config_name="other", config_hash="x", config_sections=("mpc",), config_section_hashes=("y",)
    )
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    with Transport(prefix, listen=[endpoint]) as t:
        node = ControllerNode(t, prepare_run(QUICK, None, None)[0], "follow", say=lambda _t: None)
        with pytest.raises(ConfigError, match=r"--config: the rig's scenario 'other' differs .* sections \["):
            node._reset(info)


@pytest.mark.parametrize(
    "args, message",
    [
        (
            ["rig", "serve", "--watchdog-timeout", "0"],
            "--watchdog-timeout: must be a number of seconds in (0, 60], got 0",
        ),
        (["rig", "serve", "--wait-controller", "nan"], "--wait-controller: must be a number of seconds"),
        (["rig", "serve", "--backend", "ur5"], "--ur-host: required with --backend ur5"),
        (["rig", "serve", "--seed", "-1"], "--seed: must be an integer in [0, 2**63 - 1], got -1"),
        (["rig", "serve", "--prefix", "a/*"], "prefix: must be chunks"),
        (["rig", "serve", "--listen", "bogus"], "endpoint: must be <protocol>/<address>"),
        (["control", "--controller", "nope"], "--controller: unknown 'nope'"),
        (["control", "--controller", "follow", "--wait", "-3"], "--wait: must be a number of seconds"),
        (
            ["control", "--controller", "follow", "--connect", "tcp/"],
            "endpoint: must be <protocol>/<address>",
        ),
    ],
)
def test_bad_options_exit_2_naming_them(args, message, capsys):
    from capsule_mpc.cli import main

    if args[0] == "rig":
        args = [*args, "--plant", "ideal", "--config", str(QUICK)]
    try:
        status = main(args)
    except SystemExit as exc:  # argparse refuses an option's value
        status = exc.code
    assert status == 2
    assert message in capsys.readouterr().err
