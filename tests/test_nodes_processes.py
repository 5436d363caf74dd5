"""The rig and the controller as two real processes on the loopback: they run a path and end
cleanly with the in-process run's physics; killing the controller node makes the rig's watchdog
brake the EPM within its limits, and a restarted controller node takes the run on; a controller
node with no rig gives up. No process is left behind (the ``procs`` fixture reaps them)."""

from __future__ import annotations

import json
import queue
import signal
import subprocess
import threading
import time
import uuid

import numpy as np
import pytest
from mcap.reader import make_reader

from capsule_mpc.experiments.runs import prepare_run
from capsule_mpc.nodes.rig import EVENTS_FILE, RigOptions, serve_rig
from capsule_mpc.nodes.transport import Transport
from capsule_mpc.sim import read_log, simulate
from capsule_mpc.sim.runner import realtime_scenario
from nodes_support import QUICK, free_endpoint, same_physics, start, waypoints


@pytest.fixture
def procs():
    """Subprocesses a test starts; any still running at the end is killed."""
    started: list[subprocess.Popen] = []
    yield started
    for p in started:
        if p.poll() is None:
            p.kill()
        p.communicate(timeout=30)
    assert all(p.returncode is not None for p in started)


def test_two_node_processes_run_and_end_cleanly(tmp_path, procs):
    wp = waypoints(tmp_path, [(-0.05, -0.03), (-0.04, -0.03)])
    config = tmp_path / "rig.yaml"  # 10 Hz frames: a loaded machine seldom delays a command 100 ms
    config.write_text(f"base: {QUICK}\ncamera:\n  rate_hz: 10.0\n")
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    common = ["--config", str(config), "--prefix", prefix]
    out = tmp_path / "rig"
    procs.append(
        start(
            [
                "rig",
                "serve",
                *common,
                "--waypoints",
                str(wp),
                "--plant",
                "ideal",
                "--seed",
                "5",
                "--listen",
                endpoint,
                "--out",
                str(out),
                "--wait-controller",
                "60",
            ]
        )
    )
    procs.append(start(["control", *common, "--controller", "follow", "--connect", endpoint, "--wait", "60"]))
    rig, ctl = procs
    rig_out, rig_err = rig.communicate(timeout=120)
    _ctl_out, ctl_err = ctl.communicate(timeout=30)
    scenario, path, _meta = prepare_run(config, wp, None, "ideal")
    ref = simulate(realtime_scenario(scenario), "follow", path, 5)
    assert ctl.returncode == 0, ctl_err
    assert rig.returncode == int(ref.failed), rig_err
    assert "follow (controller node):" in rig_out
    run = json.loads((out / "run.json").read_text())
    log = read_log(out / "log.csv")
    status = log["solver_status"].astype(str)
    missed = np.char.startswith(status, "late:") | np.char.startswith(status, "watchdog:")
    if run["metrics"].get("node_deadline_misses_motion", 0) == 0:  # every command in time: the same run
        assert same_physics(log, ref.log) == []
    else:
        # Without a command in time the rig held the previous one or, past the watchdog's timeout,
        # commanded zero: by design not the in-process run (a controller node that started late
        # did not step on those frames, so even its state differs); its log says where.
        assert missed[log["t_s"] >= 0].any()
        assert np.isfinite(run["metrics"]["tracking_rms_mm"])
    assert run["controller"] == "follow" and run["metrics"]["node_controller_ready"] == 1
    with (out / "run.mcap").open("rb") as f:  # the run's MCAP log, as simulate writes it
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count > 0
    kinds = [e["kind"] for e in json.loads((out / EVENTS_FILE).read_text())]
    assert kinds[:2] == ["controller_ready", "run_start"] and "run_end" in kinds
    assert "run_end: the rig ended run" in ctl_err


def braking_time_s(scenario, speed_mps: float) -> float:
    """An upper bound of the time a jerk-limited axis needs to stop from ``speed_mps``."""
    lim = scenario.limits
    return speed_mps / lim.accel_mps2 + lim.accel_mps2 / lim.jerk_mps3


