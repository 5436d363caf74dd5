"""benchmarks/fault_campaign.py: its faults are variants of one campaign on the sweep's runner, which
writes the run table; the report is aggregated from that table."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from capsule_mpc.experiments.table import TABLE_FILE, read_table

REPO = Path(__file__).resolve().parents[1]


def test_the_fault_campaign_writes_the_run_table_through_the_runner(tmp_path):
    waypoints = tmp_path / "wp.csv"
    waypoints.write_text("x_m,y_m\n0.0,0.0\n0.02,0.0\n")
    config = tmp_path / "c.yaml"
    config.write_text(
        f"base: paper\npath:\n  kind: waypoints\n  waypoints_file: {waypoints}\n"
        "mpc:\n  compile_c: false\nplace:\n  max_moves: 0\nsim:\n  settle_s: 0.2\n  tail_s: 1.0\n"
    )
    out = tmp_path / "faults.json"
    argv = ["--config", str(config), "--runs", "1", "--target", "1", "--probability", "0.3", "--workers", "1"]
    env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    done = subprocess.run(
        [sys.executable, str(REPO / "benchmarks" / "fault_campaign.py"), *argv, "--out", str(out)],
        env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    table = read_table(tmp_path / "faults" / TABLE_FILE)
    assert list(zip(table["seed"], table["variant"], table["controller"])) == [
        (0, "faults", "mpc"),
        (0, "no_faults", "mpc"),
    ]
    run_json = json.loads(next((tmp_path / "faults" / "runs").glob("seed_0.json")).read_text())
    metrics = run_json["controllers"]["faults:mpc"]
    # every metric of the run, the draw's parameters, the seed and the campaign's own checks
    assert {k for k, v in metrics.items() if not isinstance(v, (dict, list))} <= set(table.columns)
    assert any(c.startswith("plant.") for c in table.columns)
    assert {"checks.commands", "checks.jumps", "recovery_s.solver_nan", "late_real"} <= set(table.columns)
    faulty, clean = table.iloc[0], table.iloc[1]
    assert faulty["faults_injected_solver_nan"] > 0
    assert not clean["faults_injected_solver_nan"] > 0  # none injected (NaN: no fault configured)
    report = json.loads(out.read_text())
    kinds = ("solver_failure", "solver_nan", "solver_late")
    assert report["solver_faults_injected"] == sum(int(faulty[f"faults_injected_{k}"]) for k in kinds) > 0
    assert report["command_checks"]["commands"] == faulty["checks.commands"] > 0
    assert report["command_checks"]["jumps"] == report["command_checks"]["over_speed"] == 0
    assert report["tracking_rms_mm"]["mean"] == pytest.approx(faulty["tracking_rms_mm"])
    assert report["tracking_rms_mm_no_faults"]["sd"] == 0.0
    assert report["recovery_s"]["all"]["n"] == sum(len(json.loads(faulty[f"recovery_s.{k}"])) for k in kinds)
