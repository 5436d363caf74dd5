"""Static friction from breakaway experiments: the breakaway coefficient after a rest, and its healing.

A breakaway experiment (:mod:`capsule_mpc.learning.demonstrations`): the capsule comes to
rest, the EPM is held still, then pulled slowly until the capsule slides. What a real rig
logs is enough to measure the static friction it overcame:

1. **The breakaway instant** (:func:`detect_breakaway`), from the camera positions alone: the
   capsule's resting position is the median of the frames before it moved, the camera noise
   the scaled median absolute deviation of those frames about it; the capsule has moved at
   the first of ``hold_frames`` consecutive frames farther than ``max(min_move_m,
   noise_factor x noise)`` from its rest, traced back through the frames just before it
   that are already beyond ``max(min_move_m / 2, 4 x noise)`` (a slip that starts small).
   It broke away between the last frame at rest and the first moved one (their capture
   times' midpoint).
2. **The force it overcame**: the lateral magnetic force ``F_xy`` and the normal force
   ``F_N`` from the controller's force model (``scenario.force_model``, or the one given)
   at the lead ``EPM - rest position`` at that instant; the breakaway coefficient is
   ``mu_s = (|F_xy| - f_s) / F_N`` with the tether drag ``f_s`` of the scenario (the rig's
   at rest; the capsule has not moved since it came to rest).

   The lead is *tared* (default): the capsule settled under the still magnet where its lateral
   force vanishes, so the lead it rests at is taken as the force model's zero-force
   (equilibrium) lead, and the pull's lead is measured from there. As one zeroes a force
   sensor, this removes what the camera's bias and the magnet's mounting errors add to the
   measured lead; where the force rises steeply with the lead (along the Halbach array's x)
   a few tenths of a millimetre are several per cent of the breakaway force. Without the tare
   (for a capsule that was not settled at the equilibrium) the measured lead is used.
3. **The rest time** ``T``: from the capsule coming to rest (the run's provenance,
   ``rest_since_t_s``; default the log's first frame) to the breakaway. The capsule heals
   while the EPM loads it, so T is the rest before the pull plus the loading time.

The healing law fitted to the (T, mu_s) pairs (:func:`fit_healing`) is the log-linear one of
slide-hold-slide tests (Dieterich 1972; Marone 1998)::

    mu_s(T) = static_mu_1s + static_healing * ln(T / 1 s)

by least squares in ln T, with 95 % confidence intervals from the residual covariance
s^2 (X^T X)^-1, s^2 = SSR / (n - 2), and Student's t with n - 2 degrees of freedom.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import casadi as ca
import numpy as np
from scipy import stats

from ..config import Scenario
from ..dynamics import normal_force_expr
from ..magnetics import capsule_force_function, equilibrium_lead
from .data import LearningDataError
from .logs import RunLog, read_run_log

__all__ = [
    "BREAKAWAY_EXPERIMENT",
    "DEMO_FILE",
    "BreakawayEvent",
    "HealingFit",
    "StaticFrictionResult",
    "breakaway_event",
    "detect_breakaway",
    "fit_healing",
    "is_breakaway_log",
    "learn_static_friction",
    "run_provenance",
]

#: Name of a demonstration's provenance file beside its ``log.csv``.
DEMO_FILE = "demonstration.json"
#: The ``experiment`` of a breakaway run in its provenance.
BREAKAWAY_EXPERIMENT = "breakaway"
#: Consistency factor of the median absolute deviation for Gaussian noise.
_MAD_TO_STD = 1.4826
#: Fewest frames at rest before the breakaway that the rest position is estimated from.
_MIN_REST_FRAMES = 5
#: Frames before the detected motion farther than this many noise standard deviations from the rest
#: belong to the motion (the detector traces the motion back to its start through them).
_BACKTRACK_FACTOR = 4.0
#: Confidence level of the intervals.
CONFIDENCE = 0.95
#: A motion whose fitted start is more than this many frames before the threshold's crossing is a
#: creep, dated by the fit (:func:`_hinge_onset`); a slip keeps the threshold's date.
_CREEP_FRAMES = 5
#: Log time the pull starts in a breakaway run, s (the rest before it has negative times).
PULL_START_T_S = 0.0
#: A tare larger than this, m, is noted: more than camera bias and mounting errors give, so the
#: capsule may not have settled at the zero-force lead.
TARE_NOTE_M = 2e-3


def run_provenance(log_path: str | Path) -> dict[str, Any] | None:
    """The ``run`` record of a demonstration's ``demonstration.json`` beside ``log_path``, or None.

    None when there is no such file or it cannot be read as JSON with a ``run`` mapping.
    """
    meta = Path(log_path).parent / DEMO_FILE
    try:
        data = json.loads(meta.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None
    run = data.get("run") if isinstance(data, dict) else None
    return run if isinstance(run, dict) else None


def is_breakaway_log(log_path: str | Path) -> bool:
    """Whether a run log's provenance says it is a breakaway experiment."""
    run = run_provenance(log_path)
    return run is not None and run.get("experiment") == BREAKAWAY_EXPERIMENT


