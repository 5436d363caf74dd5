"""Tracking metrics of a run log, scored on a common time window; solver statistics.

The scoring window
------------------
Every window metric is taken over the frames with ``0 <= t <= window_end_s`` (t = 0 is when
the reference starts moving; the settle phase before it is not scored), and the window never
extends past the path's nominal end: the path is scored over its own time, the same for every
controller, and what happens after it (placing the capsule at rest) by :func:`end_metrics`. A
run that ended earlier (decoupled, dropped) is scored on the window a comparison gives it: a
log that ends before ``window_end_s`` is padded: its last row is held (the capsule and the EPM
stay at rest where they ended) at the log's frame spacing up to ``window_end_s``; only the
reference keeps being evaluated along the path (it holds the path's end after the nominal time, exactly as the
runner logs it). A run that stopped early far from the goal thus keeps paying for it until the
window closes. The solver statistics count the logged frames only (padding solves nothing).
Without a window end, :func:`run_metrics` falls back to :func:`motion_end_s`.

Definitions
-----------
* cross-track error: distance from the true capsule position to the reference polyline;
  RMS and max over the window, mm.
* tracking error: ``|p(t) - ref(t)|`` with the time-parameterised reference logged in
  ``ref_x_m`` / ``ref_y_m``; RMS and max over the window, mm. As ``ref(t)`` lies on the
  path, the cross-track error never exceeds the tracking error. Its RMS over the start window
  ``0 <= t <= START_WINDOW_S`` (the capsule breaking loose from rest) is reported apart.
* the paper's metric (paper §IV-D, Fig. 8): the standard deviation (population,
  ddof = 0) of the horizontal EPM-IPM distance ``|P_E - P_I|`` over the window.
  With the Halbach array the capsule rests off-centre, so ``|P_E - P_I|``
  contains a constant offset; like the paper we take the STD of the distance as
  it is.
* arrival: the first frame (t >= 0) at which the capsule's arc-length progress has reached
  ``length - tol`` and it is within ``tol`` of the path's end; compared with the nominal time
  ``length / v``.
* EPM jerk: the second time derivative of the logged EPM velocity (``numpy.gradient`` on the
  frame times, which need not be uniform), RMS over the window, m/s^3; and the EPM's
  horizontal path length over the capsule's, a measure of wasted arm motion.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .paths import ReferencePath

__all__ = [
    "ARRIVAL_TOL_M",
    "EPM_VELOCITY_COLUMNS",
    "MIN_TRAVEL_M",
    "MOVING_SPEED_MPS",
    "PLACED_STILL_M",
    "START_WINDOW_S",
    "arrival_time_s",
    "cross_track_errors",
    "end_metrics",
    "epm_jerk_mps3",
    "hold_log_until",
    "motion_end_s",
    "motion_mask",
    "paper_std_m",
    "path_length_m",
    "prediction_errors",
    "run_metrics",
    "solver_metrics",
    "stack_predictions",
    "start_metrics",
    "tracking_errors",
]

#: The start window, s: from the reference's start over the breakaway of a capsule at rest.
START_WINDOW_S = 1.5
#: Below this speed (m/s) the EPM counts as at rest when finding the end of the motion phase.
MOVING_SPEED_MPS = 1e-5
#: Default arrival tolerance, m (the default of ``sim.completion_tol_m`` in the config).
ARRIVAL_TOL_M = 0.002
#: A capsule that travelled less than this over the window did not move (``epm_path_ratio`` is
#: then NaN), m: far below the camera noise (0.3 mm), far above float round-off.
MIN_TRAVEL_M = 1e-9
#: The logged EPM velocity columns, m/s.
EPM_VELOCITY_COLUMNS: tuple[str, str, str] = ("epm_vx_mps", "epm_vy_mps", "epm_vz_mps")
#: Slack on frame times when comparing them with a window end, s (float round-off of ``k * dt``).
_TIME_EPS_S = 1e-9
#: Columns not held when a log is padded: the solver's, as no solve happens after the end.
_SOLVER_COLUMNS: frozenset[str] = frozenset({"solve_ms", "controller_ms", "solver_failed", "solver_status"})


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


def tracking_errors(log: Mapping[str, np.ndarray]) -> np.ndarray:
    """Distance (N,) from the true capsule position to the logged reference ``ref_{x,y}_m``, m."""
    return np.asarray(
        np.hypot(
            np.asarray(log["capsule_x_m"], dtype=float) - np.asarray(log["ref_x_m"], dtype=float),
            np.asarray(log["capsule_y_m"], dtype=float) - np.asarray(log["ref_y_m"], dtype=float),
        )
    )


def path_length_m(xy_m: np.ndarray) -> float:
    """Length of the polyline through the points (N, 2), m (0 for fewer than two points)."""
    xy = np.asarray(xy_m, dtype=float).reshape(-1, 2)
    if len(xy) < 2:
        return 0.0
    step = np.diff(xy, axis=0)
    return float(np.sum(np.hypot(step[:, 0], step[:, 1])))


def hold_log_until(
    log: Mapping[str, np.ndarray], end_s: float, path: ReferencePath | None = None
) -> dict[str, np.ndarray]:
    """The log padded up to ``end_s`` by holding its last row (the capsule and EPM at rest).

    Padded frames follow the last one at the log's frame spacing (the median step of ``t_s``;
    with a single frame, one padded frame at ``end_s``) while they are ``<= end_s``. Every
    column holds its last value, except: the reference ``ref_{x,y}_m`` is ``path.position(t)``
    when ``path`` is given (as the runner logs it), and the solver columns (``solve_ms``,
    ``controller_ms``: NaN; ``solver_failed``: 0; ``solver_status``: empty) as nothing is
    solved after the end.

    Parameters
    ----------
    log : mapping of str to numpy.ndarray
        A run log with at least one frame.
    end_s : float
        Time to pad up to, s; a log that already reaches it is returned unchanged (copied).
    path : ReferencePath, optional
        The reference, to continue ``ref_{x,y}_m``.

    Returns
    -------
    dict of str to numpy.ndarray
        The padded log (new arrays).
    """
    t = np.asarray(log["t_s"], dtype=float)
    out = {k: np.asarray(v).copy() for k, v in log.items()}
    if len(t) == 0 or not end_s > t[-1] + _TIME_EPS_S:
        return out
    step = np.diff(t)
    dt = float(np.median(step)) if len(step) else math.nan
    if not dt > 0:  # a single frame (or no spacing to copy): one padded frame at the end
        dt = end_s - float(t[-1])
    count = math.floor((end_s - t[-1] + _TIME_EPS_S) / dt)
    if count < 1:
        return out
    t_pad = t[-1] + dt * np.arange(1, count + 1)
    for name, col in out.items():
        if name == "t_s":
            pad = t_pad
        elif name in ("solve_ms", "controller_ms"):
            pad = np.full(count, math.nan)
        elif name in _SOLVER_COLUMNS:
            pad = np.full(count, "" if col.dtype.kind in "US" else 0, dtype=col.dtype)
        else:
            pad = np.repeat(col[-1:], count)
        out[name] = np.concatenate([col, pad])
    if path is not None and "ref_x_m" in out and "ref_y_m" in out:
        ref = path.position(t_pad)
        for j, name in enumerate(("ref_x_m", "ref_y_m")):
            out[name] = np.concatenate([np.asarray(log[name], dtype=float), ref[:, j]])
    return out


def arrival_time_s(log: Mapping[str, np.ndarray], path: ReferencePath, tol_m: float = ARRIVAL_TOL_M) -> float:
    """First frame time (t >= 0) at which the capsule has arrived at the path's end, s; NaN if never.

    Arrived: arc-length progress ``progress_m >= path.length_m - tol_m`` and distance to
    ``path.end_m`` ``<= tol_m`` (both are needed: a closed path ends where it starts). NaN
    without a ``progress_m`` column.
    """
    if "progress_m" not in log:
        return math.nan
    t = np.asarray(log["t_s"], dtype=float)
    gap = np.hypot(
        np.asarray(log["capsule_x_m"], dtype=float) - path.end_m[0],
        np.asarray(log["capsule_y_m"], dtype=float) - path.end_m[1],
    )
    arrived = (
        (t >= 0) & (np.asarray(log["progress_m"], dtype=float) >= path.length_m - tol_m) & (gap <= tol_m)
    )
    return float(t[np.argmax(arrived)]) if np.any(arrived) else math.nan


def epm_jerk_mps3(log: Mapping[str, np.ndarray]) -> np.ndarray:
    """The EPM's jerk (N, 3) at each frame, m/s^3: the second time derivative of its logged velocity.

    Taken with :func:`numpy.gradient` on the frame times ``t_s`` (second-order accurate, also on
    non-uniform times; exact for a quadratic velocity). NaN-filled with fewer than three frames
    or without the :data:`EPM_VELOCITY_COLUMNS`.
    """
    t = np.asarray(log["t_s"], dtype=float)
    if len(t) < 3 or not all(c in log for c in EPM_VELOCITY_COLUMNS):
        return np.full((len(t), 3), math.nan)
    v = np.column_stack([np.asarray(log[c], dtype=float) for c in EPM_VELOCITY_COLUMNS])
    acc = np.gradient(v, t, axis=0, edge_order=2)
    return np.asarray(np.gradient(acc, t, axis=0, edge_order=2))


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
    first_s: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far a controller's predicted capsule paths were from where the capsule really went.

    The prediction made at frame time ``t`` is taken to hold the capsule positions at
    ``t + first_s + dt_s * (0..N-1)`` (the MPC's stages); each is compared with the true capsule position
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
    first_s : float, optional
        Look-ahead of the first stage, s, > 0 (default ``dt_s``; the MPC's first stage is one
        frame, its others ``mpc.dt_s``).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray, numpy.ndarray)
        Look-ahead times (N,), s; RMS (N,) and max (N,) prediction error at each, m (NaN where
        nothing was scored).
    """
    first_s = dt_s if first_s is None else first_s
    for name, value in (("dt_s", dt_s), ("first_s", first_s)):
        if not value > 0:
            raise ValueError(f"{name}: must be > 0, got {value}")
    pred = np.asarray(predictions, dtype=float)
    t = np.asarray(log["t_s"], dtype=float)
    if pred.ndim != 3 or pred.shape[0] != len(t) or pred.shape[2] != 2:
        raise ValueError(f"predictions: must have shape ({len(t)}, N, 2), got {pred.shape}")
    n = pred.shape[1]
    lookahead = first_s + dt_s * np.arange(n)
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


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else math.nan


