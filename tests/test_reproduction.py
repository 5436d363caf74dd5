"""The paper's metric against a closed form on a synthetic log, the scenario variants of the
sensitivity, and the committed reproduction page against its JSON."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from benchmark_scripts import load
from capsule_mpc.errors import ConfigError
from capsule_mpc.experiments.reproduction import (
    lead_by_heading_mm,
    motion_windows,
    paper_std_mm,
    scenario_variant,
)

REPO = Path(__file__).resolve().parents[1]
RATE_HZ = 30.0
LEAD_MM, AMPLITUDE_MM, PERIOD_S = 18.0, 2.5, 1.0


def _synthetic_log(moving_periods: int = 8) -> dict[str, np.ndarray]:
    """The EPM at 20 mm/s along a heading of 30 deg for whole periods of the lead's oscillation,
    at rest before and after (with a far larger lead, outside the windows); the capsule behind it
    at ``LEAD + A sin(2 pi t / T)``."""
    t = np.arange(-30, round((moving_periods + 3) * PERIOD_S * RATE_HZ)) / RATE_HZ
    moving = (t >= 0) & (t < moving_periods * PERIOD_S - 1e-9)
    heading = np.array([math.cos(math.pi / 6), math.sin(math.pi / 6)])
    speed = np.where(moving, 0.02, 0.0)
    epm = np.outer(np.cumsum(speed) / RATE_HZ, heading)
    lead_mm = np.where(moving, LEAD_MM + AMPLITUDE_MM * np.sin(2 * math.pi * t / PERIOD_S), 50.0)
    capsule = epm - np.outer(lead_mm * 1e-3, heading)
    meas = capsule + np.outer(np.full(len(t), 0.4e-3), heading)  # a bias along the lead
    meas[t < 0] = np.nan  # no frame delivered yet: left out
    return {
        "t_s": t,
        "epm_x_m": epm[:, 0],
        "epm_y_m": epm[:, 1],
        "epm_vx_mps": speed * heading[0],
        "epm_vy_mps": speed * heading[1],
        "capsule_x_m": capsule[:, 0],
        "capsule_y_m": capsule[:, 1],
        "meas_x_m": meas[:, 0],
        "meas_y_m": meas[:, 1],
    }


def test_the_paper_metric_is_the_oscillation_amplitude_over_root_two():
    log = _synthetic_log()
    # over whole periods sampled evenly, mean(sin) = 0 and mean(sin^2) = 1/2 exactly
    assert paper_std_mm(log, "truth") == pytest.approx(AMPLITUDE_MM / math.sqrt(2.0), rel=1e-9)
    # a constant offset along the lead (the camera's bias here) leaves the spread alone
    assert paper_std_mm(log, "camera") == pytest.approx(AMPLITUDE_MM / math.sqrt(2.0), rel=1e-9)
    assert int(np.count_nonzero(motion_windows(log))) == 8 * round(RATE_HZ * PERIOD_S)


def test_a_lead_that_changes_with_the_heading_only_is_all_between_legs():
    """An L of two equal legs, 13 mm behind along x, 21 mm along y: the STD is half the difference."""
    n = 60
    t = np.arange(2 * n) / RATE_HZ
    vx = np.r_[np.full(n, 0.02), np.zeros(n)]
    vy = np.r_[np.zeros(n), np.full(n, 0.02)]
    epm = np.column_stack([np.cumsum(vx), np.cumsum(vy)]) / RATE_HZ
    lead = np.r_[np.tile([0.013, 0.0], (n, 1)), np.tile([0.0, 0.021], (n, 1))]
    log = {"t_s": t, "epm_vx_mps": vx, "epm_vy_mps": vy, "epm_x_m": epm[:, 0], "epm_y_m": epm[:, 1]}
    log.update(capsule_x_m=epm[:, 0] - lead[:, 0], capsule_y_m=epm[:, 1] - lead[:, 1])
    split = lead_by_heading_mm(log)
    assert split["lead_x_legs_mm"] == pytest.approx(13.0) and split["lead_y_legs_mm"] == pytest.approx(21.0)
    assert split["paper_std_within_legs_mm"] == pytest.approx(0.0, abs=1e-9)
    assert paper_std_mm(log) == pytest.approx(4.0)


def test_the_metric_is_nan_without_motion_and_refuses_an_unknown_source():
    log = _synthetic_log()
    still = dict(log, epm_vx_mps=np.zeros_like(log["t_s"]), epm_vy_mps=np.zeros_like(log["t_s"]))
    assert math.isnan(paper_std_mm(still))
    with pytest.raises(ValueError, match="source: must be 'truth' or 'camera'"):
        paper_std_mm(log, "both")


def test_scenario_variants_change_one_field_and_refuse_bad_values():
    sc = scenario_variant("paper", {"plant.preset": "ideal", "friction.rate_state.b": 0.03})
    assert sc.plant.preset == "ideal" and sc.friction.rate_state.b == 0.03
    assert sc.friction.rate_state.a == scenario_variant("paper", {}).friction.rate_state.a
    with pytest.raises(ConfigError, match=r"friction\.mu0"):
        scenario_variant("paper", {"friction.mu0": 5.0})


def _renderer():
    return load("reproduction_doc")


def test_the_committed_reproduction_page_is_rendered_from_its_json():
    record = json.loads((REPO / "docs" / "results" / "reproduction.json").read_text(encoding="utf-8"))
    page = (REPO / "docs" / "reproduction.md").read_text(encoding="utf-8")
    assert _renderer().render(record) == page
    assert record["command"].startswith("python benchmarks/reproduction.py")
