"""Figures of runs: trajectories (paper Fig. 7a), errors over time (Fig. 8), metrics per controller
(bars for one run, distributions over several), and the MPC's predicted vs actual capsule path at
a corner.

The figures of runs take run logs (column name -> array, see :mod:`capsule_mpc.sim.log`)
keyed by controller name (:func:`plot_metrics`: metrics dicts); each draws with the Agg
backend and writes a PNG, atomically (:func:`capsule_mpc.atomic.atomic_path`: complete or absent).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .atomic import atomic_path
from .metrics import prediction_errors, stack_predictions
from .paths import ReferencePath

__all__ = [
    "BAR_METRICS",
    "CORNER_MIN_TURN_RAD",
    "DISTRIBUTION_METRICS",
    "PREDICTION_ZOOM_M",
    "first_corner_arc_m",
    "metric_samples",
    "plot_errors",
    "plot_metrics",
    "plot_prediction",
    "plot_trajectories",
]

#: Metrics shown in the bar chart of one run per controller: (key in the metrics dict, axis label).
BAR_METRICS: tuple[tuple[str, str], ...] = (
    ("tracking_rms_mm", "tracking RMS |p - ref(t)|, mm"),
    ("cross_track_rms_mm", "cross-track RMS, mm"),
    ("cross_track_max_mm", "cross-track max, mm"),
    ("paper_std_mm", "paper STD |P_E - P_I|, mm"),
)
#: Metrics whose distribution over the runs is shown when controllers have several runs.
DISTRIBUTION_METRICS: tuple[tuple[str, str], ...] = (
    ("tracking_rms_mm", "tracking RMS |p - ref(t)|, mm"),
    ("cross_track_rms_mm", "cross-track RMS, mm"),
    ("final_error_mm", "final error, mm"),
)
#: Space left above the tallest bar for its value, as a fraction of the axis range.
_BAR_HEADROOM = 0.15
#: Width of a box in the distribution plot, in units of the controller spacing.
_BOX_WIDTH = 0.5
#: The runs' points are spread over +- this around their box (controller spacing units).
_STRIP_HALF_WIDTH = 0.15

#: A corner is where the path turns by at least this much within :data:`PREDICTION_ZOOM_M`, rad.
CORNER_MIN_TURN_RAD = math.radians(30.0)
#: Half-width of the zoomed view of the corner in the prediction figure, m.
PREDICTION_ZOOM_M = 0.012
#: The direction-of-travel arrowhead sits this fraction of the path's length after its start.
_DIRECTION_MARK_FRACTION = 0.08
#: Colour of the shaded motion phase in the error figure (neutral: it belongs to no run).
_WINDOW_SHADE = "0.4"
#: Predicted paths drawn in the zoomed view (evenly spread over the frames near the corner).
_PREDICTIONS_DRAWN = 12
#: Colour map of the predicted paths by frame time (its scale is the figure's colour bar).
_PREDICTION_CMAP = "autumn"

Log = Mapping[str, np.ndarray]
#: The metrics of one run (see :func:`capsule_mpc.metrics.run_metrics`).
RunMetrics = Mapping[str, Any]


def _pyplot() -> Any:
    import matplotlib  # lazy: Matplotlib only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, out: str | Path) -> Path:
    out = Path(out)
    try:
        with atomic_path(out) as tmp:
            fig.savefig(tmp, dpi=120)
    finally:
        _pyplot().close(fig)
    return out


def plot_trajectories(logs: Mapping[str, Log], path: ReferencePath, out: str | Path) -> Path:
    """Reference, EPM and capsule paths on the plate, one panel per controller (paper Fig. 7a).

    Each panel marks the path's start and its direction of travel, and where the capsule was at
    the end of the run, with its distance to the path's end (the run's final error) in the
    legend, so a run that stalled shows where. The legend sits beside the panel, hiding no data.

    Parameters
    ----------
    logs : mapping of controller name to run log
        Positions in m; plotted in mm.
    path : ReferencePath
        The reference polyline.
    out : str or Path
        PNG file to write.
    """
    plt = _pyplot()
    n = max(len(logs), 1)
    cols = min(n, 2)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(
        rows, cols, figsize=(8.5 * cols, 4.5 * rows), squeeze=False, layout="constrained"
    )
    ref = path.vertices_m * 1e3
    for ax, (name, log) in zip(axes.ravel(), logs.items()):
        ax.plot(ref[:, 0], ref[:, 1], "k--", lw=1, label="reference")
        ax.plot(log["epm_x_m"] * 1e3, log["epm_y_m"] * 1e3, "r-", lw=1.2, label="EPM")
        ax.plot(log["capsule_x_m"] * 1e3, log["capsule_y_m"] * 1e3, "b-", lw=1.2, label="capsule (IPM)")
        _mark_path_ends(ax, path)
        final = np.array([log["capsule_x_m"][-1], log["capsule_y_m"][-1]], dtype=float)
        error_mm = float(np.hypot(*(final - path.end_m))) * 1e3
        ax.plot(
            *(final * 1e3),
            "D",
            color="b",
            mec="k",
            ms=7,
            zorder=4,
            label=f"capsule at the end of the run:\n{error_mm:.1f} mm from the path's end",
        )
        ax.set_title(name)
        ax.set_xlabel("x, mm")
        ax.set_ylabel("y, mm")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    for ax in axes.ravel()[len(logs) :]:
        ax.set_visible(False)
    return _save(fig, out)


def _mark_path_ends(ax: Any, path: ReferencePath) -> None:
    """The path's start, an arrowhead on it pointing the way of travel, and (if open) its end."""
    start = path.start_m * 1e3
    ax.plot(
        *start,
        "o",
        color="k",
        mfc="w",
        mew=1.5,
        ms=9,
        zorder=4,
        label="path start and end" if path.closed else "path start",
    )
    s = _DIRECTION_MARK_FRACTION * path.length_m
    ahead = path.point_at_arc(s + _DIRECTION_MARK_FRACTION * path.length_m / 10)
    here = path.point_at_arc(s)
    heading_deg = math.degrees(math.atan2(ahead[1] - here[1], ahead[0] - here[0]))
    # A triangle marker points up (+y) unrotated: turn it onto the heading.
    ax.plot(
        *(here * 1e3),
        marker=(3, 0, heading_deg - 90.0),
        color="k",
        ms=10,
        ls="none",
        zorder=4,
        label="direction of travel",
    )
    if not path.closed:
        ax.plot(*(path.end_m * 1e3), "s", color="k", mfc="w", mew=1.5, ms=8, zorder=4, label="path end")


