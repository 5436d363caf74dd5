"""The offline planner: constraints and dynamics of its plans, minimum time, open-loop replay, CLI."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from capsule_mpc.arm import read_epm_plan_csv
from capsule_mpc.cli import main
from capsule_mpc.config import config_from_dict
from capsule_mpc.interfaces import Measurement, available_controllers
from capsule_mpc.magnetics import capsule_force_function, equilibrium_lead
from capsule_mpc.paths import ReferencePath
from capsule_mpc.planner import (
    PLAN_COLUMNS,
    PlanError,
    PlannerOptions,
    PlanReplay,
    cached_plan,
    constraint_report,
    dynamics_residual,
    path_point_expr,
    plan_path,
    read_plan_csv,
)
from capsule_mpc.sim import simulate

#: An L-shaped open path: 30 mm along x, then 20 mm along y, at the paper's 0.02 m/s (2.5 s).
L_POINTS = np.array([[0.0, 0.0], [0.03, 0.0], [0.03, 0.02]])
#: Slack in the constraint checks (IPOPT's tolerance plus bound relaxation).
TOL = 1e-6


@pytest.fixture(scope="module")
def path() -> ReferencePath:
    return ReferencePath(L_POINTS, False, 0.02)


@pytest.fixture(scope="module")
def fixed(scenario, path):
    return cached_plan(scenario, path, "fixed")


@pytest.fixture(scope="module")
def min_time(scenario, path):
    return cached_plan(scenario, path, "min_time")


def _with(scenario, **sections):
    data = scenario.model_dump(mode="json", exclude_none=True)
    for section, values in sections.items():
        data[section] |= values
    return config_from_dict(data)


def _assert_within_limits(scenario, plan, path) -> dict:
    lim = scenario.limits
    r = constraint_report(scenario, plan, path)
    assert r["max_speed_mps"] <= lim.speed_mps + TOL
    assert r["max_accel_mps2"] <= lim.accel_mps2 * (1 + TOL)
    assert r["workspace_violation_m"] <= TOL
    assert r["max_coupling_m"] <= lim.max_lead_m + TOL
    assert lim.normal_force_min_n - TOL <= r["min_normal_force_n"]
    assert r["max_normal_force_n"] <= lim.normal_force_max_n + TOL
    assert r["max_slack"] <= TOL
    assert r["end_error_m"] <= np.sqrt(2) * PlannerOptions().end_tol_m + TOL
    assert r["end_speed_mps"] <= TOL
    if not scenario.mpc.height_control:
        assert np.ptp(plan.epm_position_m[:, 2]) <= TOL
    return r


def test_fixed_plan_meets_every_limit_and_tracks_the_path(scenario, path, fixed):
    assert fixed.success, fixed.status
    r = _assert_within_limits(scenario, fixed, path)
    # Strong cross-track weight: the capsule stays within half a millimetre, even at the corner.
    assert r["cross_track_max_m"] < 5e-4
    assert fixed.duration_s == pytest.approx(path.duration_s + PlannerOptions().tail_s, abs=fixed.dt_s)
    assert fixed.dt_s == pytest.approx(1 / scenario.camera.rate_hz)
    assert r["arrival_s"] <= path.duration_s + 0.5


def test_plan_starts_at_rest_at_the_model_equilibrium(scenario, path, fixed):
    force = capsule_force_function(scenario)
    lead = equilibrium_lead(lambda x: np.asarray(force(x, scenario.plate.epm_height_m)).ravel())
    np.testing.assert_allclose(fixed.capsule_position_m[0], path.start_m, atol=1e-12)
    np.testing.assert_allclose(fixed.capsule_velocity_mps[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(fixed.epm_position_m[0, :2], path.start_m + lead, atol=1e-9)
    assert fixed.epm_position_m[0, 2] == pytest.approx(scenario.plate.epm_height_m)
    # The first command respects the acceleration limit from rest, the last one stops the EPM.
    assert np.abs(fixed.epm_velocity_mps[0]).max() <= scenario.limits.accel_mps2 * fixed.dt_s + TOL
    assert np.abs(fixed.epm_velocity_mps[-1]).max() <= TOL


def test_dynamics_residual_is_small_and_detects_a_wrong_state(scenario, fixed, min_time):
    for plan in (fixed, min_time):
        res = dynamics_residual(scenario, plan)
        assert res.position_m < 1e-8 and res.velocity_mps < 1e-7 and res.epm_m < 1e-9
        assert plan.residual == res
    # The check is independent of the NLP: a plan whose states do not follow the model fails it.
    moved = fixed.capsule_position_m.copy()
    moved[40:] += [0.0, 1e-3]
    bad = replace(fixed, capsule_position_m=moved)
    assert dynamics_residual(scenario, bad).position_m > 5e-4


def test_dynamics_residual_never_raises_and_counts_unsolved_steps(scenario, fixed):
    """A step no root finding can solve (a non-finite state) is counted, never raised."""
    states = fixed.capsule_velocity_mps.copy()
    states[7] = np.nan
    broken = replace(fixed, capsule_velocity_mps=states)
    res = dynamics_residual(scenario, broken)
    assert res.unsolved_steps >= 1 and res.velocity_mps == np.inf
    assert dynamics_residual(scenario, fixed).unsolved_steps == 0


def test_dynamics_residual_reseeds_a_step_the_start_state_cannot_solve(scenario, fixed, monkeypatch):
    """Where Newton from the step's start fails, the plan's own next state is tried: a plan that
    solves its equations then has a small residual, and the step is counted as re-seeded."""
    import capsule_mpc.planner.core as core

    real = core.ca.rootfinder

    def stalls_from_the_start(name, solver, fn, opts):  # one iteration: cannot converge from x_k
        return real(name, solver, fn, {**opts, "max_iter": 1})

    monkeypatch.setattr(core.ca, "rootfinder", stalls_from_the_start)
    res = dynamics_residual(scenario, fixed)
    assert res.reseeded_steps > 0 and res.unsolved_steps == 0
    assert res.position_m < 1e-8 and res.velocity_mps < 1e-7


def test_min_time_is_faster_within_the_tube_and_the_same_limits(scenario, path, fixed, min_time):
    assert min_time.success, min_time.status
    r = _assert_within_limits(scenario, min_time, path)
    assert min_time.duration_s < fixed.duration_s
    assert min_time.duration_s < path.duration_s
    assert r["cross_track_max_m"] <= PlannerOptions().tube_m + TOL
    prog = min_time.progress_m
    assert prog is not None and prog[0] == pytest.approx(0.0) and prog[-1] == pytest.approx(path.length_m)
    assert np.all(np.diff(prog) >= -TOL)
    # It is limited by the EPM speed: somewhere it runs at the limit.
    assert r["max_speed_mps"] == pytest.approx(scenario.limits.speed_mps, rel=1e-3)


def test_tighter_limits_are_honoured(scenario, path):
    tight = _with(scenario, limits={"speed_mps": 0.03, "accel_mps2": 0.15})
    plan = plan_path(tight, path, "fixed")
    assert plan.success, plan.status
    r = _assert_within_limits(tight, plan, path)
    assert r["max_accel_mps2"] == pytest.approx(0.15, rel=1e-3)  # active: the limit binds


def test_an_infeasible_coupling_limit_is_softened_not_failed(scenario, path):
    # The tether drag alone needs a lead offset of more than 1 mm to move the capsule: a 1 mm
    # coupling limit cannot hold while it moves, and the slack takes the excess.
    tight = _with(scenario, limits={"max_lead_m": 0.001})
    plan = plan_path(tight, path, "fixed")
    assert plan.success, plan.status
    r = constraint_report(tight, plan, path)
    assert r["max_coupling_m"] > 0.001
    assert r["max_slack"] > 0.01
    assert r["end_error_m"] <= np.sqrt(2) * PlannerOptions().end_tol_m + TOL


def test_a_failed_solve_is_a_value(scenario, path):
    plan = plan_path(scenario, path, "fixed", PlannerOptions(max_iter=2))
    assert not plan.success
    assert plan.status == "Maximum_Iterations_Exceeded"
    assert plan.iterations == 2


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="variant"):
        plan_path(None, None, "fastest")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="tube_m"):
        PlannerOptions(tube_m=0.0)
    with pytest.raises(ValueError, match="max_iter"):
        PlannerOptions(max_iter=0)
    with pytest.raises(ValueError, match="path_smoothing_m"):
        PlannerOptions(tube_m=1e-4, path_smoothing_m=2e-4)
    with pytest.raises(ValueError, match="position_gain_per_s"):
        PlanReplay(position_gain_per_s=-1.0)


def _gamma(path, smoothing_m):
    import casadi as ca

    s = ca.SX.sym("s")
    return ca.Function("gamma", [s], [path_point_expr(path, s, smoothing_m)])


@settings(max_examples=50, deadline=None)
@given(st.floats(-0.01, 0.07))
def test_path_point_expression_matches_the_polyline(sigma):
    path = ReferencePath(L_POINTS, False, 0.02)
    point = np.asarray(_gamma(path, 0.0)(sigma)).ravel()
    np.testing.assert_allclose(point, path.point_at_arc(sigma), atol=1e-15)


@settings(max_examples=50, deadline=None)
@given(st.floats(0.0, 0.05), st.floats(1e-5, 1e-3))
def test_smoothed_path_stays_within_half_the_smoothing_of_the_polyline(sigma, delta):
    path = ReferencePath(L_POINTS, False, 0.02)
    point = np.asarray(_gamma(path, delta)(sigma)).ravel()
    assert path.distance_to(point)[0] <= delta / 2 + 1e-12
    if 20 * delta < sigma < 0.03 - 20 * delta:  # far from the vertices: (almost) the exact point
        np.testing.assert_allclose(point, path.point_at_arc(sigma), atol=delta / 20)


def test_min_time_does_not_depend_on_the_nominal_speed(scenario, path, min_time):
    slow = cached_plan(scenario, path.with_speed(0.01), "min_time")
    assert slow.success, slow.status
    assert slow.duration_s == pytest.approx(min_time.duration_s, rel=1e-4)
    assert slow.nominal_duration_s == pytest.approx(2 * min_time.nominal_duration_s)


def test_plan_controller_is_registered_and_replays_open_loop(scenario, path):
    assert "plan" in available_controllers()
    # cut off 1 s after 1.25 x the path's time (the replay holds the EPM still from the plan's end)
    quick = scenario.model_copy(update={"sim": scenario.sim.model_copy(update={"tail_s": 1.0})})
    runs = [simulate(quick, "plan", path, seed) for seed in (0, 1)]
    lim = scenario.limits
    for run in runs:
        assert not run.flags.decoupled and not run.flags.dropped
        assert run.flags.invalid_commands == 0
        log = run.log
        cmd = np.column_stack([log["cmd_vx_mps"], log["cmd_vy_mps"], log["cmd_vz_mps"]])
        assert np.abs(cmd).max() <= lim.speed_mps + 1e-12
        assert np.abs(np.diff(cmd, axis=0)).max() <= lim.accel_mps2 / scenario.camera.rate_hz + 1e-12
        assert np.all(cmd[log["t_s"] < 0] == 0)
        assert {s.status for s in run.step_stats} >= {"settle", "replay"}
        assert run.metrics["cross_track_max_mm"] < 5.0
    # Open loop: different camera noise (seeds), identical commands.
    a, b = (np.column_stack([r.log["cmd_vx_mps"], r.log["cmd_vy_mps"]]) for r in runs)
    n = min(len(a), len(b))
    np.testing.assert_array_equal(a[:n], b[:n])


def test_replay_follows_the_plan_and_holds_after_it(scenario, path, fixed):
    ctrl = PlanReplay()
    epm0 = fixed.epm_position_m[0] + [0.001, 0.0, 0.0]  # the rig's EPM starts 1 mm off the plan
    ctrl.reset(scenario, path, epm0)
    meas = Measurement(0.0, 0.0, None)
    assert np.all(ctrl.step(-0.5, meas, epm0).epm_velocity_mps == 0)
    k = 30
    t = fixed.t_s[k]
    epm = fixed.epm_position_m[k] + [0.001, 0.0, 0.0]  # exactly on the anchored plan
    ctrl.u_prev = fixed.epm_velocity_mps[k - 1].copy()
    cmd = ctrl.step(t, Measurement(t, t, np.zeros(2)), epm)
    np.testing.assert_allclose(cmd.epm_velocity_mps, fixed.epm_velocity_mps[k], atol=1e-9)
    end = fixed.epm_position_m[-1] + [0.001, 0.0, 0.0]
    ctrl.u_prev = np.zeros(3)
    late = ctrl.step(fixed.duration_s + 1.0, meas, end)
    assert late.stats.status == "done"
    np.testing.assert_allclose(late.epm_velocity_mps, 0.0, atol=1e-12)


def test_replay_of_a_failed_plan_raises_instead_of_running(scenario, path):
    """No plan, no run: holding the EPM still would be scored as the controller's result."""
    ctrl = PlanReplay(options=PlannerOptions(max_iter=2))
    with pytest.raises(
        PlanError, match=r"did not converge: IPOPT returned Maximum_Iterations_Exceeded after 2 it"
    ):
        ctrl.reset(scenario, path, np.array([0.0, 0.0, 0.095]))
    with pytest.raises(RuntimeError, match="reset"):
        ctrl.step(1.0, Measurement(1.0, 1.0, np.zeros(2)), np.array([0.0, 0.0, 0.095]))


