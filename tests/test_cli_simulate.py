"""The simulate / compare / demo commands."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from capsule_mpc.cli import main
from capsule_mpc.config import load_config
from capsule_mpc.sim import read_log


@pytest.fixture
def short_path(tmp_path):
    f = tmp_path / "short.csv"
    f.write_text("x_m,y_m\n0.0,0.0\n0.02,0.0\n0.02,0.015\n")
    return f


def test_simulate_writes_a_complete_run(tmp_path, short_path, capsys, table):
    out = tmp_path / "run"
    args = ["simulate", "--controller", "follow", "--out", str(out), "--seed", "3"]
    assert main([*args, "--waypoints", str(short_path), "--speed", "0.03", "--no-progress"]) == 0
    assert {p.name for p in out.iterdir()} >= {"log.csv", "config.yaml", "run.json", "trajectories.png"}
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


def test_compare_runs_every_controller_on_the_same_seed(tmp_path, short_path, table, monkeypatch):
    monkeypatch.setattr("capsule_mpc.cli.compare.available_controllers", lambda: ["follow", "paper_0.8v"])
    out = tmp_path / "cmp"
    assert main(["compare", "--out", str(out), "--waypoints", str(short_path), "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seed"] == load_config().sim.seed
    assert set(summary["controllers"]) == {"follow", "paper_0.8v"}
    for entry in summary["controllers"].values():
        for key in ("cross_track_rms_mm", "cross_track_max_mm", "paper_std_mm", "completion_time_s",
                    "nominal_time_s", "decoupled", "dropped", "solve_ms_median", "solve_ms_p99",
                    "solver_failures", "deadline_misses"):  # fmt: skip
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


def test_demo_compares_on_the_rectangle(tmp_path, monkeypatch, capsys, table):
    monkeypatch.setattr("capsule_mpc.cli.compare.available_controllers", lambda: ["follow"])
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"].endswith("rectangle.yaml")
    assert summary["path_length_m"] == pytest.approx(0.32)
    assert f"demo results: {out.resolve()}" in capsys.readouterr().out
    assert yaml.safe_load((out / "follow" / "config.yaml").read_text())["name"] == "rectangle"


@pytest.fixture
def quick_config(tmp_path):
    """The paper rig with a short settle and the MPC's NLP left uncompiled (builds in ~1 s)."""
    f = tmp_path / "quick.yaml"
    f.write_text("base: paper\nname: quick\nsim: {settle_s: 0.5, tail_s: 0.5}\nmpc: {compile_c: false}\n")
    return f


def test_simulate_realtime_reports_deadline_misses(tmp_path, short_path, quick_config, capsys, table):
    out = tmp_path / "rt"
    args = ["simulate", "--controller", "follow", "--config", str(quick_config), "--out", str(out)]
    assert (
        main([*args, "--waypoints", str(short_path), "--speed", "0.04", "--realtime", "--no-progress"]) == 0
    )
    run = json.loads((out / "run.json").read_text())
    rt = run["realtime"]
    assert rt["frames"] > 30 and rt["period_ms"] == pytest.approx(1e3 / 30)
    assert run["metrics"]["deadline_misses"] == rt["deadline_misses"]
    assert run["timing"]["wall_time_s"] == pytest.approx(run["timing"]["sim_time_s"], abs=0.15)
    assert load_config(out / "config.yaml").mpc.enforce_deadline  # what the controller ran with
    text = capsys.readouterr().out
    assert f"deadline misses {rt['deadline_misses']} " in text and "worst step" in text
    assert not (out / "joint_trajectory.csv").exists()  # follow: no arm outputs unless --arm


def test_simulate_mpc_writes_predictions_and_arm_outputs(tmp_path, short_path, quick_config, capsys, table):
    out = tmp_path / "mpc"
    args = ["simulate", "--controller", "mpc", "--config", str(quick_config), "--out", str(out)]
    assert main([*args, "--waypoints", str(short_path), "--no-progress"]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"mpc_prediction.png", "predictions.npz", "epm_trajectory.csv", "joint_trajectory.csv",
            "joint_trajectory.yaml", "joint_trajectory.png"} <= names  # fmt: skip
    log = read_log(out / "log.csv")
    joints = np.loadtxt(out / "joint_trajectory.csv", delimiter=",", skiprows=1)
    moving = log["t_s"] >= 0
    assert joints[0, 0] == pytest.approx(log["t_s"][moving][0])  # from t = 0 on, not the settle
    assert joints[-1, 0] >= log["t_s"][-1] - 1e-9
    text = capsys.readouterr().out
    assert "solve time median" in text and "arm:" in text


def test_simulate_reports_an_arm_that_cannot_follow(
    tmp_path, short_path, quick_config, capsys, monkeypatch, table
):
    from capsule_mpc.arm import UnreachableTargetError

    def unreachable(scenario, t_s, epm, out_dir, **kw):
        raise UnreachableTargetError(t_s[3], epm[3], "joint 2 leaves its position limit")

    monkeypatch.setattr("capsule_mpc.arm.export_arm_trajectory", unreachable)
    out = tmp_path / "arm"
    args = ["simulate", "--controller", "follow", "--arm", "--config", str(quick_config), "--out", str(out)]
    assert main([*args, "--waypoints", str(short_path), "--speed", "0.04", "--no-progress"]) == 0
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
    assert len(solve) >= len(log["t_s"]) - 2  # every step but the first (no measurement yet) solves
    assert entry["solve_ms_median"] == pytest.approx(np.median(solve))
    assert entry["solve_ms_p99"] == pytest.approx(np.percentile(solve, 99))
    assert entry["deadline_misses"] == int(np.sum(solve > 1e3 / 30))
    assert entry["solver_failures"] == int(log["solver_failed"].sum())
    assert summary["controllers"]["follow"]["solve_ms_median"] is None  # follow does not solve
    assert "deadline misses" in (out / "summary.md").read_text()
