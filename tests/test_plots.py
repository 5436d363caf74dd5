"""Figures: the corner finder, and what each figure shows (checked on its matplotlib objects: the
legends hide no data, markers sit where they should, colours are explained)."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pytest

from capsule_mpc import plots
from capsule_mpc.paths import PIPE_BEND_RADIUS_M, ReferencePath, pipe, rectangle
from capsule_mpc.plots import (
    BAR_METRICS,
    DISTRIBUTION_METRICS,
    first_corner_arc_m,
    metric_samples,
    plot_errors,
    plot_metrics,
    plot_prediction,
    plot_trajectories,
)


@pytest.fixture
def figures(monkeypatch):
    """The figures the plots module saves, kept open after drawing (so their artists have extents)."""
    kept = []

    def save(fig, out):
        out = Path(out)
        fig.savefig(out, dpi=120)
        fig.canvas.draw()
        kept.append(fig)
        return out

    monkeypatch.setattr(plots, "_save", save)
    yield kept
    for fig in kept:
        plt.close(fig)


def run_log(path, stop_s=math.inf, lead_m=(-0.017, 0.0)):
    """A run log that follows ``path`` exactly from t = 0 and stays put after ``stop_s``."""
    t = np.arange(-1.0, path.duration_s + 3.0, 0.05)
    capsule = path.position(np.clip(t, 0.0, min(stop_s, path.duration_s)))
    epm = capsule + np.asarray(lead_m)
    return {
        "t_s": t,
        "capsule_x_m": capsule[:, 0],
        "capsule_y_m": capsule[:, 1],
        "epm_x_m": epm[:, 0],
        "epm_y_m": epm[:, 1],
    }


def assert_legend_hides_no_data(fig, legend, axes):
    """The legend lies outside every one of ``axes`` and covers none of their lines' points."""
    box = legend.get_window_extent(fig.canvas.get_renderer())
    for ax in axes:
        assert not box.overlaps(ax.get_window_extent()), ax.get_title()
        for line in ax.get_lines():
            xy = line.get_transform().transform(np.column_stack(line.get_data()))
            inside = (xy[:, 0] > box.x0) & (xy[:, 0] < box.x1) & (xy[:, 1] > box.y0) & (xy[:, 1] < box.y1)
            assert not np.any(inside), line.get_label()


def labelled(ax, start):
    """The line of ``ax`` whose legend label starts with ``start``."""
    (line,) = [ln for ln in ax.get_lines() if ln.get_label().startswith(start)]
    return line


def test_trajectory_figure_marks_start_direction_and_where_each_run_ended(tmp_path, figures):
    path = rectangle((0.1, 0.06))
    logs = {"follow": run_log(path), "stalled": run_log(path, stop_s=7.0)}
    plot_trajectories(logs, path, tmp_path / "t.png")
    (fig,) = figures
    axes = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title() for ax in axes] == ["follow", "stalled"]
    for ax, log in zip(axes, logs.values()):
        assert_legend_hides_no_data(fig, ax.get_legend(), axes)
        start = labelled(ax, "path start")
        assert np.column_stack(start.get_data()) == pytest.approx(path.start_m[None, :] * 1e3)
        # The arrowhead sits on the first leg (+x from the lower-left corner) and points along it.
        arrow = labelled(ax, "direction of travel")
        (x, y), angle = np.column_stack(arrow.get_data())[0], arrow.get_marker()[2]
        assert y == pytest.approx(-30.0) and -50.0 < x < 50.0
        assert angle + 90.0 == pytest.approx(0.0)
        final = labelled(ax, "capsule at the end")
        last = np.array([log["capsule_x_m"][-1], log["capsule_y_m"][-1]])
        assert np.column_stack(final.get_data())[0] == pytest.approx(last * 1e3)
        error_mm = np.hypot(*(last - path.end_m)) * 1e3
        assert f"{error_mm:.1f} mm" in final.get_label()
    # The stalled run stopped 140 mm along the path, at (50, 10) mm: hypot(100, 40) mm from the
    # end of the closed path (its start).
    assert "107.7 mm from the path's end" in labelled(axes[1], "capsule at the end").get_label()


def test_open_path_marks_its_end(tmp_path, figures):
    path = ReferencePath(np.array([[0.0, 0.0], [0.0, 0.04], [0.03, 0.04]]), False, 0.01)
    plot_trajectories({"a": run_log(path)}, path, tmp_path / "t.png")
    ax = figures[0].axes[0]
    assert labelled(ax, "path start").get_label() == "path start"
    assert np.column_stack(labelled(ax, "path end").get_data())[0] == pytest.approx([30.0, 40.0])
    assert labelled(ax, "direction of travel").get_marker()[2] + 90.0 == pytest.approx(90.0)


