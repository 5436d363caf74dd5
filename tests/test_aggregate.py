"""The run table (:mod:`capsule_mpc.experiments.table`) and its one aggregation
(:mod:`capsule_mpc.experiments.aggregate`) against numbers worked out by hand."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from capsule_mpc.experiments.aggregate import aggregate, mean_sd_worst, paired
from capsule_mpc.experiments.table import entry_rows, read_table, table_from_entries, write_table


def _draw(seed: int, paper: float, learned: float | None, stalled: bool) -> dict:
    """One draw of two variants of the MPC; ``learned`` None: that run raised."""
    runs = {"paper:mpc": {"tracking_rms_mm": paper, "stalled": stalled, "outcome": "completed"}}
    runs["learned:mpc"] = (
        {"error": "RuntimeError: boom", "traceback": "..."}
        if learned is None
        else {"tracking_rms_mm": learned, "stalled": False, "outcome": "completed"}
    )
    return {
        "seed": seed,
        "window_end_s": 20.0,
        "controllers": runs,
        "plant": {"seed": seed, "mu0_scale": 0.9},
    }


#: paper 1, 2, 3, 6 (stalled on seeds 0 and 3); learned 1.5, 1, 5 and a failed run on seed 3.
DRAWS = [
    _draw(0, 1.0, 1.5, True),
    _draw(1, 2.0, 1.0, False),
    _draw(2, 3.0, 5.0, False),
    _draw(3, 6.0, None, True),
]


def test_a_row_per_draw_variant_and_controller_with_its_draw():
    rows = entry_rows(DRAWS[3])
    assert [(r["seed"], r["variant"], r["controller"]) for r in rows] == [
        (3, "paper", "mpc"),
        (3, "learned", "mpc"),
    ]
    assert rows[0]["plant.mu0_scale"] == 0.9 and "plant.seed" not in rows[0]  # the seed is a key already
    assert rows[1]["error"] == "RuntimeError: boom" and "traceback" not in rows[1]
    assert rows[0]["error"] == ""


def test_aggregate_by_hand():
    stats = aggregate(table_from_entries(DRAWS))
    paper, learned = stats.loc[("paper", "mpc")], stats.loc[("learned", "mpc")]
    # paper: 1, 2, 3, 6 -> mean 3, sd sqrt(((-2)^2 + 1 + 0 + 9) / 3) = sqrt(14/3), worst 6
    assert paper[("tracking_rms_mm", "mean")] == pytest.approx(3.0)
    assert paper[("tracking_rms_mm", "sd")] == pytest.approx(math.sqrt(14 / 3))
    assert (paper[("tracking_rms_mm", "min")], paper[("tracking_rms_mm", "worst")]) == (1.0, 6.0)
    assert (paper[("stalled", "count")], paper[("stalled", "n")]) == (2, 4)
    # learned: 1.5, 1, 5 (seed 3 failed) -> mean 2.5, sd sqrt((1 + 2.25 + 6.25) / 2) = sqrt(4.75)
    assert learned[("tracking_rms_mm", "mean")] == pytest.approx(2.5)
    assert learned[("tracking_rms_mm", "sd")] == pytest.approx(math.sqrt(4.75))
    assert (learned[("runs", "n")], learned[("failed", "n")]) == (3, 1)
    assert "outcome" not in stats.columns.get_level_values(0)  # text is not aggregated


def test_one_value_has_sd_0_and_a_group_without_a_finished_run_has_no_numbers():
    stats = aggregate(table_from_entries(DRAWS[3:]))
    assert stats.loc[("paper", "mpc"), ("tracking_rms_mm", "sd")] == 0.0
    assert math.isnan(stats.loc[("learned", "mpc"), ("tracking_rms_mm", "mean")])
    assert stats.loc[("learned", "mpc"), ("failed", "n")] == 1


def test_paired_difference_by_hand():
    diff = paired(table_from_entries(DRAWS), {"variant": "paper"}, ["tracking_rms_mm"])
    learned = diff.loc[("learned", "mpc")]
    # learned - paper on seeds 0-2 (seed 3 failed): +0.5, -1, +2 -> mean 0.5, better on 1, worst 2
    assert learned[("tracking_rms_mm", "mean")] == pytest.approx(0.5)
    assert learned[("tracking_rms_mm", "sd")] == pytest.approx(math.sqrt((0 + 2.25 + 2.25) / 2))
    assert (learned[("tracking_rms_mm", "better")], learned[("tracking_rms_mm", "worst")]) == (1, 2.0)
    assert learned[("tracking_rms_mm", "relative")] == pytest.approx(0.5 / 2.0)  # paper's mean on seeds 0-2
    assert diff.loc[("paper", "mpc"), ("tracking_rms_mm", "mean")] == 0.0


def test_the_table_reads_back_as_written(tmp_path):
    table = table_from_entries(DRAWS)
    back = read_table(write_table(table, tmp_path / "runs.csv"))
    assert list(back.columns) == list(table.columns)
    assert back["stalled"].dtype == "boolean" and back["error"].tolist() == table["error"].tolist()
    pd.testing.assert_frame_equal(aggregate(back), aggregate(table))


def test_mean_sd_worst_text():
    assert mean_sd_worst(2.0, 1.0, 3.0) == "2.00 ± 1.00 (3.00)"
    assert mean_sd_worst(math.nan, 0.0, 0.0) == "n/a"