@dataclass(frozen=True)
class BreakawayEvent:
    """One measured breakaway.

    Attributes
    ----------
    path : Path
        The run log.
    rest_s : float
        Time the capsule had rested when it broke away, s (> 0).
    t_break_s : float
        Breakaway instant, s (log time).
    rest_position_m : numpy.ndarray (2,)
        The capsule's resting position (camera median), m.
    lead_m : numpy.ndarray (2,)
        EPM - capsule at the breakaway, m.
    height_m : float
        EPM-IPM centre height at the breakaway, m.
    force_n : numpy.ndarray (3,)
        ``(F_x, F_y, F_att)`` of the force model there, N.
    normal_n : float
        Normal force F_N, N.
    drag_n : float
        Tether drag subtracted, N.
    mu_s : float
        Breakaway coefficient (|F_xy| - f_s) / F_N, dimensionless.
    noise_m : float
        Camera noise estimated from the frames at rest (per axis), m.
    threshold_m : float
        Displacement from the rest position that counted as moved, m.
    tare_m : numpy.ndarray (2,)
        Measured rest lead less the force model's equilibrium lead, m, taken off ``lead_m``
        (zeros without the tare).
    """

    path: Path
    rest_s: float
    t_break_s: float
    rest_position_m: np.ndarray
    lead_m: np.ndarray
    height_m: float
    force_n: np.ndarray
    normal_n: float
    drag_n: float
    mu_s: float
    noise_m: float
    threshold_m: float
    tare_m: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict."""
        out: dict[str, Any] = {}
        for key, value in self.__dict__.items():
            out[key] = value.tolist() if isinstance(value, np.ndarray) else value
        out["path"] = str(self.path)
        return out


def _capture_times(log: RunLog) -> np.ndarray:
    """Capture time of every frame, s (the delivery time where the log has none)."""
    if log.capture_t_s is None:
        return log.t_s
    return np.where(np.isfinite(log.capture_t_s), log.capture_t_s, log.t_s)


def _rest_estimate(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Median position (2,) of resting frames and the per-axis noise (scaled MAD pooled over x, y), m."""
    rest = np.median(points, axis=0)
    noise = _MAD_TO_STD * float(np.median(np.abs(points - rest)))
    return rest, noise


def _first_moved(distance: np.ndarray, threshold: float, hold_frames: int) -> int | None:
    """Index (into ``distance``) of the first of ``hold_frames`` consecutive values above ``threshold``."""
    above = distance > threshold
    if hold_frames > 1:
        runs = np.convolve(above.astype(int), np.ones(hold_frames, dtype=int), mode="valid")
        starts = np.flatnonzero(runs == hold_frames)
    else:
        starts = np.flatnonzero(above)
    return int(starts[0]) if len(starts) else None


