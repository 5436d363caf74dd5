"""The issue's closed-loop targets on the full paths (slow: `make test-slow`)."""

from __future__ import annotations

import pytest

from capsule_mpc import load_config
from capsule_mpc.config import packaged_config_path
from capsule_mpc.mpc import MPCController
from capsule_mpc.paths import path_from_scenario
from capsule_mpc.sim import simulate

pytestmark = pytest.mark.slow


def _runs(config: str, speed: float | None = None) -> dict[str, dict]:
    scenario = load_config(packaged_config_path(config))
    path = path_from_scenario(scenario, speed=speed)
    out = {}
    for name in ("follow", "paper_0.8v"):
        out[name] = simulate(scenario, name, path, seed=0).metrics
    out["mpc"] = simulate(scenario, MPCController(), path, seed=0).metrics
    return out


@pytest.fixture(scope="module")
def rectangle_runs() -> dict[str, dict]:
    return _runs("rectangle")


def test_rectangle_targets_met_on_lab(rectangle_runs):
    """What the MPC meets on a `lab` draw: tracking RMS <= 1/3 of paper_0.8v's, cross-track below
    both baselines, on time, no failure."""
    m = rectangle_runs
    mpc, heuristic = m["mpc"], m["paper_0.8v"]
    assert mpc["tracking_rms_mm"] <= heuristic["tracking_rms_mm"] / 3
    assert mpc["cross_track_rms_mm"] < min(m["follow"]["cross_track_rms_mm"], heuristic["cross_track_rms_mm"])
    assert mpc["cross_track_rms_mm"] <= 1.0
    assert mpc["cross_track_max_mm"] <= heuristic["cross_track_max_mm"] / 2
    assert mpc["arrival_time_s"] <= 1.05 * mpc["nominal_time_s"]
    for name in m:
        assert not (m[name]["decoupled"] or m[name]["dropped"]), name


@pytest.mark.xfail(
    strict=True,
    reason="missed on lab (issue 9): cross-track RMS 0.77 vs 0.72 mm (1/3 of paper_0.8v's) over 20 "
    "runs, 0.54 vs 0.51 on this draw; final error <= 0.5 mm in 7 of 20 runs (README). Issue 12.",
)
def test_rectangle_targets_missed_on_lab(rectangle_runs):
    mpc, heuristic = rectangle_runs["mpc"], rectangle_runs["paper_0.8v"]
    assert mpc["cross_track_rms_mm"] <= heuristic["cross_track_rms_mm"] / 3
    assert mpc["final_error_mm"] <= 0.5


@pytest.mark.parametrize("speed", [0.005, 0.02, 0.045])
def test_pipe_mpc_beats_both_baselines(speed):
    m = _runs("pipe", speed)
    for baseline in ("follow", "paper_0.8v"):
        assert m["mpc"]["cross_track_rms_mm"] < m[baseline]["cross_track_rms_mm"]
    assert not (m["mpc"]["decoupled"] or m["mpc"]["dropped"])
