"""The rig and the controller as nodes in one process: the same physics as the in-process loop
when the commands come in time; a controller node refusing another scenario; bad options."""

from __future__ import annotations

import threading
import uuid

import pytest

from capsule_mpc.errors import ConfigError
from capsule_mpc.experiments.runs import prepare_run
from capsule_mpc.nodes import messages as m
from capsule_mpc.nodes.controller import ControllerNode, ControlOptions
from capsule_mpc.nodes.rig import RigOptions, serve_rig
from capsule_mpc.nodes.transport import Transport
from capsule_mpc.sim import simulate
from capsule_mpc.sim.runner import realtime_scenario
from nodes_support import QUICK, free_endpoint, same_physics, waypoints


def run_in_process(scenario, path, seed, controller, *, watchdog_s=0.5):
    """The rig and a controller node as two sessions of this process (the node in a thread)."""
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    status: dict[str, int] = {}
    with Transport(prefix, listen=[endpoint]) as rig_t, Transport(prefix, connect=[endpoint]) as ctl_t:
        node = ControllerNode(ctl_t, scenario, controller, ControlOptions(wait_s=60), say=lambda _t: None)
        thread = threading.Thread(target=lambda: status.setdefault("rc", node.run()), daemon=True)
        thread.start()
        result, events = serve_rig(
            scenario, path, seed, rig_t, say=lambda _t: None,
            options=RigOptions(watchdog_timeout_s=watchdog_s, wait_controller_s=60),
        )  # fmt: skip
        thread.join(10)
    return result, events, status.get("rc"), node


@pytest.mark.parametrize(
    "controller, plant", [("follow", "ideal"), pytest.param("mpc", "lab", marks=pytest.mark.slow)]
)
def test_nodes_in_time_give_the_in_process_run(tmp_path, controller, plant):
    wp = waypoints(tmp_path, [(-0.05, -0.03), (-0.035, -0.03)])
    scenario, path, _meta = prepare_run(QUICK, wp, None, plant)
    if controller == "mpc":  # uncompiled NLP functions: built in well under a second
        scenario = scenario.model_copy(update={"mpc": scenario.mpc.model_copy(update={"compile_c": False})})
    result, events, rc, node = run_in_process(scenario, path, 2, controller)
    assert rc == 0 and not node.counts["frames_lost"]
    ref = simulate(realtime_scenario(scenario), controller, path, 2)
    misses = (
        result.metrics["node_deadline_misses_motion"]
        if "node_deadline_misses_motion" in result.metrics
        else 0
    )
    assert [e["kind"] for e in events][:2] == ["controller_ready", "run_start"]
    assert result.controller == controller
    if misses == 0 and result.metrics.get("node_deadline_misses", 0) == 0:
        assert same_physics(result.log, ref.log) == []
    else:  # a loaded machine made commands late: the same run within the timing they add
        assert result.metrics["tracking_rms_mm"] == pytest.approx(ref.metrics["tracking_rms_mm"], rel=0.05)


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
        (["rig", "serve", "--backend", "ur5"], "--backend: ur5 is not installed"),
        (["rig", "serve", "--seed", "-1"], "--seed: must be an integer >= 0"),
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