def _max(values: np.ndarray) -> float:
    return float(np.max(values)) if values.size else math.nan


def run_metrics(
    log: Mapping[str, np.ndarray],
    path: ReferencePath,
    *,
    window_end_s: float | None = None,
    arrival_tol_m: float = ARRIVAL_TOL_M,
    deadline_ms: float = math.inf,
    completion_time_s: float = math.nan,
) -> dict[str, Any]:
    """Every metric of one run, over the scoring window ``0 <= t <= window_end_s``.

    Parameters
    ----------
    log : mapping of str to numpy.ndarray
        A run log (see :mod:`capsule_mpc.sim.log`).
    path : ReferencePath
        The reference the capsule had to follow (the nominal one, at the nominal speed).
    window_end_s : float, optional
        End of the scoring window, s. A log that ends earlier is padded by holding its last
        row (:func:`hold_log_until`), so runs that came to rest at different times are scored
        on the same window. Default: :func:`motion_end_s` of the log (with
        ``completion_time_s``).
    arrival_tol_m : float
        Distance to the path's end (and shortfall of progress) that counts as arrived, m.
    deadline_ms : float
        Solve-time budget for ``deadline_misses``, ms.
    completion_time_s : float
        Deprecated: only used for the default window end when ``window_end_s`` is None (the
        run's completion time, s; NaN if it did not complete). Not reported any more: see
        ``arrival_time_s``.

    Returns
    -------
    dict
        Over the window: ``cross_track_rms_mm`` / ``cross_track_max_mm`` (to the polyline),
        ``tracking_rms_mm`` / ``tracking_max_mm`` (to the time-parameterised reference),
        ``start_tracking_rms_mm`` (its RMS over the first :data:`START_WINDOW_S` of the window),
        ``paper_std_mm``, ``lead_mean_mm`` (mean |P_E - P_I|), ``epm_jerk_rms_mps3``,
        ``epm_path_ratio`` (EPM / capsule horizontal path length; NaN if the capsule did not
        move), ``normal_force_min_n`` / ``normal_force_max_n`` (N). Besides: ``final_error_mm``
        (last logged capsule position to the path end), ``arrival_time_s`` (over the whole
        log, NaN if it never arrived; :func:`arrival_time_s`), ``nominal_time_s``,
        ``arrival_ratio`` (arrival / nominal), ``window_end_s`` and ``motion_end_s`` (both the
        window end used, s), and the :func:`solver_metrics` of the logged frames.
    """
    motion_end = motion_end_s(log, completion_time_s) if window_end_s is None else float(window_end_s)
    # The path's metrics cover the path: the same window, its nominal time, for every controller
    # (the end is scored at rest by end_metrics).
    end = min(motion_end, path.duration_s)
    scored = hold_log_until(log, end, path)
    mask = motion_mask(scored, end)
    capsule = np.column_stack([scored["capsule_x_m"], scored["capsule_y_m"]])[mask]
    epm = np.column_stack([scored["epm_x_m"], scored["epm_y_m"]])[mask]
    cross = cross_track_errors(capsule, path) if len(capsule) else np.zeros(0)
    track = tracking_errors(scored)[mask]
    start = track[np.asarray(scored["t_s"], dtype=float)[mask] <= START_WINDOW_S + _TIME_EPS_S]
    lead = np.hypot(*(epm - capsule).T) if len(capsule) else np.zeros(0)
    f_n = np.asarray(scored["normal_force_n"], dtype=float)[mask]
    jerk = np.linalg.norm(epm_jerk_mps3(scored)[mask], axis=1)
    travel = path_length_m(capsule)
    logged = np.column_stack([log["capsule_x_m"], log["capsule_y_m"]]).astype(float)
    final = float(np.hypot(*(logged[-1] - path.end_m))) if len(logged) else math.nan
    arrival = arrival_time_s(log, path, arrival_tol_m)
    out: dict[str, Any] = {
        "cross_track_rms_mm": _rms(cross) * 1e3,
        "cross_track_max_mm": _max(cross) * 1e3,
        "tracking_rms_mm": _rms(track) * 1e3,
        "tracking_max_mm": _max(track) * 1e3,
        "start_tracking_rms_mm": _rms(start) * 1e3,
        "paper_std_mm": paper_std_m(epm, capsule) * 1e3,
        "lead_mean_mm": float(np.mean(lead)) * 1e3 if lead.size else math.nan,
        "final_error_mm": final * 1e3,
        "arrival_time_s": arrival,
        "nominal_time_s": path.duration_s,
        "arrival_ratio": arrival / path.duration_s,
        "window_end_s": end,
        "motion_end_s": motion_end,
        "epm_jerk_rms_mps3": _rms(jerk),
        "epm_path_ratio": path_length_m(epm) / travel if travel > MIN_TRAVEL_M else math.nan,
        "normal_force_min_n": float(np.nanmin(f_n)) if np.any(np.isfinite(f_n)) else math.nan,
        "normal_force_max_n": float(np.nanmax(f_n)) if np.any(np.isfinite(f_n)) else math.nan,
    }
    out.update(solver_metrics(log, deadline_ms))
    return out


