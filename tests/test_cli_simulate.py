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