def plot_errors(
    logs: Mapping[str, Log],
    path: ReferencePath,
    out: str | Path,
    motion_end_s: Mapping[str, float] | None = None,
) -> Path:
    """Cross-track error and EPM-IPM distance over time, all controllers (paper Fig. 8).

    The motion phase, t = 0 until the last run is at rest (the window the runs are scored on),
    is shaded once in grey; if the runs' motion phases end at different times, each run's end
    is a dotted line in its colour, given in its legend label. One legend beside the panels.

    Parameters
    ----------
    logs : mapping of controller name to run log
    path : ReferencePath
        The reference, for the cross-track error.
    out : str or Path
        PNG file to write.
    motion_end_s : mapping of controller name to float, optional
        End of each run's motion phase, s (non-finite values are left out).
    """
    plt = _pyplot()
    fig, (ax_ct, ax_pe) = plt.subplots(2, 1, figsize=(11, 6.5), sharex=True, layout="constrained")
    ends = {n: float(e) for n, e in (motion_end_s or {}).items() if n in logs and math.isfinite(float(e))}
    differ = len(set(ends.values())) > 1
    for name, log in logs.items():
        t = log["t_s"]
        capsule = np.column_stack([log["capsule_x_m"], log["capsule_y_m"]])
        label = f"{name} (motion ends {ends[name]:.1f} s)" if differ and name in ends else name
        (line,) = ax_ct.plot(t, path.distance_to(capsule) * 1e3, lw=1, label=label)
        d = np.hypot(log["epm_x_m"] - log["capsule_x_m"], log["epm_y_m"] - log["capsule_y_m"])
        ax_pe.plot(t, d * 1e3, lw=1, color=line.get_color())
        if differ and name in ends:
            for ax in (ax_ct, ax_pe):
                ax.axvline(ends[name], color=line.get_color(), ls=":", lw=1)
    if ends:
        end = max(ends.values())
        until = "the last run stopped" if len(ends) > 1 else "the run stopped"
        for ax in (ax_ct, ax_pe):
            ax.axvspan(
                0.0,
                end,
                color=_WINDOW_SHADE,
                alpha=0.12,
                lw=0,
                label=f"motion phase (scored):\nt = 0 until {until}, {end:.1f} s",
            )
    ax_ct.set_ylabel("cross-track error, mm")
    ax_pe.set_ylabel("EPM-capsule distance\n|P_E - P_I|, mm")
    ax_pe.set_xlabel("time, s (path starts at 0)")
    for ax in (ax_ct, ax_pe):
        ax.grid(alpha=0.3)
    ax_ct.set_title("tracking error over time")
    fig.legend(*ax_ct.get_legend_handles_labels(), fontsize=8, loc="outside right upper")
    return _save(fig, out)


