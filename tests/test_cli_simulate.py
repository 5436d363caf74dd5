"""The simulate / compare / demo commands."""

from __future__ import annotations

import json
import os
import re

import numpy as np
import pytest
import yaml

from capsule_mpc.cli import main
from capsule_mpc.config import load_config
from capsule_mpc.outputs import MANIFEST_NAME, read_manifest
from capsule_mpc.sim import read_log


@pytest.fixture
def short_path(tmp_path):
    f = tmp_path / "short.csv"
    f.write_text("x_m,y_m\n0.0,0.0\n0.02,0.0\n0.02,0.015\n")
    return f


def run_status(out):
    """The exit status ``simulate`` owes the run in ``out``: 0 completed, 1 failed."""
    return 0 if json.loads((out / "run.json").read_text())["flags"]["completed"] else 1


def test_simulate_writes_a_complete_run(tmp_path, short_path, capsys, table):
    out = tmp_path / "run"
    args = ["simulate", "--controller", "follow", "--out", str(out), "--seed", "3"]
    status = main([*args, "--waypoints", str(short_path), "--speed", "0.03", "--no-progress"])
    assert {p.name for p in out.iterdir()} >= {"log.csv", "config.yaml", "run.json", "trajectories.png"}
    assert status == run_status(out)
    run = json.loads((out / "run.json").read_text())
    assert run["seed"] == 3 and run["controller"] == "follow" and run["speed_mps"] == 0.03
    assert run["waypoints_file"] == str(short_path.resolve())
    assert run["flags"]["decoupled"] is False
    assert "paper_std_mm" in run["metrics"]
    used = load_config(out / "config.yaml")  # the dump reproduces the overridden run
    assert used.path.kind == "waypoints" and used.path.speed_mps == 0.03
    log = read_log(out / "log.csv")
    assert np.all(np.diff(log["t_s"]) > 0)
    assert "results in" in capsys.readouterr().out