def detect_breakaway(
    log: RunLog,
    min_move_m: float = 1e-3,
    noise_factor: float = 6.0,
    hold_frames: int = 3,
    pull_start_t_s: float = PULL_START_T_S,
) -> tuple[float, np.ndarray, float, float] | None:
    """When the capsule of a breakaway run started to move, from its camera positions.

    Parameters
    ----------
    log : RunLog
        The run log (camera positions; NaN rows are dropped frames).
    min_move_m : float
        Smallest displacement from the rest position that counts as moved, m, > 0.
    noise_factor : float
        The displacement must also exceed this many camera-noise standard deviations, > 0.
    hold_frames : int
        Consecutive frames that must be displaced (an outlier is not a breakaway), >= 1.
    pull_start_t_s : float
        Log time the pull starts, s; the frames up to it seed the rest position.

    Returns
    -------
    (float, numpy.ndarray, float, float) or None
        The breakaway instant (s, log time), the rest position (2,) (m), the camera noise and
        the threshold used (m); None if the capsule never moved (or too few frames at rest).
    """
    if not (min_move_m > 0 and noise_factor > 0 and hold_frames >= 1):
        raise ValueError("min_move_m and noise_factor: must be > 0; hold_frames: must be >= 1")
    valid = np.all(np.isfinite(log.capsule_m), axis=1)
    t_cap = _capture_times(log)[valid]
    pos = log.capsule_m[valid]
    seed = t_cap <= pull_start_t_s
    if seed.sum() < _MIN_REST_FRAMES:
        seed = np.zeros(len(t_cap), dtype=bool)
        seed[:_MIN_REST_FRAMES] = True
    if len(pos) < _MIN_REST_FRAMES + hold_frames:
        return None
    rest, noise = _rest_estimate(pos[seed])
    for _ in range(2):  # the rest from the seed frames, then from every frame before the motion
        onset = _onset(np.hypot(*(pos - rest).T), noise, min_move_m, noise_factor, hold_frames)
        if onset is None or onset < _MIN_REST_FRAMES:
            return None
        rest, noise = _rest_estimate(pos[:onset])
    threshold = max(min_move_m, noise_factor * noise)
    onset = _onset(np.hypot(*(pos - rest).T), noise, min_move_m, noise_factor, hold_frames)
    if onset is None or onset < 1:
        return None
    onset = _hinge_onset(t_cap, pos, rest, onset, hold_frames, max(int(seed.sum()), 1))
    return 0.5 * float(t_cap[onset - 1] + t_cap[onset]), rest, noise, threshold


def _hinge_onset(
    t: np.ndarray, pos: np.ndarray, rest: np.ndarray, onset: int, hold_frames: int, first: int
) -> int:
    """The motion's start, refined for a capsule that creeps: the frame k from which the
    displacement along the motion is best fitted by a ramp b (t - t_k) (zero before it),
    least squares over k from ``first`` (the pull's start) to the threshold's onset; used when it is
    more than :data:`_CREEP_FRAMES` frames before the threshold's onset.

    A capsule that slips crosses the threshold within a frame or two of its start, and the
    threshold dates it well; one that creeps after breaking loose (weak stick-slip, a noisy camera)
    crosses it seconds later, and dating the breakaway there would overstate the force it overcame.
    Written by hand: a change-point search over one onset with a fixed model is a loop of small
    least-squares fits, not a library call.
    """
    end = min(onset + hold_frames, len(t))
    moved = pos[onset:end].mean(axis=0) - rest
    if not float(np.hypot(*moved)) > 0 or onset - first < 3:
        return onset
    along = (pos[:end] - rest) @ (moved / float(np.hypot(*moved)))
    best, best_k = math.inf, onset
    for k in range(max(first, 1), onset + 1):
        x = t[k:end] - t[k]
        slope = float(x @ along[k:end]) / max(float(x @ x), 1e-300)
        sse = float(along[:k] @ along[:k]) + float(np.sum((along[k:end] - slope * x) ** 2))
        if sse < best:
            best, best_k = sse, k
    return best_k if onset - best_k > _CREEP_FRAMES else onset


def _onset(
    distance: np.ndarray, noise: float, min_move_m: float, noise_factor: float, hold_frames: int
) -> int | None:
    """First frame of the motion: the first sustained excursion beyond the threshold, traced back
    through the frames before it that are already beyond :data:`_BACKTRACK_FACTOR` noise (and half
    ``min_move_m``), so a slip smaller than the threshold that grows into it is dated by its start."""
    k = _first_moved(distance, max(min_move_m, noise_factor * noise), hold_frames)
    if k is None:
        return None
    low = max(0.5 * min_move_m, _BACKTRACK_FACTOR * noise)
    while k > 0 and distance[k - 1] > low:
        k -= 1
    return k