def test_simulate_with_a_failed_plan_exits_1_naming_the_solve(tmp_path, monkeypatch, capsys):
    import capsule_mpc.planner.replay as replay

    monkeypatch.setattr(
        replay, "cached_plan", lambda sc, p, v, o: cached_plan(sc, p, v, PlannerOptions(max_iter=2))
    )
    wp = _waypoints(tmp_path, "0.0,0.0\n0.03,0.0\n")
    out = tmp_path / "sim"
    args = ["simulate", "--controller", "plan", "--waypoints", str(wp), "--out", str(out), "--no-progress"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "plan controller: no plan to replay" in err and "Maximum_Iterations_Exceeded" in err
    assert "Traceback" not in err
    assert not out.exists()


def _waypoints(tmp_path, rows: str):
    file = tmp_path / "wp.csv"
    file.write_text("x_m,y_m\n" + rows)
    return file


def test_cli_writes_the_plan_and_the_arm_files(tmp_path, capsys, scenario):
    wp = _waypoints(tmp_path, "0.0,0.0\n0.03,0.0\n0.03,0.02\n")
    out = tmp_path / "plan"
    assert main(["plan", "--waypoints", str(wp), "--out", str(out)]) == 0
    names = {p.name for p in out.iterdir()}
    expected = {"epm_plan.csv", "plan.json", "config.yaml", "plan.png", "epm_trajectory.csv"}
    assert expected | {"joint_trajectory.csv", "joint_trajectory.yaml", "joint_trajectory.png"} <= names
    cols = read_plan_csv(out / "epm_plan.csv")
    assert tuple(cols) == PLAN_COLUMNS
    summary = json.loads((out / "plan.json").read_text())
    assert summary["success"] and summary["variant"] == "fixed"
    assert summary["iterations"] > 0 and summary["solve_s"] > 0
    assert summary["residual"]["position_m"] < 1e-8
    assert summary["nominal_duration_s"] == pytest.approx(2.5)
    # The arm's reader takes the plan CSV as it is.
    t, p = read_epm_plan_csv(out / "epm_plan.csv")
    np.testing.assert_allclose(t, cols["t_s"])
    np.testing.assert_allclose(p[:, 2], scenario.plate.epm_height_m)
    assert "Solve_Succeeded" in capsys.readouterr().out


def test_cli_min_time_without_arm(tmp_path):
    wp = _waypoints(tmp_path, "0.0,0.0\n0.03,0.0\n0.03,0.02\n")
    out = tmp_path / "mt"
    assert main(["plan", "--waypoints", str(wp), "--out", str(out), "--variant", "min_time", "--no-arm"]) == 0
    summary = json.loads((out / "plan.json").read_text())
    assert summary["variant"] == "min_time"
    assert summary["duration_s"] < summary["nominal_duration_s"]
    assert not (out / "joint_trajectory.csv").exists()


def test_cli_bad_input_exits_2_with_a_clear_message(tmp_path, capsys):
    outside = _waypoints(tmp_path, "0.0,0.0\n0.5,0.0\n")
    assert main(["plan", "--waypoints", str(outside), "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert "line 3" in err and "outside the workspace" in err
    assert main(["plan", "--speed", "-0.01", "--out", str(tmp_path / "b")]) == 2
    assert "speed" in capsys.readouterr().err
    missing = tmp_path / "missing.yaml"
    assert main(["plan", "--config", str(missing), "--out", str(tmp_path / "c")]) == 2
    with pytest.raises(SystemExit) as exc:
        main(["plan", "--variant", "fastest", "--out", str(tmp_path / "d")])
    assert exc.value.code == 2


def test_cli_failed_solve_exits_1(tmp_path, monkeypatch, capsys):
    import capsule_mpc.experiments.plan as planning

    real = planning.plan_path
    monkeypatch.setattr(
        planning, "plan_path", lambda sc, p, v, **kw: real(sc, p, v, PlannerOptions(max_iter=2), **kw)
    )
    wp = _waypoints(tmp_path, "0.0,0.0\n0.03,0.0\n")
    out = tmp_path / "fail"
    assert main(["plan", "--waypoints", str(wp), "--out", str(out), "--no-arm", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert (
        "the fixed plan did not converge: IPOPT returned Maximum_Iterations_Exceeded after 2 iterations"
        in err
    )
    assert json.loads((out / "plan.json").read_text())["success"] is False
    assert not (out / "epm_plan.csv").exists()


def test_plan_uses_the_controllers_friction_law(scenario, path, fixed):
    # A learned law with more friction than the paper's (c = 0.03, the plant's a - b) makes the
    # model's capsule trail further behind the magnet: the plan needs a longer lead.
    law = {"coefficients": [0.03], "validity_mps": [0.005, 0.04], "force_model": scenario.force_model}
    learned = _with(scenario, friction={"learned": law})
    plan = cached_plan(learned, path, "fixed")
    assert plan.success, plan.status
    lead_paper = constraint_report(scenario, fixed, path)["max_coupling_m"]
    lead_learned = constraint_report(learned, plan, path)["max_coupling_m"]
    assert lead_learned > 2 * lead_paper


def test_cli_shows_ipopt_progress_on_stderr_unless_no_progress(tmp_path, capsys):
    wp = _waypoints(tmp_path, "0.0,0.0\n0.03,0.0\n")
    assert main(["plan", "--waypoints", str(wp), "--out", str(tmp_path / "a"), "--no-arm"]) == 0
    captured = capsys.readouterr()
    frames = [f.strip() for f in captured.err.replace("\r", "\n").splitlines() if f.strip()]
    assert any(f.startswith("plan (fixed): 0 iterations") and "building the NLP" in f for f in frames)
    counted = [f for f in frames if "objective" in f and "violation" in f]
    assert counted and all(f.startswith("plan (fixed): ") for f in counted)
    assert "Solve_Succeeded" in captured.out  # the summary stays on stdout
    assert (
        main(["plan", "--waypoints", str(wp), "--out", str(tmp_path / "b"), "--no-arm", "--no-progress"]) == 0
    )
    assert capsys.readouterr().err == ""


def test_a_plan_at_the_friction_laws_lowest_speed_converges(scenario):
    """the pipe at 5 mm/s, the lower end of c(v)'s range, failed to converge.

    A hard clamp of the speed into the range put a kink in mu(v) at 5 mm/s; the capsule slows
    below it in a bend, and IPOPT cycled there (the pipe's first bend alone: 500 iterations,
    Maximum_Iterations_Exceeded; 56 with the smooth clamp). The bend is entered and left over 5 mm
    (a 7 s plan, not 12 s): with the hard clamp (``C_RANGE_SMOOTHING_MPS = 0``) this plan too
    stops at 500 iterations; 43 with the smooth one.
    """
    from pathlib import Path

    from capsule_mpc.config import load_config
    from capsule_mpc.paths import path_from_scenario

    pipe = path_from_scenario(load_config(Path(__file__).resolve().parents[1] / "configs" / "pipe.yaml"))
    bend = pipe.vertices_m[1:10]  # the first 90 degree bend, 15 mm radius
    points = np.vstack([bend[0] - [0.005, 0.0], bend, bend[-1] + [0.0, 0.005]])
    plan = plan_path(scenario, ReferencePath(points, False, 0.005), "fixed")
    assert plan.success, plan.failure
    assert plan.iterations < 200
    _assert_within_limits(scenario, plan, ReferencePath(points, False, 0.005))
