"""Fault injection: rates, reproducibility, and the controller holding up."""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass

import numpy as np
import pytest

from capsule_mpc.cli import main
from capsule_mpc.config import CameraConfig, FaultsConfig
from capsule_mpc.interfaces import Measurement
from capsule_mpc.mpc import MPCController
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import Camera, draw_plant_truth, simulate
from capsule_mpc.sim.faults import (
    FAULT_KINDS,
    RECOVERY_TOL_MM,
    FaultEvent,
    FaultInjector,
    recovery_times,
)

FRAME_S = 1 / 30
N_FRAMES = 3000  # 100 s of frames
PATH = ReferencePath(np.array([[0.0, 0.0], [0.03, 0.0], [0.03, 0.015]]), closed=False, speed_mps=0.02)
#: Every fault on at rates that hit a 3-4 s run several times.
ALL_ON = {
    "solver_failure_probability": 0.1,
    "solver_nan_probability": 0.1,
    "solver_late_probability": 0.1,
    "camera_drop_burst_rate_hz": 0.5,
    "camera_outlier_probability": 0.05,
    "arm_stall_rate_hz": 0.5,
    "latency_spike_probability": 0.05,
}


def _band(count: int, n: int, p: float, sds: float = 5.0) -> bool:
    """Whether ``count`` is within ``sds`` standard deviations of a Binomial(n, p) mean."""
    mean, sd = n * p, math.sqrt(n * p * (1 - p))
    return abs(count - mean) <= sds * sd


@dataclass(frozen=True)
class _Result:
    """The fields of a SolveResult the injector touches."""

    success: bool
    status: str
    solve_ms: float
    w: np.ndarray


def _solver_run(config: FaultsConfig, seed: int) -> tuple[FaultInjector, list[_Result]]:
    inj = FaultInjector(config, seed, FRAME_S)
    out = []
    for j in range(N_FRAMES):
        inj.begin_frame(j * FRAME_S)
        out.append(inj.corrupt_solve(_Result(True, "step", 1.0, np.zeros(4))))
    return inj, out


def test_all_faults_are_off_by_default(scenario):
    assert not scenario.faults.enabled
    assert not FaultsConfig().enabled
    assert FaultsConfig(camera_outlier_probability=0.1).enabled
    assert not FaultsConfig(camera_outlier_probability=0.1).solver_enabled


def test_solver_faults_hit_at_their_rate_and_do_what_they_say():
    cfg = FaultsConfig(
        solver_failure_probability=0.1, solver_nan_probability=0.05, solver_late_probability=0.2
    )
    inj, results = _solver_run(cfg, seed=7)
    for kind, p in (("solver_failure", 0.1), ("solver_nan", 0.05), ("solver_late", 0.2)):
        assert _band(inj.counts[kind], N_FRAMES, p), (kind, inj.counts[kind])
    failed = sum(not r.success for r in results)
    assert failed == inj.counts["solver_failure"]
    nan = [r for r in results if not np.all(np.isfinite(r.w))]
    assert len(nan) == inj.counts["solver_nan"]
    assert sum(r.solve_ms == 1.0 + cfg.solver_late_ms for r in results) == inj.counts["solver_late"]
    # A NaN with no failure on the same frame reports success: the controller must not trust it.
    assert any(r.success for r in nan)


def test_a_failed_frame_fails_its_recovery_solves_too_and_counts_once():
    inj = FaultInjector(FaultsConfig(solver_failure_probability=1.0), 0, FRAME_S)
    inj.begin_frame(0.0)
    first = inj.corrupt_solve(_Result(True, "step", 1.0, np.zeros(2)))
    again = inj.corrupt_solve(_Result(True, "converged", 1.0, np.zeros(2)))
    assert not first.success and not again.success
    assert inj.counts["solver_failure"] == 1
    inj.begin_frame(-FRAME_S)  # the settle phase is fault free
    assert inj.corrupt_solve(_Result(True, "step", 1.0, np.zeros(2))).success


def test_faults_are_reproducible_from_the_seed_and_each_kind_has_its_own_stream():
    cfg = FaultsConfig(**ALL_ON)
    a, _ = _solver_run(cfg, 3)
    b, _ = _solver_run(cfg, 3)
    c, _ = _solver_run(cfg, 4)
    assert a.events == b.events
    assert a.events != c.events
    # Switching another kind on leaves the failures where they were.
    only, _ = _solver_run(FaultsConfig(solver_failure_probability=0.1), 3)
    failures = [e for e in a.events if e.kind == "solver_failure"]
    assert failures == [e for e in only.events if e.kind == "solver_failure"]