def breakaway_event(
    log: RunLog,
    scenario: Scenario,
    force_fn: ca.Function | None = None,
    force_model: Literal["dipole", "lookup"] | None = None,
    rest_since_t_s: float | None = None,
    tare: bool = True,
    **detect: Any,
) -> BreakawayEvent | None:
    """The breakaway of one run log (see the module docstring), or None if the capsule never moved.

    Parameters
    ----------
    log : RunLog
        A breakaway run's log (camera positions).
    scenario : Scenario
        Force model, capsule mass and setup (F_N), tether drag.
    force_fn : casadi.Function, optional
        The force model ``F = f(lead, height)``, if already built.
    force_model : {'dipole', 'lookup'}, optional
        Default ``scenario.force_model``.
    rest_since_t_s : float, optional
        Log time the capsule came to rest, s; default: from the run's provenance, else the first
        frame.
    tare : bool
        Measure the lead from the force model's equilibrium lead at the rest (see the module
        docstring); the EPM at rest is the last log row before the pull (``pull_start_t_s`` of
        ``detect``, default 0), else the first.
    **detect
        Passed to :func:`detect_breakaway`.
    """
    found = detect_breakaway(log, **detect)
    if found is None:
        return None
    t_b, rest, noise, threshold = found
    if rest_since_t_s is None:
        run = run_provenance(log.path) or {}
        since = run.get("rest_since_t_s")
        rest_since_t_s = float(since) if isinstance(since, (int, float)) else float(log.t_s[0])
    rest_s = t_b - rest_since_t_s
    if not rest_s > 0:
        raise LearningDataError(
            f"{log.path}: the capsule broke away at t = {t_b:.3f} s, not after it came to rest "
            f"(rest_since_t_s = {rest_since_t_s:.3f} s)"
        )
    epm = np.array([np.interp(t_b, log.t_s, log.epm_m[:, k]) for k in range(3)])
    if force_fn is None:
        force_fn = capsule_force_function(scenario, force_model or scenario.force_model)
    pull_start_t_s = float(detect.get("pull_start_t_s", PULL_START_T_S))
    offset = _tare(log, rest, force_fn, pull_start_t_s) if tare else np.zeros(2)
    lead = epm[:2] - rest - offset
    force = np.asarray(force_fn(lead, epm[2]), dtype=float).ravel()
    normal = float(np.asarray(normal_force_expr(scenario, force[2]), dtype=float))
    if not normal > 0:
        raise LearningDataError(f"{log.path}: normal force {normal:.4g} N <= 0 at the breakaway")
    drag = float(scenario.friction.tether_drag_n)
    mu_s = (math.hypot(force[0], force[1]) - drag) / normal
    return BreakawayEvent(
        path=log.path,
        rest_s=float(rest_s),
        t_break_s=float(t_b),
        rest_position_m=rest,
        lead_m=lead,
        height_m=float(epm[2]),
        force_n=force,
        normal_n=normal,
        drag_n=drag,
        mu_s=float(mu_s),
        noise_m=float(noise),
        threshold_m=float(threshold),
        tare_m=offset,
    )


def _tare(log: RunLog, rest: np.ndarray, force_fn: ca.Function, pull_start_t_s: float) -> np.ndarray:
    """The measured rest lead less the force model's equilibrium lead at the EPM's rest height, m."""
    before = np.flatnonzero(log.t_s <= pull_start_t_s)
    k = int(before[-1]) if len(before) else 0
    epm = log.epm_m[k]
    measured = epm[:2] - rest
    try:
        equilibrium = equilibrium_lead(
            lambda lead: np.asarray(force_fn(lead, epm[2]), dtype=float).ravel(), measured
        )
    except RuntimeError as exc:
        raise LearningDataError(f"{log.path}: cannot tare the lead: {exc}") from None
    return np.asarray(measured - equilibrium, dtype=float)


@dataclass(frozen=True)
class HealingFit:
    """mu_s(T) = static_mu_1s + static_healing ln(T / 1 s), fitted by least squares.

    Attributes
    ----------
    static_mu_1s : float
        Breakaway coefficient after 1 s at rest.
    static_healing : float
        Its growth per e-fold of rest time.
    ci95 : dict of str to (float, float)
        95 % confidence interval of each of the two.
    n : int
        Breakaways fitted.
    dof : int
        Residual degrees of freedom, n - 2.
    rmse : float
        Root-mean-square residual of mu_s.
    rest_s, mu_s, residuals : numpy.ndarray
        The fitted points and mu_s - fit.
    """

    static_mu_1s: float
    static_healing: float
    ci95: dict[str, tuple[float, float]]
    n: int
    dof: int
    rmse: float
    rest_s: np.ndarray = field(repr=False)
    mu_s: np.ndarray = field(repr=False)
    residuals: np.ndarray = field(repr=False)

    def __call__(self, rest_s: np.ndarray | float) -> np.ndarray:
        """mu_s after ``rest_s`` seconds at rest."""
        return np.asarray(self.static_mu_1s + self.static_healing * np.log(np.asarray(rest_s, dtype=float)))


