"""The benchmark's leaderboard against a hand computation, its files, and the command's refusals."""

from __future__ import annotations

import json
import math

import pandas as pd
import pytest

from benchmark_scripts import load
from capsule_mpc.cli import main
from capsule_mpc.envs import load_policy
from capsule_mpc.errors import ConfigError
from capsule_mpc.experiments.benchmark import (
    RUN_COLUMNS,
    Entrant,
    leaderboard,
    leaderboard_markdown,
    run_entrant,
    write_benchmark,
)


def _row(seed: int, score: float, final: float, success: bool, error: str = "") -> dict:
    return {
        "entrant": "mpc",
        "task": "place",
        "preset": "lab",
        "seed": seed,
        "score": score,
        "tracking_rms_mm": 2.0 * score,
        "final_error_mm": final,
        "paper_std_mm": 1.0,
        "arrival_ratio": 1.1,
        "success": success,
        "outcome": "completed",
        "cpu_s": 1.0,
        "error": error,
    }


def test_the_leaderboard_of_a_two_run_suite_matches_a_hand_computation():
    runs = pd.DataFrame([_row(5000, 0.3, 0.3, True), _row(5001, 0.7, 0.7, False)])
    board = leaderboard(runs)
    assert len(board) == 1
    r = board.iloc[0]
    assert r["n_runs"] == 2 and r["n_errors"] == 0
    assert r["success_rate"] == pytest.approx(0.5)
    assert r["score_mean"] == pytest.approx(0.5)
    assert r["score_sd"] == pytest.approx(0.4 / math.sqrt(2.0))  # |a - b| / sqrt(2), ddof 1
    assert r["score_worst"] == pytest.approx(0.7)
    assert r["tracking_rms_mm_mean"] == pytest.approx(1.0)
    assert r["tracking_rms_mm_worst"] == pytest.approx(1.4)
    md = leaderboard_markdown(board)
    assert "| mpc | place | lab | 2 | 50 % | 0.50 ± 0.28 | 0.70 | 1.00 ± 0.57 | 0.50 ± 0.28 |" in md


def test_a_run_that_raised_counts_as_a_failure_and_has_no_score():
    nan = math.nan
    runs = pd.DataFrame([_row(5000, 0.4, 0.4, True), _row(5001, nan, nan, False, error="PlanError: no")])
    r = leaderboard(runs).iloc[0]
    assert r["n_runs"] == 2 and r["n_errors"] == 1
    assert r["success_rate"] == pytest.approx(0.5)
    assert r["score_mean"] == pytest.approx(0.4) and r["score_sd"] == 0.0 and r["score_worst"] == 0.4


def test_the_files_hold_the_runs_and_the_command(tmp_path):
    rows = [_row(5000, 0.3, 0.3, True), _row(5001, 0.7, 0.7, False)]
    paths = write_benchmark(rows, tmp_path, {"command": "capsule-mpc benchmark ...", "commit": "abc"})
    runs = pd.read_csv(paths["runs"])
    assert list(runs.columns) == list(RUN_COLUMNS) and len(runs) == 2
    record = json.loads(paths["leaderboard_json"].read_text(encoding="utf-8"))
    assert record["meta"]["commit"] == "abc"
    assert record["leaderboard"][0]["score_mean"] == pytest.approx(0.5)
    assert "| mpc | place | lab |" in paths["leaderboard_md"].read_text(encoding="utf-8")


def test_a_policy_runs_the_suite_through_the_environment():
    entrant = Entrant.of_policy("capsule_mpc.envs.policies:random_policy")
    rows = run_entrant(entrant, [3], tasks=["pipe_fast"], presets=["lab"])
    assert len(rows) == 1 and rows[0]["error"] == ""
    assert rows[0]["success"] is False  # random actions do not make a path
    assert math.isfinite(rows[0]["score"])


def test_bad_policies_and_options_are_refused(capsys, tmp_path):
    with pytest.raises(ConfigError, match="--policy: must be module:function"):
        load_policy("capsule_mpc.envs.policies")
    with pytest.raises(ConfigError, match="--policy: cannot import 'no_such_module'"):
        load_policy("no_such_module:f")
    with pytest.raises(ConfigError, match="is not a callable"):
        load_policy("capsule_mpc.envs.policies:nothing")
    assert main(["benchmark", "--out", str(tmp_path / "b")]) == 2
    assert "give at least one --controller or --policy" in capsys.readouterr().err
    assert main(["benchmark", "--controller", "nope", "--out", str(tmp_path / "b")]) == 2
    out = str(tmp_path / "b")
    assert main(["benchmark", "--controller", "follow", "--task", "spiral", "--out", out]) == 2
    assert "task: must be one of" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


def test_the_reference_scores_in_the_docs_are_rendered_from_their_json():
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    module = load("benchmark_doc")
    record = json.loads(
        (repo / "docs" / "results" / "benchmark" / "leaderboard.json").read_text(encoding="utf-8")
    )
    doc = (repo / "docs" / "benchmark.md").read_text(encoding="utf-8")
    assert module.render(doc, record) == doc
    assert record["meta"]["commit"] and record["meta"]["command"].startswith("capsule-mpc benchmark")
