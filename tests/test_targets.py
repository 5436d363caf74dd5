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


def test_rectangle_targets():
    m = _runs("rectangle")
    mpc, heuristic = m["mpc"], m["paper_0.8v"]
    assert mpc["cross_track_rms_mm"] <= heuristic["cross_track_rms_mm"] / 3
    assert mpc["cross_track_rms_mm"] <= 1.0
    assert mpc["cross_track_max_mm"] <= heuristic["cross_track_max_mm"] / 2
    assert mpc["arrival_time_s"] <= 1.05 * mpc["nominal_time_s"]
    assert not (mpc["decoupled"] or mpc["dropped"])


@pytest.mark.parametrize("speed", [0.005, 0.02, 0.045])
def test_pipe_mpc_beats_both_baselines(speed):
    m = _runs("pipe", speed)
    for baseline in ("follow", "paper_0.8v"):
        assert m["mpc"]["cross_track_rms_mm"] < m[baseline]["cross_track_rms_mm"]
    assert not (m["mpc"]["decoupled"] or m["mpc"]["dropped"])
