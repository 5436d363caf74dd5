"""Figures of a friction fit, as the paper's Fig. 7b (c against v) and Fig. 7c (residuals)."""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..atomic import atomic_path
from ..config import PAPER_C_COEFFICIENTS, PAPER_C_VALIDITY_MPS
from .core import LearningResult

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["figure_paths", "plot_c_fit", "plot_residuals", "save_figures"]

#: Most sample points drawn in a scatter (a seeded random subset beyond that keeps files small).
_MAX_POINTS = 20000


def _subset(n: int, seed: int = 0) -> np.ndarray:
    if n <= _MAX_POINTS:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, _MAX_POINTS, replace=False))


def _axes(ax: Axes | None) -> tuple[Figure, Axes]:
    if ax is not None:
        return ax.figure, ax  # type: ignore[return-value]
    import matplotlib  # lazy: Matplotlib only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, new_ax = plt.subplots(figsize=(6.4, 4.2), layout="constrained")
    return fig, new_ax


def plot_c_fit(result: LearningResult, ax: Axes | None = None, paper: bool = True) -> Figure:
    """c against v: the samples, the fitted polynomial, its validity band (paper Fig. 7b).

    Parameters
    ----------
    result : LearningResult
        A fit.
    ax : matplotlib Axes, optional
        Draw here; default a new figure (Agg backend).
    paper : bool
        Also draw the paper's polynomial over its own validity range, for reference.
    """
    fig, ax = _axes(ax)
    cs, fit = result.c_samples, result.fit
    idx = _subset(len(cs.c))
    ax.scatter(
        cs.speed_mps[idx] * 1e3,
        cs.c[idx],
        s=2,
        alpha=0.3,
        color="tab:blue",
        rasterized=True,
        label=f"samples (n = {len(cs.c)})",
    )
    lo, hi = fit.validity_mps
    ax.axvspan(lo * 1e3, hi * 1e3, color="tab:green", alpha=0.08, label="validity range")
    v = np.linspace(lo, hi, 300)
    r2 = "n/a" if fit.r2 is None else f"{fit.r2:.3f}"
    ax.plot(
        v * 1e3,
        fit(v),
        color="tab:red",
        lw=2,
        label=f"fit, degree {fit.degree}{' (Huber)' if fit.robust else ''}, R$^2$ = {r2}",
    )
    lo_c, hi_c = np.percentile(cs.c, [0.5, 99.5]) if len(cs.c) else (0.0, 1.0)
    lo_c, hi_c = min(lo_c, float(fit(v).min())), max(hi_c, float(fit(v).max()))
    if paper:
        vp = np.linspace(*PAPER_C_VALIDITY_MPS, 300)
        cp = np.polyval(PAPER_C_COEFFICIENTS, vp)
        ax.plot(vp * 1e3, cp, color="k", ls="--", lw=1.2, label="paper's c(v) (eq. 12)")
        lo_c, hi_c = min(lo_c, float(cp.min())), max(hi_c, float(cp.max()))
    pad = 0.1 * (hi_c - lo_c) + 1e-3
    ax.set_ylim(lo_c - pad, hi_c + pad)
    ax.set_xlabel("speed v (mm/s)")
    ax.set_ylabel("c")
    ax.set_title("Learned friction relation c(v)  (cf. paper Fig. 7b)")
    ax.legend(fontsize=8, loc="best")
    ax.grid(alpha=0.3)
    return fig


def plot_residuals(result: LearningResult, ax: Axes | None = None) -> Figure:
    """Residuals c_sample - c_fit against v (paper Fig. 7c), with SSE and RMSE."""
    fig, ax = _axes(ax)
    cs, fit = result.c_samples, result.fit
    idx = _subset(len(cs.c))
    ax.scatter(
        cs.speed_mps[idx] * 1e3, fit.residuals[idx], s=2, alpha=0.3, color="tab:purple", rasterized=True
    )
    ax.axhline(0.0, color="k", lw=1)
    ax.set_xlabel("speed v (mm/s)")
    ax.set_ylabel("residual of c")
    ax.set_title(
        f"Residuals (cf. paper Fig. 7c): SSE = {fit.sse:.4g}, RMSE = {fit.rmse:.3g}, n = {fit.n_samples}"
    )
    ax.grid(alpha=0.3)
    return fig


#: The figures of a fit: file name part and the function drawing it.
_FIGURES = (("c_fit", plot_c_fit), ("residuals", plot_residuals))


def figure_paths(out_dir: str | Path, prefix: str = "friction") -> list[Path]:
    """The files :func:`save_figures` writes: ``<prefix>_c_fit.png`` and ``<prefix>_residuals.png``."""
    return [Path(out_dir) / f"{prefix}_{name}.png" for name, _ in _FIGURES]


def save_figures(
    result: LearningResult, out_dir: str | Path, prefix: str = "friction", stack: ExitStack | None = None
) -> list[Path]:
    """Write ``<prefix>_c_fit.png`` (Fig. 7b) and ``<prefix>_residuals.png`` (Fig. 7c); returns the paths.

    Each file is written to a temporary name beside it and renamed into place
    (:func:`~capsule_mpc.atomic.atomic_path`). With ``stack`` the renames wait until the caller
    closes it, so several outputs appear together or not at all; without, they happen here.
    """
    import matplotlib.pyplot as plt  # lazy: Matplotlib only when a figure is drawn

    paths = figure_paths(out_dir, prefix)
    with ExitStack() as own:
        commit = own if stack is None else stack
        for path, (_, make) in zip(paths, _FIGURES):
            fig = make(result)
            try:
                fig.savefig(commit.enter_context(atomic_path(path)), dpi=120, format="png")
            finally:
                plt.close(fig)
    return paths
