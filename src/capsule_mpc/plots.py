"""Figures of runs: trajectories (paper Fig. 7a), errors over time (Fig. 8) and a metrics bar chart.

Every function takes run logs (column name -> array, see :mod:`capsule_mpc.sim.log`)
keyed by controller name, draws with the Agg backend and writes a PNG.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .paths import ReferencePath

__all__ = ["BAR_METRICS", "plot_errors", "plot_metrics", "plot_trajectories"]

#: Metrics shown in the bar chart: (key in the metrics dict, axis label).
BAR_METRICS: tuple[tuple[str, str], ...] = (
    ("cross_track_rms_mm", "cross-track RMS, mm"),
    ("cross_track_max_mm", "cross-track max, mm"),
    ("paper_std_mm", "paper STD |P_E - P_I|, mm"),
)

Log = Mapping[str, np.ndarray]


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, out: str | Path) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    _pyplot().close(fig)
    return out


def plot_trajectories(logs: Mapping[str, Log], path: ReferencePath, out: str | Path) -> Path:
    """Reference, EPM and capsule paths on the plate, one panel per controller (paper Fig. 7a).

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
    fig, axes = plt.subplots(rows, cols, figsize=(6 * cols, 4.5 * rows), squeeze=False)
    ref = path.vertices_m * 1e3
    for ax, (name, log) in zip(axes.ravel(), logs.items()):
        ax.plot(ref[:, 0], ref[:, 1], "k--", lw=1, label="reference")
        ax.plot(log["epm_x_m"] * 1e3, log["epm_y_m"] * 1e3, "r-", lw=1.2, label="EPM")
        ax.plot(log["capsule_x_m"] * 1e3, log["capsule_y_m"] * 1e3, "b-", lw=1.2, label="capsule (IPM)")
        ax.set_title(name)
        ax.set_xlabel("x, mm")
        ax.set_ylabel("y, mm")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    for ax in axes.ravel()[len(logs) :]:
        ax.set_visible(False)
    fig.tight_layout()
    return _save(fig, out)


def plot_errors(
    logs: Mapping[str, Log],
    path: ReferencePath,
    out: str | Path,
    motion_end_s: Mapping[str, float] | None = None,
) -> Path:
    """Cross-track error and EPM-IPM distance over time, all controllers (paper Fig. 8).

    Parameters
    ----------
    logs : mapping of controller name to run log
    path : ReferencePath
        The reference, for the cross-track error.
    out : str or Path
        PNG file to write.
    motion_end_s : mapping of controller name to float, optional
        End of each run's motion phase, s; the motion phases are shaded.
    """
    plt = _pyplot()
    fig, (ax_ct, ax_pe) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    for name, log in logs.items():
        t = log["t_s"]
        capsule = np.column_stack([log["capsule_x_m"], log["capsule_y_m"]])
        (line,) = ax_ct.plot(t, path.distance_to(capsule) * 1e3, lw=1, label=name)
        d = np.hypot(log["epm_x_m"] - log["capsule_x_m"], log["epm_y_m"] - log["capsule_y_m"])
        ax_pe.plot(t, d * 1e3, lw=1, color=line.get_color(), label=name)
        if motion_end_s is not None and name in motion_end_s:
            for ax in (ax_ct, ax_pe):
                ax.axvspan(0.0, motion_end_s[name], color=line.get_color(), alpha=0.06)
    ax_ct.set_ylabel("cross-track error, mm")
    ax_pe.set_ylabel("|P_E - P_I|, mm")
    ax_pe.set_xlabel("time, s (path starts at 0)")
    for ax in (ax_ct, ax_pe):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    ax_ct.set_title("tracking error over time (shaded: motion phase)")
    fig.tight_layout()
    return _save(fig, out)


def plot_metrics(
    metrics: Mapping[str, Mapping[str, Any]],
    out: str | Path,
    keys: Sequence[tuple[str, str]] = BAR_METRICS,
) -> Path:
    """Bar chart of metrics per controller (missing or non-finite values are left out).

    Parameters
    ----------
    metrics : mapping of controller name to metrics dict
    out : str or Path
        PNG file to write.
    keys : sequence of (metric key, label)
        Which metrics to show, one panel each.
    """
    plt = _pyplot()
    names = list(metrics)
    fig, axes = plt.subplots(1, len(keys), figsize=(4.2 * len(keys), 3.8), squeeze=False)
    for ax, (key, label) in zip(axes.ravel(), keys):
        values = [metrics[n].get(key) for n in names]
        heights = [float(v) if isinstance(v, (int, float)) and math.isfinite(v) else 0.0 for v in values]
        bars = ax.bar(range(len(names)), heights, color=[f"C{i}" for i in range(len(names))])
        for bar, v in zip(bars, values):
            text = f"{v:.2f}" if isinstance(v, (int, float)) and math.isfinite(v) else "n/a"
            ax.annotate(text, (bar.get_x() + bar.get_width() / 2, bar.get_height()), ha="center", va="bottom")
        ax.set_xticks(range(len(names)), names, rotation=20)
        ax.set_title(label, fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return _save(fig, out)