def fit_healing(rest_s: Sequence[float] | np.ndarray, mu_s: Sequence[float] | np.ndarray) -> HealingFit:
    """Least-squares fit of mu_s(T) = static_mu_1s + static_healing ln(T / 1 s) with 95 % intervals.

    Parameters
    ----------
    rest_s : array_like
        Rest times at the breakaways, s, each > 0.
    mu_s : array_like
        Breakaway coefficients.

    Returns
    -------
    HealingFit

    Raises
    ------
    LearningDataError
        Fewer than 3 points or fewer than 2 distinct rest times (no interval), non-finite values
        or a rest time <= 0.
    """
    t = np.asarray(rest_s, dtype=float)
    mu = np.asarray(mu_s, dtype=float)
    if t.shape != mu.shape or t.ndim != 1:
        raise ValueError(f"rest_s and mu_s: must be 1-D of equal length, got {t.shape} and {mu.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(mu))):
        raise LearningDataError("breakaways: rest times and mu_s must be finite")
    if np.any(t <= 0):
        raise LearningDataError(f"breakaways: rest times must be > 0 s, got {float(t.min())}")
    if len(t) < 3 or len(np.unique(t)) < 2:
        raise LearningDataError(
            f"breakaways: need at least 3 breakaways at 2 or more rest times for a healing fit with "
            f"confidence intervals, got {len(t)} at {len(np.unique(t))} rest time(s)"
        )
    design = np.column_stack([np.ones_like(t), np.log(t)])
    beta, *_ = np.linalg.lstsq(design, mu, rcond=None)
    residuals = mu - design @ beta
    dof = len(t) - 2
    cov = float(residuals @ residuals) / dof * np.linalg.inv(design.T @ design)
    half = float(stats.t.ppf(0.5 + CONFIDENCE / 2, dof)) * np.sqrt(np.diag(cov))
    names = ("static_mu_1s", "static_healing")
    ci = {name: (float(beta[k] - half[k]), float(beta[k] + half[k])) for k, name in enumerate(names)}
    return HealingFit(
        static_mu_1s=float(beta[0]),
        static_healing=float(beta[1]),
        ci95=ci,
        n=len(t),
        dof=dof,
        rmse=float(np.sqrt(np.mean(residuals**2))),
        rest_s=t,
        mu_s=mu,
        residuals=residuals,
    )


@dataclass(frozen=True)
class StaticFrictionResult:
    """Breakaways measured in run logs and the healing law fitted to them.

    Attributes
    ----------
    events : tuple of BreakawayEvent
        One per log in which the capsule broke away.
    fit : HealingFit
        The healing law.
    notes : list of str
        Logs without a breakaway, one sentence each.
    force_model : str
        The force model the forces came from.
    """

    events: tuple[BreakawayEvent, ...]
    fit: HealingFit
    notes: list[str]
    force_model: str


def learn_static_friction(
    paths: Sequence[str | Path],
    scenario: Scenario,
    force_model: Literal["dipole", "lookup"] | None = None,
    tare: bool = True,
    **detect: Any,
) -> StaticFrictionResult:
    """Measure the breakaway in each breakaway log and fit the healing law to them.

    Parameters
    ----------
    paths : sequence of str or Path
        The breakaway runs' ``log.csv`` files.
    scenario : Scenario
        Force model (default), capsule, tether drag.
    force_model : {'dipole', 'lookup'}, optional
        Default ``scenario.force_model``.
    tare : bool
        Measure each lead from the force model's equilibrium lead at the rest
        (:func:`breakaway_event`); a rest lead farther than :data:`TARE_NOTE_M` from it is noted.
    **detect
        Passed to :func:`detect_breakaway`.

    Raises
    ------
    LearningDataError
        A log cannot be read, or too few breakaways for the fit (:func:`fit_healing`).
    """
    kind = force_model or scenario.force_model
    force_fn = capsule_force_function(scenario, kind)
    events, notes = [], []
    for path in paths:
        log = read_run_log(path)
        event = breakaway_event(log, scenario, force_fn=force_fn, tare=tare, **detect)
        if event is None:
            notes.append(f"{path}: no breakaway found (the capsule never moved clearly from its rest)")
            continue
        events.append(event)
        if float(np.hypot(*event.tare_m)) > TARE_NOTE_M:
            notes.append(
                f"{path}: the capsule rested {1e3 * float(np.hypot(*event.tare_m)):.1f} mm from the force "
                "model's zero-force lead; if it was not settled under the magnet, learn without the tare "
                "(--no-tare)"
            )
    try:
        fit = fit_healing([e.rest_s for e in events], [e.mu_s for e in events])
    except LearningDataError as exc:
        raise LearningDataError(f"{len(paths)} breakaway log(s): {exc}") from None
    return StaticFrictionResult(tuple(events), fit, notes, kind)
