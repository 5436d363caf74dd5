"""Figures: the corner finder, the predicted-vs-actual figure and the metrics figure (the others are
drawn by the CLI tests)."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from capsule_mpc.paths import PIPE_BEND_RADIUS_M, ReferencePath, pipe, rectangle
from capsule_mpc.plots import (
    BAR_METRICS,
    DISTRIBUTION_METRICS,
    first_corner_arc_m,
    metric_samples,
    plot_metrics,
    plot_prediction,
)


def test_first_corner_of_a_rectangle_is_its_second_vertex():
    # Counter-clockwise from (-50, -30) mm: the start (a corner at t = 0) is skipped.
    assert first_corner_arc_m(rectangle((0.1, 0.06))) == pytest.approx(0.1)


def test_first_corner_of_a_rounded_bend_is_its_middle():
    p = pipe()
    s = first_corner_arc_m(p)
    corner = np.array([-0.04, -0.04])  # the first (sharp) corner the bend rounds off
    # The middle of a 90 degree fillet of radius r lies r (sqrt 2 - 1) from the sharp corner.
    expected = PIPE_BEND_RADIUS_M * (math.sqrt(2) - 1)
    assert s is not None
    assert np.linalg.norm(p.point_at_arc(s) - corner) == pytest.approx(expected, abs=5e-4)
    # Its tangent there points half way between the two legs (+x then +y).
    before, after = p.point_at_arc(s - 1e-3), p.point_at_arc(s + 1e-3)
    heading = math.degrees(math.atan2(*(after - before)[::-1]))
    assert heading == pytest.approx(45.0, abs=10.0)


def test_straight_path_has_no_corner():
    assert (
        first_corner_arc_m(ReferencePath(np.array([[0.0, 0.0], [0.1, 0.0], [0.2, 0.001]]), False, 0.01))
        is None
    )


def test_prediction_figure_is_written(tmp_path):
    path = ReferencePath(np.array([[0.0, 0.0], [0.02, 0.0], [0.02, 0.02]]), False, 0.01)
    t = np.arange(-0.5, 4.0, 0.1)
    truth = path.position(np.clip(t, 0, None))
    log = {
        "t_s": t,
        "capsule_x_m": truth[:, 0],
        "capsule_y_m": truth[:, 1],
        "solver_failed": np.zeros(len(t)),
    }
    horizon = 0.1 * np.arange(1, 6)
    preds = [None if ti < 0 else path.position(ti + horizon) + 1e-4 for ti in t]
    out = plot_prediction(log, preds, path, tmp_path / "p.png", dt_s=0.1)
    assert out.stat().st_size > 10_000
    with pytest.raises(ValueError, match="no predicted path"):
        plot_prediction(log, [None] * len(t), path, tmp_path / "q.png", dt_s=0.1)
    with pytest.raises(ValueError, match="predictions"):
        plot_prediction(log, np.zeros((3, 5, 2)), path, tmp_path / "r.png", dt_s=0.1)


def png_width_px(path):
    """Width of a PNG image, px (from its IHDR chunk)."""
    return struct.unpack(">I", path.read_bytes()[16:20])[0]


def test_metric_samples_keep_the_finite_values_of_every_run():
    one = {"a": {"x_mm": 1.5}, "b": {"x_mm": math.nan}, "c": {}}
    assert {k: v.tolist() for k, v in metric_samples(one, "x_mm").items()} == {"a": [1.5], "b": [], "c": []}
    runs = {"a": [{"x_mm": 1.0}, {"x_mm": None}, {"x_mm": 3}, {"x_mm": np.float64(2.0)}], "b": []}
    assert {k: v.tolist() for k, v in metric_samples(runs, "x_mm").items()} == {"a": [1.0, 3.0, 2.0], "b": []}


def test_metrics_figure_bars_for_one_run_distributions_for_several(tmp_path):
    run = {"tracking_rms_mm": 2.0, "cross_track_rms_mm": 0.5, "cross_track_max_mm": 1.0, "paper_std_mm": 1.2}
    bars = plot_metrics({"a": run, "b": [dict(run, paper_std_mm=math.nan)]}, tmp_path / "bars.png")
    spread = [dict(run, final_error_mm=e) for e in (1.0, 2.0, 4.0)]
    boxes = plot_metrics(
        {"a": spread, "b": [dict(run, final_error_mm=math.nan)], "c": []}, tmp_path / "boxes.png"
    )
    # One panel per metric, each as wide as the others: the defaults pick the panels.
    assert png_width_px(bars) / len(BAR_METRICS) == pytest.approx(
        png_width_px(boxes) / len(DISTRIBUTION_METRICS)
    )
    assert len(BAR_METRICS) != len(DISTRIBUTION_METRICS)
    assert boxes.stat().st_size > 10_000
    chosen = plot_metrics({"a": spread}, tmp_path / "one.png", keys=[("final_error_mm", "final error, mm")])
    assert png_width_px(chosen) < png_width_px(boxes)