#: A capsule counts as placed from the time it stays this close to where it ends, m (a few camera
#: noise floors below the placement tolerance).
PLACED_STILL_M = 2e-5


def end_metrics(
    log: Mapping[str, np.ndarray],
    path: ReferencePath,
    camera_bias_m: np.ndarray,
    placement_moves: int,
    at_rest: bool,
) -> dict[str, Any]:
    """How the run ended, from the plant's truth: the metrics of the placement at the path's end.

    Parameters
    ----------
    log : mapping of str to numpy.ndarray
        A run log (true positions; the ``phase`` column when the controller has phases).
    path : ReferencePath
        The reference; its end is the target.
    camera_bias_m : numpy.ndarray (2,)
        The draw's camera registration bias, m: what the camera adds to every position on average.
    placement_moves : int
        The controller's placement moves.
    at_rest : bool
        Whether the run ended at rest (else the time to place is NaN).

    Returns
    -------
    dict
        ``final_error_seen_mm``: the last true position plus the camera's bias (what the camera
        sees on average, noise-free) to the path's end; ``camera_bias_mm`` (|bias|, a floor no
        controller can see); ``time_to_place_s``: from the path's nominal end to the time from
        which the capsule stayed within :data:`PLACED_STILL_M` of where it ended (0 if it was
        there by the nominal end; NaN if the run did not end at rest); ``placement_moves``;
        ``end_phase``: the controller's phase at the last frame ('' without phases).
    """
    t = np.asarray(log["t_s"], dtype=float)
    pos = np.column_stack([log["capsule_x_m"], log["capsule_y_m"]]).astype(float)
    bias = np.asarray(camera_bias_m, dtype=float)
    if not len(t):
        return {"final_error_seen_mm": math.nan, "camera_bias_mm": float(np.linalg.norm(bias)) * 1e3,
                "time_to_place_s": math.nan, "placement_moves": placement_moves, "end_phase": ""}  # fmt: skip
    final = pos[-1]
    away = np.linalg.norm(pos - final, axis=1) > PLACED_STILL_M
    last_away = float(t[away][-1]) if np.any(away) else -math.inf
    placed_s = max(last_away - path.duration_s, 0.0) if at_rest else math.nan
    phases = log.get("phase")
    return {
        "final_error_seen_mm": float(np.linalg.norm(final + bias - path.end_m)) * 1e3,
        "camera_bias_mm": float(np.linalg.norm(bias)) * 1e3,
        "time_to_place_s": placed_s,
        "placement_moves": int(placement_moves),
        "end_phase": "" if phases is None or not len(phases) else str(phases[-1]),
    }


def start_metrics(first_motion_s: float, bound_s: float) -> dict[str, Any]:
    """When the capsule first slid after t = 0, against the draw's arm-limited bound
    (:func:`capsule_mpc.sim.start_bound.breakaway_bound_s`).

    Parameters
    ----------
    first_motion_s : float
        The end of the first plant step at t >= 0 after which the capsule was not held by static
        friction, s (the simulator records it at the plant's rate: the camera's frames would round
        it up by up to a frame); NaN if it never moved.
    bound_s : float
        The draw's arm-limited bound, s.

    Returns
    -------
    dict
        ``first_motion_s``, ``first_motion_bound_s`` and ``first_motion_ratio`` (first motion /
        bound; NaN without a finite, positive bound).
    """
    first = float(first_motion_s)
    ratio = first / bound_s if math.isfinite(bound_s) and bound_s > 0 else math.nan
    return {"first_motion_s": first, "first_motion_bound_s": bound_s, "first_motion_ratio": ratio}
