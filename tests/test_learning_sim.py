"""Learning from simulated demonstrations: the demonstrate command, end-to-end c(v), held-out leads."""

from __future__ import annotations

import json

import numpy as np
import pytest

from capsule_mpc.cli import main
from capsule_mpc.learning import (
    LearningDataError,
    LogOptions,
    check_open_loop,
    learn_from_logs,
    measured_steady_lead,
    plant_mu,
    predicted_steady_lead,
    read_run_log,
    steady_lead,
)
from capsule_mpc.learning.demonstrations import demo_path, run_demonstrations
from capsule_mpc.magnetics import capsule_force_function
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import simulate, write_run

SPEEDS = (0.01, 0.02, 0.03)


def plant_c(scenario, v: float) -> float:
    """The plant's steady c in the paper's form: (a - b) ln(v*/v + 1) / ln(v*/v)."""
    rs = scenario.friction.rate_state
    v_star = scenario.friction.v_star_mps
    return (rs.a - rs.b) * np.log(v_star / v + 1) / np.log(v_star / v)


@pytest.fixture(scope="module")
def demos(scenario, table, tmp_path_factory):
    out = tmp_path_factory.mktemp("demos")
    runs = run_demonstrations(scenario, SPEEDS, out, path_kinds=("straight_x",), seed=3)
    return out, runs


def test_demonstrations_are_written_and_cached(scenario, demos):
    out, runs = demos
    assert [r.speed_mps for r in runs] == list(SPEEDS)
    assert all(r.status in ("completed", "stalled") for r in runs)  # never decoupled or dropped
    assert all(r.log_path.exists() and (r.log_path.parent / "run.json").exists() for r in runs)
    manifest = json.loads((out / "demonstrations.json").read_text())
    assert len(manifest["runs"]) == 3 and manifest["seed"] == 3
    again = run_demonstrations(scenario, SPEEDS, out, path_kinds=("straight_x",), seed=3)
    assert all(r.cached for r in again)
    assert [r.seed for r in again] == [r.seed for r in runs]
    assert len({r.seed for r in runs}) == 3


def test_demo_paths(scenario):
    p = demo_path(scenario, "straight_y", 0.02)
    assert p.length_m == pytest.approx(0.16) and not p.closed
    assert demo_path(scenario, "rectangle", 0.02).closed
    with pytest.raises(ValueError, match="path kind: must be one of"):
        demo_path(scenario, "circle", 0.02)


def test_learned_c_matches_the_plants_rate_state_law(scenario, demos):
    """End to end: camera logs -> c(v) within 5 % of (a - b) ln(v*/v + 1)/ln(v*/v) with the lookup model."""
    _, runs = demos
    result = learn_from_logs([r.log_path for r in runs], scenario, LogOptions(force_model="lookup"), degree=1)
    for v in SPEEDS:
        assert result.fit(v) == pytest.approx(plant_c(scenario, v), rel=0.05)
    # The dipole overestimates the force; the fit absorbs the mismatch into a much larger c.
    dipole = learn_from_logs([r.log_path for r in runs], scenario, LogOptions(force_model="dipole"), degree=1)
    assert all(dipole.fit(v) > 1.3 * plant_c(scenario, v) for v in SPEEDS)


def test_held_out_speed_steady_lead_is_predicted(scenario, demos):
    _, runs = demos
    train = [r.log_path for r in runs if r.speed_mps != 0.02]
    held = next(r for r in runs if r.speed_mps == 0.02)
    model = learn_from_logs(train, scenario, LogOptions(force_model="lookup"), degree=1).model
    measured = measured_steady_lead(read_run_log(held.log_path, truth=True))
    assert measured.speed_mps == pytest.approx(0.02, rel=0.01)
    fn = capsule_force_function(scenario, "lookup")
    predicted = predicted_steady_lead(scenario, model, measured.speed_mps, measured.direction, force_fn=fn)
    assert np.linalg.norm(predicted - measured.lead_m) < 1e-4  # 0.1 mm
    # The plant's own law with the lookup force model predicts it too (checks the measurement).
    ideal = steady_lead(scenario, plant_mu(scenario)(measured.speed_mps), measured.direction, force_fn=fn)
    assert np.linalg.norm(ideal - measured.lead_m) < 1e-4


def test_demonstrations_pass_the_open_loop_check_and_an_mpc_run_does_not(scenario, demos, tmp_path):
    _, runs = demos
    for run in runs:
        check = check_open_loop(read_run_log(run.log_path))
        assert check.controller == "follow" and not check.closed_loop, check
    straight = ReferencePath(np.array([[-0.03, 0.0], [0.03, 0.0]]), False, 0.02)
    write_run(simulate(scenario, "mpc", straight, 1), tmp_path)
    (tmp_path / "run.json").unlink()  # the log's content alone must tell
    check = check_open_loop(read_run_log(tmp_path / "log.csv"))
    assert check.closed_loop and check.p_value < 1e-6 and check.controller is None


def test_measured_steady_lead_needs_truth(demos):
    _, runs = demos
    with pytest.raises(LearningDataError, match="truth=True"):
        measured_steady_lead(read_run_log(runs[0].log_path))


def test_demonstrate_cli(tmp_path, capsys, table):
    args = [
        "demonstrate",
        "--speeds",
        "0.03",
        "--paths",
        "straight_x",
        "--no-breakaway",
        "--out",
        str(tmp_path),
    ]
    assert main(args) == 0
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "1 demonstration run(s) (0 breakaway, 1 cached)" in out
    assert (tmp_path / "straight_x_v30mmps_r0" / "log.csv").exists()


def test_demonstrate_cli_rejects_bad_speeds(tmp_path, capsys):
    assert main(["demonstrate", "--speeds", "0.5", "--out", str(tmp_path)]) == 2
    assert "speeds_mps: each must be in (0, 0.08]" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(SystemExit):
        main(["demonstrate", "--speeds", "-1", "--out", str(tmp_path)])