def _camera_run(config: FaultsConfig, seed: int = 0, latency: int = 1) -> tuple[Camera, list]:
    inj = FaultInjector(config, seed, FRAME_S, latency)
    cam_cfg = CameraConfig(noise_std_m=3e-4, latency_frames=latency)
    cam = Camera(cam_cfg, np.random.default_rng(seed), faults=inj)
    return cam, [cam.frame(j * FRAME_S, np.zeros(2)) for j in range(N_FRAMES)]


def test_drop_bursts_start_at_their_rate_and_last_at_most_their_length():
    cfg = FaultsConfig(camera_drop_burst_rate_hz=0.5, camera_drop_burst_max_s=0.5)
    cam, frames = _camera_run(cfg)
    inj = cam.faults
    assert inj is not None
    bursts = inj.counts["camera_drop"]
    lost = sum(f.position_m is None for f in frames) - 1  # the first frame is in flight
    assert lost == inj.dropped_frames
    # A burst can start on every frame outside a burst (and on a burst's first frame).
    eligible = N_FRAMES - inj.dropped_frames + bursts
    assert _band(bursts, eligible, -math.expm1(-0.5 * FRAME_S)), bursts
    for ev in inj.events:
        assert ev.end_s - ev.start_s <= 0.5 + 2 * FRAME_S + 1e-9  # lost frames + the latency
    # Runs of lost frames are at most 0.5 s long (15 frames), back to back at worst.
    runs, length = [], 0
    for f in frames[1:]:
        length = length + 1 if f.position_m is None else 0
        runs.append(length)
    assert max(runs) <= 2 * math.ceil(0.5 / FRAME_S)


def test_outliers_jump_by_their_size_at_their_rate_and_leave_the_camera_noise_alone():
    cfg = FaultsConfig(camera_outlier_probability=0.05, camera_outlier_m=0.01)
    cam, frames = _camera_run(cfg)
    _, clean = _camera_run(FaultsConfig())
    assert cam.faults is not None
    n = cam.faults.counts["camera_outlier"]
    assert _band(n, N_FRAMES, 0.05), n
    jumps = [
        float(np.linalg.norm(f.position_m - g.position_m))
        for f, g in zip(frames[1:], clean[1:])
        if not np.array_equal(f.position_m, g.position_m)
    ]
    assert n - 1 <= len(jumps) <= n  # an outlier on the last frame is still in flight
    assert jumps == pytest.approx([0.01] * len(jumps), abs=1e-12)


def test_stalls_and_latency_spikes_hit_at_their_rates():
    cfg = FaultsConfig(arm_stall_rate_hz=0.5, arm_stall_s=0.5, latency_spike_probability=0.02)
    inj = FaultInjector(cfg, 5, FRAME_S)
    eligible, spikes = 0, []
    for j in range(N_FRAMES):
        t = j * FRAME_S
        eligible += int(t >= inj.stall_end_s)
        inj.stall_starts(t)
        spikes.append(inj.latency_spike_s(t))
    assert _band(inj.counts["arm_stall"], eligible, -math.expm1(-0.5 * FRAME_S))
    assert _band(inj.counts["latency_spike"], N_FRAMES, 0.02)
    assert set(spikes) == {0.0, 0.1}
    stalls = [e for e in inj.events if e.kind == "arm_stall"]
    assert all(b.start_s >= a.end_s - 1e-9 for a, b in itertools.pairwise(stalls))  # never overlapping


def test_recovery_time_is_measured_from_the_fault_end_to_the_pre_fault_level():
    t = np.arange(0, 5, FRAME_S)
    err = np.full_like(t, 0.5)
    err[(t >= 2.0) & (t < 3.0)] = 4.0  # the fault's effect outlasts it by 0.5 s
    ev = FaultEvent("arm_stall", 2.0, 2.5)
    rec = recovery_times(t, err, [ev])
    assert rec.times_s["arm_stall"] == pytest.approx([0.5], abs=FRAME_S)
    # A run already above 1 mm recovers to its own pre-fault mean.
    rec = recovery_times(t, err + 2.0, [ev])
    assert rec.times_s["arm_stall"] == pytest.approx([0.5], abs=FRAME_S)
    assert RECOVERY_TOL_MM == 1.0
    never = recovery_times(t, np.where(t >= 2.0, 9.0, 0.5), [ev])
    assert never.unrecovered == {"arm_stall": 1} and not never.times_s