def test_error_figure_shades_the_motion_phase_once_in_a_neutral_colour(tmp_path, figures):
    path = rectangle((0.1, 0.06))
    logs = {name: run_log(path, stop_s=stop) for name, stop in (("a", 20.0), ("b", 12.0), ("c", 16.0))}
    plot_errors(logs, path, tmp_path / "e.png", dict.fromkeys(logs, 19.0))
    (fig,) = figures
    (legend,) = fig.legends
    assert_legend_hides_no_data(fig, legend, fig.axes)
    for ax in fig.axes:
        (band,) = ax.patches
        r, g, b, _ = band.get_facecolor()
        assert r == g == b  # grey: it belongs to no run
        x0, x1 = band.get_bbox().x0, band.get_bbox().x1
        assert (x0, x1) == pytest.approx((0.0, 19.0))
        assert ax.get_ylabel().endswith(", mm")
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels[:3] == ["a", "b", "c"]
    assert "motion phase" in labels[3] and "19.0 s" in labels[3]


def test_error_figure_marks_each_run_whose_motion_ends_earlier(tmp_path, figures):
    path = rectangle((0.1, 0.06))
    logs = {"a": run_log(path), "b": run_log(path)}
    plot_errors(logs, path, tmp_path / "e.png", {"a": 17.0, "b": 21.0})
    (fig,) = figures
    for ax in fig.axes:
        (band,) = ax.patches
        assert band.get_bbox().x1 == pytest.approx(21.0)
        ends = sorted(ln.get_xdata()[0] for ln in ax.get_lines() if ln.get_linestyle() == ":")
        assert ends == pytest.approx([17.0, 21.0])
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels[:2] == ["a (motion ends 17.0 s)", "b (motion ends 21.0 s)"]


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


def corner_prediction():
    """A run along an L with predictions 0.1 mm off the truth, and the figure's arguments."""
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
    return log, preds, path


def test_prediction_figure_is_written(tmp_path):
    log, preds, path = corner_prediction()
    out = plot_prediction(log, preds, path, tmp_path / "p.png", dt_s=0.1)
    assert out.stat().st_size > 10_000
    with pytest.raises(ValueError, match="no predicted path"):
        plot_prediction(log, [None] * len(log["t_s"]), path, tmp_path / "q.png", dt_s=0.1)
    with pytest.raises(ValueError, match="predictions"):
        plot_prediction(log, np.zeros((3, 5, 2)), path, tmp_path / "r.png", dt_s=0.1)


def test_prediction_figure_has_a_colour_bar_of_frame_time(tmp_path, figures):
    log, preds, path = corner_prediction()
    plot_prediction(log, preds, path, tmp_path / "p.png", dt_s=0.1)
    (fig,) = figures
    ax, ax_err = fig.axes[:2]
    (bar,) = ax.child_axes
    assert bar.get_ylabel().startswith("frame time") and ", s" in bar.get_ylabel()
    # Its scale spans the frames whose predictions are drawn (their first points are the dots).
    starts = [ln for ln in ax.get_lines() if ln.get_marker() == "o"]
    t_drawn = []
    for line in starts:
        first = np.column_stack(line.get_data())[0] * 1e-3
        (i,) = [i for i, p in enumerate(preds) if p is not None and np.allclose(p[0], first)]
        t_drawn.append(log["t_s"][i])
    assert len(t_drawn) > 2
    assert bar.get_ylim() == pytest.approx((min(t_drawn), max(t_drawn)))
    # Each prediction's colour is the bar's colour at its frame time.
    cmap, norm = plt.get_cmap(plots._PREDICTION_CMAP), plt.Normalize(*bar.get_ylim())
    for line, t in zip(starts, t_drawn):
        assert line.get_color() == pytest.approx(cmap(norm(t)))
    for a in (ax, ax_err):
        assert_legend_hides_no_data(fig, a.get_legend(), [ax, ax_err])
    assert "corner" in [t.get_text() for t in ax.get_legend().get_texts()]


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


def test_metrics_figure_labels_its_axes_and_keeps_the_values_inside(tmp_path, figures):
    runs = {"a": {"tracking_rms_mm": 31.95}, "b": {"tracking_rms_mm": 5.07}, "c": {"tracking_rms_mm": 0.97}}
    plot_metrics(runs, tmp_path / "m.png", keys=[("tracking_rms_mm", "tracking RMS, mm")])
    spread = {"a": [{"tracking_rms_mm": v} for v in (1.0, 2.0, 3.0)]}
    plot_metrics(spread, tmp_path / "d.png", keys=[("tracking_rms_mm", "tracking RMS, mm")])
    bars, boxes = figures
    ax = bars.axes[0]
    assert ax.get_ylabel() == "tracking RMS, mm"
    frame = ax.get_window_extent()
    for text in ax.texts:  # each value inside the axes, clear of its frame by half a line
        box = text.get_window_extent(bars.canvas.get_renderer())
        assert frame.y0 <= box.y0 and box.y1 + box.height / 2 <= frame.y1, text.get_text()
    assert boxes.axes[0].get_ylabel() == "tracking RMS, mm"
    assert "median and quartiles" in boxes.get_suptitle()
