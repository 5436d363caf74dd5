"""The closed-loop targets on the full paths (slow: `make test-slow`)."""

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
    """The targets on a `lab` draw: tracking and cross-track RMS <= 1/3 of paper_0.8v's,
    cross-track below both baselines, final error at rest <= 0.5 mm, on time, no failure.

    Over 200 `lab` draws the RMS targets hold on the means; the final error is <= 0.5 mm
    in 148 of them (a capsule held by static friction 0.5-2.6 mm off is left there), so the last
    assertion holds on this draw, not on every one.
    """
    m = rectangle_runs
    mpc, heuristic = m["mpc"], m["paper_0.8v"]
    assert mpc["tracking_rms_mm"] <= heuristic["tracking_rms_mm"] / 3
    assert mpc["cross_track_rms_mm"] <= heuristic["cross_track_rms_mm"] / 3
    assert mpc["cross_track_rms_mm"] < min(m["follow"]["cross_track_rms_mm"], heuristic["cross_track_rms_mm"])
    assert mpc["cross_track_max_mm"] <= heuristic["cross_track_max_mm"] / 2
    assert mpc["arrival_time_s"] <= 1.05 * mpc["nominal_time_s"]
    assert mpc["final_error_mm"] <= 0.5
    for name in m:
        assert not (m[name]["decoupled"] or m[name]["dropped"]), name


@pytest.mark.parametrize("speed", [0.005, 0.02, 0.045])
def test_pipe_mpc_beats_both_baselines(speed):
    m = _runs("pipe", speed)
    for baseline in ("follow", "paper_0.8v"):
        assert m["mpc"]["cross_track_rms_mm"] < m[baseline]["cross_track_rms_mm"]
    assert not (m["mpc"]["decoupled"] or m["mpc"]["dropped"])