def test_faults_do_not_change_the_plant_draw(lab_scenario):
    faulty = lab_scenario.model_copy(update={"faults": FaultsConfig(**ALL_ON)})
    assert draw_plant_truth(faulty, 11).values == draw_plant_truth(lab_scenario, 11).values


@pytest.fixture(scope="module")
def faulty(lab_scenario):
    """The lab rig, every fault on, the MPC falling back on late solves, a short run.

    The deadline (500 ms) is one no real solve here misses and every injected late one (1 s) does,
    so the run does not depend on this machine's speed.
    """
    mpc = {"compile_c": False, "enforce_deadline": True, "deadline_ms": 500.0}
    return lab_scenario.model_copy(
        update={
            "mpc": lab_scenario.mpc.model_copy(update=mpc),
            "sim": lab_scenario.sim.model_copy(update={"settle_s": 0.5, "tail_s": 3.0}),
            "faults": FaultsConfig(**ALL_ON, solver_late_ms=1000.0),
        }
    )


@pytest.fixture(scope="module")
def faulty_run(faulty):
    return simulate(faulty, MPCController(), PATH, seed=2)


def test_mpc_under_every_fault_sends_finite_commands_within_every_limit(faulty, faulty_run):
    log, lim = faulty_run.log, faulty.limits
    m = faulty_run.metrics
    for kind in FAULT_KINDS:
        assert m[f"faults_injected_{kind}"] > 0, kind  # every kind was exercised
    u = np.stack([log["cmd_vx_mps"], log["cmd_vy_mps"], log["cmd_vz_mps"]], axis=1)
    assert np.all(np.isfinite(u))
    assert np.abs(u).max() <= lim.speed_mps + 1e-12
    du = np.abs(np.diff(u, axis=0))
    assert du.max() <= lim.accel_mps2 * FRAME_S + 1e-12  # no jump, frame to frame
    epm = np.stack([log["epm_x_m"], log["epm_y_m"], log["epm_z_m"]], axis=1)
    assert np.all(epm >= np.asarray(lim.workspace_min_m) - 1e-12)
    assert np.all(epm <= np.asarray(lim.workspace_max_m) + 1e-12)
    assert m["invalid_commands"] == 0
    assert not m["decoupled"] and not m["dropped"]
    status = log["solver_status"]
    assert any("injected failure" in s for s in status)
    assert any("non-finite solution (injected NaN)" in s for s in status)
    assert any(s.startswith("late:") for s in status)
    # Every outlier that was delivered was rejected or re-acquired past (none is fused).
    assert m["measurements_rejected"] >= 1
    assert math.isfinite(m["fault_recovery_max_s"])


def test_a_faulty_run_is_reproducible_from_its_seed(faulty, faulty_run):
    again = simulate(faulty, MPCController(), PATH, seed=2)
    assert again.fault_events == faulty_run.fault_events
    for kind in FAULT_KINDS:
        key = f"faults_injected_{kind}"
        assert again.metrics[key] == faulty_run.metrics[key]
    np.testing.assert_array_equal(again.log["capsule_x_m"], faulty_run.log["capsule_x_m"])


def test_a_stalled_arm_brakes_to_rest_and_then_follows_again(lab_scenario):
    cfg = lab_scenario.model_copy(
        update={
            "sim": lab_scenario.sim.model_copy(update={"settle_s": 0.2, "tail_s": 2.0}),
            "faults": FaultsConfig(arm_stall_rate_hz=1.0, arm_stall_s=0.5),
        }
    )
    run = simulate(cfg, "follow", PATH, seed=1)
    stalls = [e for e in run.fault_events if e.kind == "arm_stall"]
    assert stalls and run.metrics["faults_injected_arm_stall"] == len(stalls)
    t = run.log["t_s"]
    speed = np.hypot(run.log["epm_vx_mps"], run.log["epm_vy_mps"])
    braking_s = cfg.limits.speed_mps / cfg.limits.accel_mps2  # the longest stop at the accel limit
    for ev in stalls:
        held = (t >= ev.start_s + braking_s + 0.01) & (t < ev.end_s - 1e-9)
        assert np.all(speed[held] < cfg.sim.rest_speed_mps)  # at rest, behind the servo lag
        after = (t > ev.end_s + 0.2) & (t < ev.end_s + 0.4) & (t < PATH.duration_s)
        for other in stalls:
            after &= (t < other.start_s) | (t >= other.end_s)
        assert not np.any(after) or np.all(speed[after] > 0)