def test_killing_the_controller_node_brakes_the_epm_and_a_restarted_one_goes_on(tmp_path, procs):
    # 13 s at 0.02 m/s: time for a new controller process to start on a loaded machine
    wp = waypoints(tmp_path, [(-0.05, -0.03), (0.05, -0.03), (0.05, 0.03), (-0.05, 0.03)])
    scenario, path, _meta = prepare_run(QUICK, wp, None, "ideal")
    endpoint, prefix = free_endpoint(), f"test/{uuid.uuid4().hex}"
    control = [
        "control",
        "--config",
        str(QUICK),
        "--prefix",
        prefix,
        "--controller",
        "follow",
        "--connect",
        endpoint,
        "--wait",
        "60",
    ]
    lines: queue.Queue[str] = queue.Queue()
    timeout_s = 0.5

    def operator() -> None:
        """Start the controller node, kill it mid-path and start another."""
        procs.append(start(control))
        wait_line(lines, "run_start")
        time.sleep(1.5)
        procs[0].send_signal(signal.SIGKILL)
        procs.append(start(control))

    with Transport(prefix, listen=[endpoint]) as rig_t:
        thread = threading.Thread(target=operator, daemon=True)
        thread.start()
        result, events = serve_rig(
            scenario,
            path,
            1,
            rig_t,
            options=RigOptions(watchdog_timeout_s=timeout_s, wait_controller_s=60),
            say=lines.put,
        )
        thread.join(30)
    assert procs[1].wait(timeout=30) == 0  # the restarted node ends with the run
    assert procs[0].wait(timeout=10) == -signal.SIGKILL
    kinds = [e["kind"] for e in events]
    assert kinds.count("controller_ready") == 2 and "controller_lost" in kinds
    assert kinds.count("watchdog_stop") >= 1 and kinds.count("watchdog_clear") >= 1
    log = result.log
    t, status = log["t_s"], log["solver_status"].astype(str)
    lost = next(e["t_s"] for e in events if e["kind"] == "controller_lost")
    stop = next(e["t_s"] for e in events if e["kind"] == "watchdog_stop" and e["t_s"] >= lost - 1.0)
    silent = t[(t < stop) & ~np.char.startswith(status, "late") & ~np.char.startswith(status, "watchdog")][-1]
    assert stop - silent <= timeout_s + 2 / scenario.camera.rate_hz + 1e-9
    # stopped within the timeout + braking time of its last command (+ a frame of the watchdog's check)
    vel = np.column_stack([log["epm_vx_mps"], log["epm_vy_mps"], log["epm_vz_mps"]])
    speed = np.abs(vel)
    v_before = speed[t <= stop].max(axis=1)[-1]
    brake = braking_time_s(scenario, v_before) + 1 / scenario.camera.rate_hz
    held = (t >= stop + brake) & (t < stop + brake + 0.2)
    assert held.any() and speed[held].max() < 1e-6
    # no limit exceeded: speed per axis, and the arm's own check of the joint commands it ran
    assert speed.max() <= scenario.limits.speed_mps + 1e-9
    # the logged velocity is the arm's latest setpoint (its own ticks), read at the frame times: a
    # difference over one frame is within a tick's share of the limit
    accel = np.abs(np.diff(vel, axis=0)) / np.diff(t)[:, None]
    tick_share = scenario.camera.rate_hz / scenario.arm.arm_rate_hz
    assert accel.max() <= scenario.limits.accel_mps2 * (1 + 2 * tick_share)
    assert result.flags.arm_failure == ""
    # the rig stayed alive and the run went on under the restarted controller
    clear = [e["t_s"] for e in events if e["kind"] == "watchdog_clear"][-1]
    after = (t > clear) & (t < path.duration_s)
    assert after.any() and np.mean(status[after] == "ok") >= 0.8  # answered (a loaded machine may miss some)
    assert np.hypot(log["epm_vx_mps"][after], log["epm_vy_mps"][after]).max() > 0.01
    assert result.metrics["node_watchdog_stop"] >= 1 and result.metrics["node_controller_lost"] >= 1


def wait_line(lines: queue.Queue, word: str, timeout_s: float = 60.0) -> str:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            line = lines.get(timeout=0.1)
        except queue.Empty:
            continue
        if f": {word}:" in line:
            return line
    raise AssertionError(f"no {word!r} event within {timeout_s} s")


def test_a_controller_node_without_a_rig_gives_up_after_its_wait(procs):
    proc = start(
        [
            "control",
            "--controller",
            "follow",
            "--connect",
            free_endpoint(),
            "--prefix",
            f"test/{uuid.uuid4().hex}",
            "--wait",
            "1",
        ]
    )
    procs.append(proc)
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1 and "no rig run on" in err