def metric_samples(
    metrics: Mapping[str, RunMetrics | Sequence[RunMetrics]], key: str
) -> dict[str, np.ndarray]:
    """The finite values of one metric per controller, over its runs.

    Parameters
    ----------
    metrics : mapping of controller name to a metrics dict or a sequence of them (one per run)
    key : str
        The metric.

    Returns
    -------
    dict of str to numpy.ndarray
        Per controller, the finite values of ``key`` in run order (missing, None and NaN left out).
    """
    out = {}
    for name, runs in _per_run(metrics).items():
        values = [r.get(key) for r in runs]
        out[name] = np.array(
            [float(v) for v in values if isinstance(v, (int, float)) and math.isfinite(v)], dtype=float
        )
    return out


def _per_run(metrics: Mapping[str, RunMetrics | Sequence[RunMetrics]]) -> dict[str, list[RunMetrics]]:
    return {name: [m] if isinstance(m, Mapping) else list(m) for name, m in metrics.items()}


def plot_metrics(
    metrics: Mapping[str, RunMetrics | Sequence[RunMetrics]],
    out: str | Path,
    keys: Sequence[tuple[str, str]] | None = None,
) -> Path:
    """Metrics per controller: bars for one run each, the distribution over the runs for several.

    With one run per controller, a bar chart (missing or non-finite values: no bar, "n/a").
    When any controller has several runs, a box plot per controller (median, quartiles,
    whiskers at 1.5 IQR) with every run drawn as a point over it; NaN values are left out and
    the number of values drawn is given with each controller's name.

    Parameters
    ----------
    metrics : mapping of controller name to a metrics dict or a sequence of them (one per run)
    out : str or Path
        PNG file to write.
    keys : sequence of (metric key, label), optional
        Which metrics to show, one panel each; default :data:`BAR_METRICS` for one run per
        controller, :data:`DISTRIBUTION_METRICS` for several.
    """
    plt = _pyplot()
    runs = _per_run(metrics)
    several = any(len(r) > 1 for r in runs.values())
    if keys is None:
        keys = DISTRIBUTION_METRICS if several else BAR_METRICS
    names = list(runs)
    fig, axes = plt.subplots(1, len(keys), figsize=(4.2 * len(keys), 3.8), squeeze=False)
    for ax, (key, label) in zip(axes.ravel(), keys):
        samples = metric_samples(metrics, key)
        if several:
            _draw_distribution(ax, names, samples)
            ticks = [f"{n}\n(n = {samples[n].size})" for n in names]
        else:
            _draw_bars(ax, names, samples)
            ticks = names
        ax.set_xticks(range(len(names)), ticks, rotation=20)
        ax.set_ylabel(label, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    if several:
        fig.suptitle(
            "dots: one run each; box: median and quartiles; whiskers: the furthest run within 1.5 IQR",
            fontsize=9,
        )
    fig.tight_layout()
    return _save(fig, out)


def _draw_bars(ax: Any, names: Sequence[str], samples: Mapping[str, np.ndarray]) -> None:
    values = [float(samples[n][0]) if samples[n].size else None for n in names]
    heights = [0.0 if v is None else v for v in values]
    bars = ax.bar(range(len(names)), heights, color=[f"C{i}" for i in range(len(names))])
    for bar, v in zip(bars, values):
        text = "n/a" if v is None else f"{v:.2f}"
        ax.annotate(text, (bar.get_x() + bar.get_width() / 2, bar.get_height()), ha="center", va="bottom")
    ax.margins(y=_BAR_HEADROOM)  # room above the tallest bar for its value


def _draw_distribution(ax: Any, names: Sequence[str], samples: Mapping[str, np.ndarray]) -> None:
    drawn = [i for i, n in enumerate(names) if samples[n].size]
    if drawn:
        ax.boxplot(
            [samples[names[i]] for i in drawn],
            positions=drawn,
            widths=_BOX_WIDTH,
            showfliers=False,  # every run is drawn as a point anyway
            medianprops={"color": "k"},
        )
    for i, name in enumerate(names):
        values = samples[name]
        if values.size:
            offsets = (
                np.linspace(-_STRIP_HALF_WIDTH, _STRIP_HALF_WIDTH, values.size) if values.size > 1 else 0.0
            )
            ax.plot(i + offsets, values, "o", color=f"C{i}", ms=4, alpha=0.7)
    ax.set_xlim(-0.5, len(names) - 0.5)


def first_corner_arc_m(path: ReferencePath, window_m: float = PREDICTION_ZOOM_M) -> float | None:
    """Arc length (m) of the first corner after the start, or None if the path never turns.

    The turn at each interior vertex is summed over ``+-window_m`` of arc length, so a rounded
    bend (many small turns) counts as one corner; the corner is the turn-weighted centre of the
    first run of vertices whose summed turn reaches :data:`CORNER_MIN_TURN_RAD`.
    """
    v = path.vertices_m
    seg = np.diff(v, axis=0)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    heading = np.arctan2(seg[:, 1], seg[:, 0])
    turn = np.abs(np.angle(np.exp(1j * np.diff(heading))))  # at interior vertices 1..M-2
    s_v = arc[1:-1]
    if turn.size == 0:
        return None
    near = np.abs(s_v[:, None] - s_v[None, :]) <= window_m
    summed = near @ turn
    hit = summed >= CORNER_MIN_TURN_RAD
    if not np.any(hit):
        return None
    first = int(np.argmax(hit))
    last = first
    while last + 1 < len(hit) and hit[last + 1] and s_v[last + 1] - s_v[last] <= window_m:
        last += 1
    w = turn[first : last + 1]
    return float(np.sum(w * s_v[first : last + 1]) / np.sum(w)) if np.sum(w) > 0 else float(s_v[first])


def _draw_predictions(plt: Any, fig: Any, ax: Any, pred: np.ndarray, t: np.ndarray, idx: np.ndarray) -> None:
    """Draw up to :data:`_PREDICTIONS_DRAWN` of the predictions made at frames ``idx``, coloured by
    their frame time on a colour bar beside ``ax``."""
    if not idx.size:
        return
    chosen = idx[
        np.unique(np.linspace(0, idx.size - 1, min(_PREDICTIONS_DRAWN, idx.size)).round().astype(int))
    ]
    cmap = plt.get_cmap(_PREDICTION_CMAP)
    frame_time = plt.Normalize(float(t[chosen[0]]), float(t[chosen[-1]]))
    for k, i in enumerate(chosen):
        colour = cmap(frame_time(t[i]))
        xy = pred[i] * 1e3
        first = k == 0
        ax.plot(
            xy[:, 0],
            xy[:, 1],
            "-",
            color=colour,
            lw=1,
            label="predicted at a frame (colour bar: its time)" if first else None,
        )
        ax.plot(
            xy[0, 0],
            xy[0, 1],
            "o",
            color=colour,
            ms=3,
            label="estimate one stage ahead (where a prediction starts)" if first else None,
        )
    # The bar hangs off the zoomed axes itself, so it stays beside it whatever its aspect does.
    bar = fig.colorbar(plt.cm.ScalarMappable(frame_time, cmap), cax=ax.inset_axes((1.03, 0.0, 0.04, 1.0)))
    bar.set_label("frame time of the prediction, s (path starts at 0)")


def plot_prediction(
    log: Log,
    predictions: np.ndarray | Sequence[np.ndarray | None],
    path: ReferencePath,
    out: str | Path,
    dt_s: float,
    title: str = "mpc",
    first_s: float | None = None,
) -> Path:
    """The controller's predicted capsule paths vs the actual path at the first corner.

    Left: a :data:`PREDICTION_ZOOM_M` view of the first corner after t = 0 with the
    reference, the true capsule path and the paths predicted at frames near the corner (each
    starting where the controller estimated the capsule one stage ahead; their colour is the frame
    time, on the colour bar beside the view).
    Right: RMS and max distance between a prediction and where the capsule really was, against
    the look-ahead time (:func:`capsule_mpc.metrics.prediction_errors`), over the whole motion
    and over the corner frames.

    Parameters
    ----------
    log : run log
        ``t_s``, ``capsule_x_m``, ``capsule_y_m`` (and ``solver_failed``: frames whose step
        failed are left out, as their prediction is an older one).
    predictions : numpy.ndarray (F, N, 2) or sequence of (N, 2) arrays / None
        The predicted capsule path after each frame's step, m (NaN or None where none).
    path : ReferencePath
        The reference.
    out : str or Path
        PNG file to write.
    dt_s : float
        Time between prediction stages, s.
    title : str
        Controller name for the title.
    first_s : float, optional
        Look-ahead of the first stage, s (default ``dt_s``).
    """
    plt = _pyplot()
    stacked = predictions if isinstance(predictions, np.ndarray) else stack_predictions(list(predictions))
    if stacked is None:
        raise ValueError("predictions: the run has no predicted path (its controller does not predict)")
    pred = np.asarray(stacked, dtype=float)
    if pred.ndim != 3 or pred.shape[0] != len(log["t_s"]) or pred.shape[2] != 2:
        raise ValueError(f"predictions: must have shape ({len(log['t_s'])}, N, 2), got {pred.shape}")
    t = np.asarray(log["t_s"], dtype=float)
    usable = np.all(np.isfinite(pred), axis=(1, 2)) & (t >= 0)
    if "solver_failed" in log:
        usable &= np.asarray(log["solver_failed"]) == 0
    s_c = first_corner_arc_m(path)
    if s_c is None:  # no corner: the middle of the path
        s_c = path.length_m / 2
    corner = path.point_at_arc(s_c)
    t_c = s_c / path.speed_mps
    zoom = min(PREDICTION_ZOOM_M, path.length_m / 4)
    window_s = 1.5 * zoom / path.speed_mps
    near = usable & (np.abs(t - t_c) <= window_s)
    fig, (ax, ax_err) = plt.subplots(1, 2, figsize=(13, 6.2), layout="constrained")
    ref = path.vertices_m * 1e3
    ax.plot(ref[:, 0], ref[:, 1], "k--", lw=1, label="reference")
    ax.plot(
        log["capsule_x_m"] * 1e3, log["capsule_y_m"] * 1e3, "b-", lw=2, alpha=0.6, label="capsule (actual)"
    )
    _draw_predictions(plt, fig, ax, pred, t, np.flatnonzero(near))
    ax.plot(*(corner * 1e3), "k+", ms=12, mew=1.5, ls="none", label="corner")
    # Centre the view inside the turn, so both legs of the corner are in it.
    d_in = corner - path.point_at_arc(s_c - zoom)
    d_out = path.point_at_arc(s_c + zoom) - corner
    inward = d_out / max(float(np.linalg.norm(d_out)), 1e-12) - d_in / max(float(np.linalg.norm(d_in)), 1e-12)
    centre = corner + 0.5 * zoom * inward / max(float(np.linalg.norm(inward)), 1e-12)
    ax.set_xlim((centre[0] - zoom) * 1e3, (centre[0] + zoom) * 1e3)
    ax.set_ylim((centre[1] - zoom) * 1e3, (centre[1] + zoom) * 1e3)
    ax.set_aspect("equal")
    ax.set_xlabel("x, mm")
    ax.set_ylabel("y, mm")
    ax.set_title(f"{title}: predicted vs actual capsule path, first corner (t ~ {t_c:.1f} s)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncols=2)
    for frames, label, style in ((usable, "whole motion", "-"), (near, "corner frames", "--")):
        if not np.any(frames):
            continue
        look, rms, worst = prediction_errors(log, pred, dt_s, frames, first_s)
        (line,) = ax_err.plot(look, rms * 1e3, style, lw=1.5, label=f"RMS, {label}")
        ax_err.plot(
            look, worst * 1e3, style, lw=0.8, color=line.get_color(), alpha=0.6, label=f"max, {label}"
        )
    ax_err.set_xlabel("look-ahead, s")
    ax_err.set_ylabel("|predicted - actual| capsule position, mm")
    ax_err.set_title("prediction error against look-ahead", fontsize=10)
    ax_err.grid(alpha=0.3)
    ax_err.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncols=2)
    return _save(fig, out)
