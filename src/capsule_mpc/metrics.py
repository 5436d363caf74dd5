"""Tracking metrics of a run log: cross-track error, the paper's STD metric, completion, solver stats.

Definitions (all over the *motion phase*: frames with ``0 <= t <= t_end``, where
``t_end`` is the completion time if the capsule completed the path, else the
last frame at which the EPM or the capsule was still moving):

* cross-track error: distance from the true capsule position to the reference
  polyline; reported as RMS and max, mm.
* the paper's metric (paper §IV-D, Fig. 8): the standard deviation (population,
  ddof = 0) of the horizontal EPM-IPM distance ``|P_E - P_I|`` over the motion.
  With the Halbach array the capsule rests off-centre, so ``|P_E - P_I|``
  contains a constant offset; like the paper we take the STD of the distance as
  it is.
* completion time vs the nominal time ``length / v``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .paths import ReferencePath

__all__ = [
    "MOVING_SPEED_MPS",
    "cross_track_errors",
    "motion_end_s",
    "motion_mask",
    "paper_std_m",
    "prediction_errors",
    "run_metrics",
    "solver_metrics",
    "stack_predictions",
]

#: Below this speed (m/s) the EPM counts as at rest when finding the end of the motion phase.
MOVING_SPEED_MPS = 1e-5


def cross_track_errors(capsule_xy_m: np.ndarray, path: ReferencePath) -> np.ndarray:
    """Distance (N,) from each capsule position (N, 2) to the path, m."""
    return path.distance_to(np.asarray(capsule_xy_m, dtype=float))


def paper_std_m(epm_xy_m: np.ndarray, capsule_xy_m: np.ndarray) -> float:
    """The paper's metric: std (ddof = 0) of the horizontal distance |P_E - P_I|, m; NaN if empty."""
    d = np.asarray(epm_xy_m, dtype=float) - np.asarray(capsule_xy_m, dtype=float)
    if len(d) == 0:
        return math.nan
    return float(np.std(np.hypot(d[:, 0], d[:, 1])))


def motion_end_s(log: Mapping[str, np.ndarray], completion_time_s: float = math.nan) -> float:
    """End of the motion phase, s: the completion time, else the last frame with motion.

    "Motion" is an EPM speed above :data:`MOVING_SPEED_MPS` or a capsule that is not stuck.
    """
    t = np.asarray(log["t_s"], dtype=float)
    if math.isfinite(completion_time_s):
        return float(completion_time_s)
    moving = np.asarray(log["stuck"]) == 0
    if all(c in log for c in ("epm_vx_mps", "epm_vy_mps", "epm_vz_mps")):
        v = np.vstack([log["epm_vx_mps"], log["epm_vy_mps"], log["epm_vz_mps"]])
        moving |= np.linalg.norm(v, axis=0) > MOVING_SPEED_MPS
    moving &= t >= 0
    return float(t[moving][-1]) if np.any(moving) else 0.0


def motion_mask(log: Mapping[str, np.ndarray], end_s: float) -> np.ndarray:
    """Boolean mask of the frames with ``0 <= t <= end_s``."""
    t = np.asarray(log["t_s"], dtype=float)
    return np.asarray((t >= 0) & (t <= end_s + 1e-9))


def solver_metrics(log: Mapping[str, np.ndarray], deadline_ms: float) -> dict[str, float | int]:
    """Solve-time statistics from the ``solve_ms`` / ``solver_failed`` columns.

    Returns ``solve_ms_median``, ``solve_ms_p99`` (NaN when the controller reports no solve
    times), ``solve_ms_max``, ``solver_failures`` (count), ``deadline_misses`` (solves longer
    than ``deadline_ms``, e.g. the camera period; every frame counts, the settle phase too)
    and ``step_ms_max`` (the longest controller step, from the ``controller_ms`` column; NaN
    without it).
    """
    solve = np.asarray(log["solve_ms"], dtype=float)
    timed = solve[np.isfinite(solve)]
    step = np.asarray(log.get("controller_ms", []), dtype=float)
    step = step[np.isfinite(step)]
    return {
        "solve_ms_median": float(np.median(timed)) if timed.size else math.nan,
        "solve_ms_p99": float(np.percentile(timed, 99)) if timed.size else math.nan,
        "solve_ms_max": float(np.max(timed)) if timed.size else math.nan,
        "solver_failures": int(np.sum(np.asarray(log["solver_failed"]) != 0)),
        "deadline_misses": int(np.sum(timed > deadline_ms)),
        "step_ms_max": float(np.max(step)) if step.size else math.nan,
    }


def stack_predictions(predictions: Sequence[np.ndarray | None]) -> np.ndarray | None:
    """Per-frame predictions as one array (F, N, 2), NaN-filled where None; None if there are none.

    Predictions of different lengths are NaN-padded to the longest.
    """
    present = [np.asarray(p, dtype=float) for p in predictions if p is not None]
    if not present:
        return None
    n = max(p.shape[0] for p in present)
    out = np.full((len(predictions), n, 2), math.nan)
    for i, pred in enumerate(predictions):
        if pred is not None:
            arr = np.asarray(pred, dtype=float).reshape(-1, 2)
            out[i, : arr.shape[0]] = arr
    return out