def test_compare_runs_every_controller_on_the_same_seed(
    tmp_path, short_path, quick_config, table, monkeypatch
):
    monkeypatch.setattr(
        "capsule_mpc.experiments.compare.available_controllers", lambda: ["follow", "paper_0.8v"]
    )
    out = tmp_path / "cmp"
    args = ["compare", "--config", str(quick_config), "--out", str(out), "--waypoints", str(short_path)]
    assert main([*args, "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seed"] == load_config().sim.seed
    assert set(summary["controllers"]) == {"follow", "paper_0.8v"}
    for entry in summary["controllers"].values():
        for key in (
            "cross_track_rms_mm",
            "cross_track_max_mm",
            "paper_std_mm",
            "arrival_time_s",
            "tracking_rms_mm",
            "final_error_mm",
            "nominal_time_s",
            "decoupled",
            "dropped",
            "solve_ms_median",
            "solve_ms_p99",
            "solver_failures",
            "deadline_misses",
        ):
            assert key in entry
    for name in ("summary.md", "trajectories.png", "errors.png", "metrics.png"):
        assert (out / name).stat().st_size > 0
    assert "| follow |" in (out / "summary.md").read_text()
    noise = []
    for name in ("follow", "paper_0.8v"):  # camera noise = measurement - true position one frame earlier
        log = read_log(out / name / "log.csv")
        noise.append(log["meas_x_m"][1:] - log["capsule_x_m"][:-1])
    n = min(map(len, noise))
    np.testing.assert_allclose(noise[0][:n], noise[1][:n], atol=1e-12)  # same seed, same noise
    assert np.std(noise[0][:n]) == pytest.approx(3e-4, rel=0.3)


def test_compare_rejects_unknown_controller(tmp_path, capsys):
    assert main(["compare", "--out", str(tmp_path), "--controllers", "nope"]) == 2
    assert "unknown ['nope']" in capsys.readouterr().err


def test_bad_waypoints_exit_2_with_row(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("x_m,y_m\n0,0\n1.0,0\n")
    assert (
        main(["simulate", "--controller", "follow", "--out", str(tmp_path / "o"), "--waypoints", str(bad)])
        == 2
    )
    assert "line 3" in capsys.readouterr().err


@pytest.mark.slow  # ~3 min; .ci/run runs `make demo` itself on the clean clone after the tests
def test_demo_demonstrates_learns_and_compares_with_a_cache(tmp_path, capsys, table):
    from capsule_mpc.config import packaged_config_path

    cfg = tmp_path / "rect.yaml"  # the demo's rectangle, with a shorter settle phase
    cfg.write_text(f"base: {packaged_config_path('rectangle')}\nsim: {{settle_s: 0.5}}\n")
    out = tmp_path / "demo"
    args = ["demo", "--config", str(cfg), "--out", str(out), "--speeds", "0.03", "0.04"]
    args += ["--controllers", "follow", "--no-progress"]
    assert main(args) == 0
    first = capsys.readouterr().out
    logs = sorted((out / "demonstrations").glob("*/log.csv"))
    # straight x, straight y, rectangle at two speeds; breakaways along x and y after 4 rest times
    assert len(logs) == 6 + 8
    model = yaml.safe_load((out / "learned_friction.yaml").read_text())
    assert model["force_model"] == "lookup" and model["degree"] == 4
    assert model["rig"] == {"preset": "lab", "seed": 0} and "static_mu_1s" in model and "p1" in model["ci95"]
    assert sorted(model["sources"]) == sorted(str(p.resolve()) for p in logs)
    assert (out / "learning" / "friction_c_fit.png").stat().st_size > 0
    scenario = load_config(out / "scenario.yaml")  # the derived scenario: lookup model + learned friction
    assert scenario.force_model == "lookup" and scenario.path.rectangle_size_m == (0.1, 0.06)
    assert scenario.sim.settle_s == 0.5
    assert scenario.controller_friction().coefficients == model["coefficients"]
    summary = json.loads((out / "compare" / "summary.json").read_text())
    assert summary["config"] == str((out / "scenario.yaml").resolve())
    assert summary["path_length_m"] == pytest.approx(0.32)
    assert list(summary["controllers"]) == ["follow"]
    used = yaml.safe_load((out / "compare" / "follow" / "config.yaml").read_text())
    assert used["friction"]["learned"]["coefficients"] == model["coefficients"]  # inlined beside the run
    assert "| follow |" in first and "demo results" in first and str(out.resolve() / "compare") in first
    assert "(0 cached)" in first and "friction model: c(v) of degree 4" in first
    # The fit's verdict (weak or not) is printed and kept in the model file, as learn-friction does.
    printed = [ln.split("WARNING: ", 1)[1] for ln in first.splitlines() if "WARNING: " in ln]
    header = [
        ln.split("WARNING: ", 1)[1]
        for ln in (out / "learned_friction.yaml").read_text().splitlines()
        if ln.startswith("# WARNING: ")
    ]
    assert printed == header and printed  # two speeds only: the fit is flagged

    # Second run: demonstrations reused, no re-fit, the comparison runs again.
    stamp = (out / "learned_friction.yaml").stat().st_mtime_ns
    assert main(args) == 0
    second = capsys.readouterr().out
    assert "(14 cached)" in second and "friction model: up to date" in second and "| follow |" in second
    assert (out / "learned_friction.yaml").stat().st_mtime_ns == stamp  # (re-fit rules: next test)


def test_model_is_current_needs_the_same_logs(tmp_path):
    from capsule_mpc.experiments.demo import model_is_current

    log_a, log_b, model = tmp_path / "a.csv", tmp_path / "b.csv", tmp_path / "m.yaml"
    for f in (log_a, log_b):
        f.write_text("t_s\n")
    assert not model_is_current(model, [log_a])  # no model yet
    model.write_text(yaml.safe_dump({"force_model": "lookup", "sources": [str(log_a.resolve())]}))
    os.utime(log_a, (0, 0))
    os.utime(log_b, (0, 0))
    assert model_is_current(model, [log_a])
    assert not model_is_current(model, [log_a, log_b])  # fitted to other logs
    future = model.stat().st_mtime + 10
    os.utime(log_a, (future, future))
    assert not model_is_current(model, [log_a])  # a demonstration newer than the model
    os.utime(log_a, (0, 0))
    model.write_text(yaml.safe_dump({"force_model": "dipole", "sources": [str(log_a.resolve())]}))
    assert not model_is_current(model, [log_a])  # another force model


def test_demo_rejects_unknown_controller(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--controllers", "nope"]) == 2
    assert "unknown ['nope']" in capsys.readouterr().err


@pytest.fixture
def quick_config(tmp_path):
    """The paper rig with a short settle and the MPC's NLP left uncompiled (builds in ~1 s)."""
    f = tmp_path / "quick.yaml"
    f.write_text("base: paper\nname: quick\nsim: {settle_s: 0.5, tail_s: 0.5}\nmpc: {compile_c: false}\n")
    return f


def test_simulate_realtime_reports_deadline_misses(tmp_path, short_path, quick_config, capsys, table):
    out = tmp_path / "rt"
    args = ["simulate", "--controller", "follow", "--config", str(quick_config), "--out", str(out)]
    status = main([*args, "--waypoints", str(short_path), "--speed", "0.04", "--realtime", "--no-progress"])
    assert status == run_status(out)
    run = json.loads((out / "run.json").read_text())
    rt = run["realtime"]
    assert rt["frames"] > 30 and rt["period_ms"] == pytest.approx(1e3 / 30)
    assert run["metrics"]["deadline_misses"] == rt["deadline_misses"]
    # Paced by the wall clock: never ahead of the simulated time (how closely it keeps pace depends
    # on the machine's load; the pacing itself is checked on a virtual clock in tests/test_sim.py).
    assert run["timing"]["wall_time_s"] >= run["timing"]["sim_time_s"]
    assert load_config(out / "config.yaml").mpc.enforce_deadline  # what the controller ran with
    text = capsys.readouterr().out
    assert f"deadline misses {rt['deadline_misses']} " in text and "worst step" in text
    assert not (out / "joint_trajectory.csv").exists()  # follow: no arm outputs unless --arm


def test_simulate_mpc_writes_predictions_and_arm_outputs(tmp_path, short_path, quick_config, capsys, table):
    out = tmp_path / "mpc"
    args = ["simulate", "--controller", "mpc", "--config", str(quick_config), "--out", str(out)]
    assert main([*args, "--waypoints", str(short_path), "--no-progress"]) == run_status(out)
    names = {p.name for p in out.iterdir()}
    assert {
        "mpc_prediction.png",
        "predictions.npz",
        "epm_trajectory.csv",
        "joint_trajectory.csv",
        "joint_trajectory.yaml",
        "joint_trajectory.png",
    } <= names
    log = read_log(out / "log.csv")
    joints = np.loadtxt(out / "joint_trajectory.csv", delimiter=",", skiprows=1)
    moving = log["t_s"] >= 0
    assert joints[0, 0] == pytest.approx(log["t_s"][moving][0])  # from t = 0 on, not the settle
    tick = 1.0 / load_config(out / "config.yaml").arm.arm_rate_hz
    assert joints[-1, 0] >= log["t_s"][-1] - tick - 1e-9  # the arm's last tick of the run
    run = json.loads((out / "run.json").read_text())
    assert run["metrics"]["arm_ok"] and run["flags"]["arm_failure"] == ""
    text = capsys.readouterr().out
    assert "solve time median" in text and "arm:" in text
    assert set(read_manifest(out)["files"]) == names - {MANIFEST_NAME}
    # A follow run into the same folder replaces the mpc run: no stale predictions or arm files.
    follow = ["simulate", "--controller", "follow", "--config", str(quick_config), "--out", str(out)]
    status = main([*follow, "--waypoints", str(short_path), "--no-progress"])
    after = {p.name for p in out.iterdir()}
    run_files = {"log.csv", "config.yaml", "run.json", "run.mcap", "trajectories.png", "errors.png"}
    assert after == run_files | {MANIFEST_NAME}
    manifest = read_manifest(out)
    assert manifest["command"] == "simulate" and manifest["exit_status"] == status == run_status(out)
    assert manifest["status"] == ("complete" if status == 0 else "failed")  # a stalled run is no success


def test_simulate_refuses_an_out_that_is_a_file_before_running(tmp_path, short_path, capsys):
    f = tmp_path / "taken.txt"
    f.write_text("keep")
    args = ["simulate", "--controller", "follow", "--waypoints", str(short_path), "--out", str(f)]
    assert main(args) == 2
    assert f"--out: {f} exists and is not a folder" in capsys.readouterr().err
    assert f.read_text() == "keep"


def test_simulate_fails_a_run_whose_joint_commands_fail_their_check(
    tmp_path, short_path, quick_config, capsys, monkeypatch, table
):
    """The robot arm's joint commands are checked in the run: a failed check is in run.json
    (``arm_ok`` false, the check's message), no arm file is written, and simulate exits 1."""
    from capsule_mpc.arm import ExportCheckError

    def too_fast(scenario, cart, joints):
        raise ExportCheckError(cart.t_s[5], cart.position_m[5], "joint 2 beyond its velocity limit")

    monkeypatch.setattr("capsule_mpc.arm.check_run_trajectory", too_fast)
    out = tmp_path / "arm"
    args = ["simulate", "--controller", "follow", "--arm", "--config", str(quick_config), "--out", str(out)]
    assert main([*args, "--waypoints", str(short_path), "--speed", "0.04", "--no-progress"]) == 1
    run = json.loads((out / "run.json").read_text())
    assert run["metrics"]["arm_ok"] is False
    assert "joint 2 beyond its velocity limit" in run["flags"]["arm_failure"]
    captured = capsys.readouterr()
    assert "arm commands invalid: " in captured.out.splitlines()[0]
    assert "fail their check" in captured.err and "skipped" in captured.err
    assert (out / "log.csv").exists() and not (out / "joint_trajectory.csv").exists()


def test_simulate_reports_an_arm_that_cannot_follow(tmp_path, short_path, capsys, monkeypatch, table):
    """With the simplified actuator the arm outputs come from the logged EPM trajectory."""
    from capsule_mpc.arm import UnreachableTargetError

    def unreachable(scenario, t_s, epm, out_dir, **kw):
        raise UnreachableTargetError(t_s[3], epm[3], "joint 2 leaves its position limit")

    monkeypatch.setattr("capsule_mpc.experiments.runs.export_arm_trajectory", unreachable)
    simple = tmp_path / "simple.yaml"
    simple.write_text("base: paper\nsim: {settle_s: 0.5, tail_s: 0.5, actuator: simple}\n")
    out = tmp_path / "arm"
    args = ["simulate", "--controller", "follow", "--arm", "--config", str(simple), "--out", str(out)]
    assert main([*args, "--waypoints", str(short_path), "--speed", "0.04", "--no-progress"]) == run_status(
        out
    )
    err = capsys.readouterr().err
    assert "cannot follow" in err and "joint 2 leaves its position limit" in err and "skipped" in err
    assert (out / "log.csv").exists() and not (out / "joint_trajectory.csv").exists()


def test_simulate_rejects_unknown_controller(tmp_path, capsys):
    assert main(["simulate", "--controller", "nope", "--out", str(tmp_path / "x")]) == 2
    assert "unknown 'nope'" in capsys.readouterr().err


def test_compare_with_mpc_adds_solver_figures_and_prediction(tmp_path, short_path, quick_config, table):
    out = tmp_path / "cmp"
    args = ["compare", "--config", str(quick_config), "--out", str(out), "--waypoints", str(short_path)]
    assert main([*args, "--controllers", "follow", "mpc", "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert "mpc_prediction.png" in summary["figures"] and (out / "mpc_prediction.png").stat().st_size > 0
    entry = summary["controllers"]["mpc"]
    log = read_log(out / "mpc" / "log.csv")
    solve = log["solve_ms"][np.isfinite(log["solve_ms"])]
    # every step but the first (no measurement yet) solves, but the placement's waits (release, observe)
    sliding = log["phase"] != "place"
    assert np.isfinite(log["solve_ms"][sliding]).sum() >= sliding.sum() - 2
    assert entry["solve_ms_median"] == pytest.approx(np.median(solve))
    assert entry["solve_ms_p99"] == pytest.approx(np.percentile(solve, 99))
    assert entry["deadline_misses"] == int(np.sum(solve > 1e3 / 30))
    assert entry["solver_failures"] == int(log["solver_failed"].sum())
    assert summary["controllers"]["follow"]["solve_ms_median"] is None  # follow does not solve
    assert "deadline misses" in (out / "summary.md").read_text()


# --- how a run ended: said in words, and in the exit status -------------------------------------------------


def simulate_follow(tmp_path, config_text, waypoints, *extra):
    """``simulate --controller follow`` with a config derived from paper.yaml; (status, stdout, run.json)."""
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("base: paper\nsim: {settle_s: 0.5" + config_text + "}\n")
    out = tmp_path / "run"
    args = ["simulate", "--controller", "follow", "--config", str(cfg), "--out", str(out)]
    status = main([*args, "--waypoints", str(waypoints), "--speed", "0.03", "--no-progress", *extra])
    return status, out, json.loads((out / "run.json").read_text())


def check_summary(text, run):
    """The first line says how the run ended and which limits acted, as run.json records them."""
    first = text.splitlines()[0]
    assert first.startswith(f"follow: {run['metrics']['outcome']}")
    for name, count in run["limit_counts"].items():
        assert (f" in {count} " in first) == (count > 0), name
    assert not re.search(r"\bnan\b", text)  # "arrival nan s" was printed before
    assert not re.search(r"[ ;]0x real time", text)  # a run slower than real time: "0.6x", not "0x"
    return first


def test_simulate_says_a_stalled_run_stalled_and_exits_1(tmp_path, short_path, capsys, table):
    status, out, run = simulate_follow(tmp_path, "", short_path, "--seed", "3")
    assert run["flags"]["stalled"] and status == 1
    first = check_summary(capsys.readouterr().out, run)
    short = run["metrics"]["final_error_mm"]
    assert first.startswith(f"follow: stalled {short:.2f} mm short of the end (at rest, ")
    assert (out / "log.csv").exists() and (out / "trajectories.png").exists()  # the run is still written


def test_simulate_says_a_run_cut_off_timed_out_and_exits_1(tmp_path, short_path, capsys, table):
    status, _, run = simulate_follow(tmp_path, ", tail_s: 0.5", short_path, "--seed", "3")
    assert run["flags"]["timed_out"] and status == 1
    text = capsys.readouterr().out
    assert check_summary(text, run).startswith("follow: timed out at t = ")
    assert "never arrived (nominal" in text


def test_simulate_says_when_a_run_decoupled_and_exits_1(tmp_path, short_path, capsys, table):
    """A sticky patch on the path, and a plant that lets go of the capsule early."""
    patch = "{x_range_m: [0.01, 0.03], y_range_m: [-0.01, 0.03], scale: 10}"
    config = ", decouple_lead_m: 0.006}\nplant: {preset: ideal, friction_patches: [" + patch + "]"
    status, _, run = simulate_follow(tmp_path, config, short_path)
    assert run["flags"]["decoupled"] and status == 1
    first = check_summary(capsys.readouterr().out, run)
    found = re.match(
        r"follow: decoupled: \|lead - equilibrium lead\| = (\d+\.\d) mm > sim\.decouple_lead_m = 6\.0 mm",
        first,
    )
    assert found and 6.0 <= float(found.group(1)) < 6.5  # the first frame past the limit
    assert f"at t = {run['flags']['failure_t_s']:.3f} s" in first


def test_simulate_exits_0_when_the_run_completed(tmp_path, short_path, capsys, table):
    status, _, run = simulate_follow(tmp_path, ", completion_tol_m: 0.01", short_path, "--seed", "3")
    assert run["flags"]["completed"] and status == 0
    text = capsys.readouterr().out
    assert check_summary(text, run).startswith("follow: completed: at rest ")


def test_simulate_help_documents_the_exit_statuses(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "Exit status: 0 the run completed" in help_text
    assert "1 the run failed (stalled, timed out, decoupled or dropped" in help_text
    assert "2 a bad config, waypoint file or option" in help_text