@pytest.mark.parametrize("command", ["compare", "sweep"])
def test_fault_counts_reach_the_summary_of_compare_and_sweep(tmp_path, command, monkeypatch):
    import capsule_mpc.experiments.sweep.campaign as campaign

    # the sweep's 12 figures are not the subject (test_sweep.py checks them)
    monkeypatch.setattr(campaign, "write_figures", lambda out, per_seed, **kw: [])
    config = tmp_path / "c.yaml"
    config.write_text(
        "base: paper\nsim:\n  settle_s: 0.2\n  tail_s: 1.0\n"
        "faults:\n  camera_outlier_probability: 0.2\n  latency_spike_probability: 0.1\n"
    )
    wp = tmp_path / "wp.csv"
    wp.write_text("x_m,y_m\n0.0,0.0\n0.02,0.0\n")
    out = tmp_path / "out"
    extra = ["--no-progress"] if command == "compare" else ["--workers", "1"]
    argv = [
        command,
        "--config",
        str(config),
        "--waypoints",
        str(wp),
        "--controllers",
        "follow",
        "--runs",
        "2",
        "--out",
        str(out),
        *extra,
    ]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    follow = summary["controllers"]["follow"]
    runs = [r["controllers"]["follow"] for r in summary["runs"]]
    for key in ("faults_injected_camera_outlier", "faults_injected_latency_spike"):
        counts = [r[key] for r in runs]
        assert min(counts) > 0
        assert follow[key] == pytest.approx(np.mean(counts))
        assert follow["spread"][key]["max"] == max(counts)
    assert follow["faults_injected_solver_failure"] == 0  # switched off: counted as 0
    assert "fault_recovery_max_s" in follow


def test_a_dropped_or_rejected_frame_does_not_move_the_disturbance_estimate(scenario):
    fast = scenario.model_copy(update={"mpc": scenario.mpc.model_copy(update={"compile_c": False})})
    ctrl = MPCController()
    epm = np.array([-0.017, 0.0, fast.plate.epm_height_m])
    ctrl.reset(fast, PATH, epm)

    def step(k: int, position: np.ndarray | None) -> None:
        nonlocal epm
        t = k * FRAME_S
        cmd = ctrl.step(t, Measurement(t, t - FRAME_S, position), epm)
        epm = epm + FRAME_S * cmd.epm_velocity_mps

    for k in range(20):  # the capsule moving at 18 mm/s, seen every frame
        step(k, PATH.position(max((k - 1) * FRAME_S, 0)) * 0.9)
    before = ctrl.disturbance_n.copy()
    assert np.any(before != 0)  # it is being learned
    step(20, None)  # a dropped frame
    step(21, PATH.position(20 * FRAME_S) * 0.9 + np.array([0.0, 0.01]))  # a 10 mm outlier
    assert ctrl.estimator.rejected == 1
    np.testing.assert_array_equal(ctrl.disturbance_n, before)


def test_recovery_against_the_fault_free_run_leaves_out_the_paths_own_excursions():
    t = np.arange(0, 5, FRAME_S)
    clean = np.where((t >= 2.0) & (t < 4.0), 5.0, 0.5)  # a corner: the error rises anyway
    faulty = clean.copy()
    faulty[(t >= 2.0) & (t < 2.5)] += 2.0  # the fault adds 2 mm until 2.5 s
    ev = FaultEvent("solver_nan", 2.0, 2.0 + FRAME_S)
    assert recovery_times(t, faulty, [ev]).times_s["solver_nan"][0] == pytest.approx(2.0, abs=FRAME_S)
    twin = recovery_times(t, faulty, [ev], clean)
    assert twin.times_s["solver_nan"][0] == pytest.approx(0.5 - FRAME_S, abs=FRAME_S)