def prediction_errors(
    log: Mapping[str, np.ndarray],
    predictions: np.ndarray,
    dt_s: float,
    frames: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far a controller's predicted capsule paths were from where the capsule really went.

    The prediction made at frame time ``t`` is taken to hold the capsule positions at
    ``t + dt_s * (1..N)`` (the MPC's stages); each is compared with the true capsule position
    at that time (linear interpolation in the log). Stages beyond the end of the log and
    frames without a prediction (NaN) are left out.

    Parameters
    ----------
    log : mapping of str to numpy.ndarray
        A run log (``t_s``, ``capsule_x_m``, ``capsule_y_m``).
    predictions : numpy.ndarray (F, N, 2)
        Per-frame predicted capsule positions, m (NaN where none).
    dt_s : float
        Time between prediction stages, s, > 0.
    frames : numpy.ndarray of bool (F,), optional
        Which frames to score (default: every frame with a prediction).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray, numpy.ndarray)
        Look-ahead times (N,), s; RMS (N,) and max (N,) prediction error at each, m (NaN where
        nothing was scored).
    """
    if not dt_s > 0:
        raise ValueError(f"dt_s: must be > 0, got {dt_s}")
    pred = np.asarray(predictions, dtype=float)
    t = np.asarray(log["t_s"], dtype=float)
    if pred.ndim != 3 or pred.shape[0] != len(t) or pred.shape[2] != 2:
        raise ValueError(f"predictions: must have shape ({len(t)}, N, 2), got {pred.shape}")
    n = pred.shape[1]
    lookahead = dt_s * np.arange(1, n + 1)
    use = np.all(np.isfinite(pred), axis=(1, 2)) if frames is None else np.asarray(frames, dtype=bool)
    when = t[use, None] + lookahead[None, :]  # (F', N)
    inside = when <= t[-1] + 1e-9
    actual = np.stack(
        [np.interp(when, t, log["capsule_x_m"]), np.interp(when, t, log["capsule_y_m"])], axis=-1
    )
    err = np.hypot(*np.moveaxis(pred[use] - actual, -1, 0))
    scored = inside & np.isfinite(err)
    counts = np.sum(scored, axis=0)
    sq = np.where(scored, err, 0.0) ** 2
    rms = np.sqrt(np.sum(sq, axis=0) / np.maximum(counts, 1))
    worst = np.max(np.where(scored, err, 0.0), axis=0, initial=0.0)
    return lookahead, np.where(counts > 0, rms, np.nan), np.where(counts > 0, worst, np.nan)


def run_metrics(
    log: Mapping[str, np.ndarray],
    path: ReferencePath,
    *,
    completion_time_s: float = math.nan,
    deadline_ms: float = math.inf,
) -> dict[str, Any]:
    """Every metric of one run.

    Parameters
    ----------
    log : mapping of str to numpy.ndarray
        A run log (see :mod:`capsule_mpc.sim.log`).
    path : ReferencePath
        The reference the capsule had to follow (the nominal one, at the nominal speed).
    completion_time_s : float
        When the capsule completed the path, s (NaN if it did not).
    deadline_ms : float
        Solve-time budget for ``deadline_misses``, ms.

    Returns
    -------
    dict
        ``cross_track_rms_mm``, ``cross_track_max_mm``, ``paper_std_mm``, ``lead_mean_mm``
        (mean |P_E - P_I|), ``completion_time_s``, ``nominal_time_s``, ``completion_ratio``
        (completion / nominal), ``final_error_mm`` (last capsule position to the path end),
        ``motion_end_s``, ``normal_force_min_n`` / ``normal_force_max_n`` over the motion, and
        the :func:`solver_metrics`.
    """
    end = motion_end_s(log, completion_time_s)
    mask = motion_mask(log, end)
    capsule = np.column_stack([log["capsule_x_m"], log["capsule_y_m"]])
    epm = np.column_stack([log["epm_x_m"], log["epm_y_m"]])
    moving_capsule = capsule[mask]
    if moving_capsule.size:
        err = cross_track_errors(moving_capsule, path)
        rms, worst = float(np.sqrt(np.mean(err**2))), float(np.max(err))
        lead = epm[mask] - moving_capsule
        lead_mean = float(np.mean(np.hypot(lead[:, 0], lead[:, 1])))
        f_n = np.asarray(log["normal_force_n"], dtype=float)[mask]
        fn_min, fn_max = float(np.nanmin(f_n)), float(np.nanmax(f_n))
    else:
        rms = worst = lead_mean = fn_min = fn_max = math.nan
    final = float(np.hypot(*(capsule[-1] - path.end_m))) if len(capsule) else math.nan
    out: dict[str, Any] = {
        "cross_track_rms_mm": rms * 1e3,
        "cross_track_max_mm": worst * 1e3,
        "paper_std_mm": paper_std_m(epm[mask], moving_capsule) * 1e3,
        "lead_mean_mm": lead_mean * 1e3,
        "completion_time_s": float(completion_time_s),
        "nominal_time_s": path.duration_s,
        "completion_ratio": float(completion_time_s) / path.duration_s,
        "final_error_mm": final * 1e3,
        "motion_end_s": end,
        "normal_force_min_n": fn_min,
        "normal_force_max_n": fn_max,
    }
    out.update(solver_metrics(log, deadline_ms))
    return out
