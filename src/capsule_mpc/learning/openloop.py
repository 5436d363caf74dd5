"""Is a run log an open-loop demonstration? Learning c(v) assumes it is (paper §IV-C).

The paper moved the EPM along preset paths at preset speeds, whatever the capsule did.
In a closed-loop run (the MPC) the EPM moves *in response to the measured capsule*, and
that breaks the fit in two ways: the lead, hence the traction F, becomes correlated with
the camera noise that the controller reacts to (a feedback bias in the regressor), and
the controller holds the speed near the operating speed, so the samples span too narrow a
range for c(v)'s shape. A polynomial fitted to such a log swings with the noise.

Two pieces of evidence, either of which makes a log closed-loop:

1. **Metadata.** ``run.json`` beside the log (written by every simulator run) names the
   controller; only those in :data:`OPEN_LOOP_CONTROLLERS` never read the capsule while
   moving.
2. **Content** (any log with camera columns, also from a rig). A feedback controller reacts
   to each camera frame, noise included, so the EPM's velocity changes in the frames after a
   measurement depend on that measurement's noise. Open loop, the EPM cannot know the
   camera's noise. The test is Granger's: per axis, regress the EPM's frame-to-frame velocity
   change on its own :data:`FEEDBACK_LAGS` previous values and on the camera's
   high-frequency residual (measurement minus a short Savitzky-Golay smooth: the camera
   noise, the capsule's own motion removed) in the :data:`FEEDBACK_LAGS` previous frames,
   and test the residual's coefficients for zero (Wald statistic, chi^2 with FEEDBACK_LAGS
   degrees of freedom per axis; Q sums both axes). Only *past* measurements enter, and the
   EPM's own past absorbs its scheduled ramps (start, corners), so the capsule reacting to
   the EPM, which happens open loop too, is not mistaken for the EPM reacting to the
   capsule. A p-value below :data:`FEEDBACK_P_VALUE` flags feedback.

   Measured (lab plant): MPC runs give Q = 241-551 (``simulate --config configs/rectangle.yaml
   --controller mpc``, seeds 0-2) and 399 (``configs/pipe.yaml``); open-loop runs give Q = 1-18
   (33 ``demonstrate`` runs: the default set and ``--repeats 2 --seed 5``; the mean, 7, is the
   chi^2's 8), ``paper_0.8v`` 5 and ``plan`` 6.5 on rectangle.yaml. The test needs neither a
   constant speed nor straight paths, so the plan replay (open loop, varying speed) passes. With a noiseless
   camera it has nothing to go on and finds no feedback; the metadata still does.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats
from scipy.signal import savgol_filter

from .logs import RunLog

__all__ = [
    "FEEDBACK_LAGS",
    "FEEDBACK_P_VALUE",
    "OPEN_LOOP_CONTROLLERS",
    "LoopCheck",
    "check_open_loop",
    "run_controller",
]

#: Controllers that never read the capsule while the EPM moves: the baselines ``follow`` and
#: ``paper_0.8v`` (capsule_mpc.baselines: the camera only calibrates the offset at rest) and the
#: plan replay ``plan`` (capsule_mpc.planner.replay).
OPEN_LOOP_CONTROLLERS = ("follow", "paper_0.8v", "plan")
#: Frames after a measurement in which a controller's reaction is looked for: the command of
#: that frame, a compute delay of up to a frame, and the arm's acceleration limit spreading a
#: velocity step over a few frames.
FEEDBACK_LAGS = 4
#: p-value below which the correlation counts as feedback: with 15 logs (the default
#: demonstrations) the chance of one false warning is 1.5 %.
FEEDBACK_P_VALUE = 1e-3
#: Savitzky-Golay smoothing (frames, order) whose residual is the camera's high-frequency noise:
#: 0.3 s at 30 Hz, short enough that the residual is nearly white, long enough for the
#: capsule's motion to be smooth over it.
_HIGHPASS_FRAMES = 9
_HIGHPASS_ORDER = 2
#: Fewest camera frames the content test runs on (below it r_L's standard error exceeds ~0.1).
_MIN_FRAMES = 100


@dataclass(frozen=True)
class LoopCheck:
    """Whether a log looks like an open-loop demonstration.

    Attributes
    ----------
    path : Path
        The log.
    controller : str or None
        The controller named by ``run.json`` beside the log (None: no readable run.json).
    q_statistic : float or None
        The feedback statistic Q (None: the content test could not run).
    dof : int
        Its degrees of freedom.
    p_value : float or None
        P(Q >= q) for an open-loop run.
    n_frames : int
        Camera frames the content test used.
    closed_loop : bool
        Whether the metadata or the content says closed loop.
    reason : str
        Why (empty when open loop); or why the content test could not run.
    """

    path: Path
    controller: str | None
    q_statistic: float | None
    dof: int
    p_value: float | None
    n_frames: int
    closed_loop: bool
    reason: str

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dict."""
        return {**self.__dict__, "path": str(self.path)}


def run_controller(log_path: Path) -> str | None:
    """The controller named by the ``run.json`` beside a log, or None (absent or unreadable)."""
    meta = log_path.parent / "run.json"
    try:
        data = json.loads(meta.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    controller = data.get("controller") if isinstance(data, dict) else None
    return controller if isinstance(controller, str) else None


def _lagged(x: np.ndarray, lags: int) -> np.ndarray:
    """Columns x[k - 1], ..., x[k - lags] for k = lags .. len(x) - 1."""
    n = len(x)
    return np.column_stack([x[lags - j : n - j] for j in range(1, lags + 1)])


def _granger_statistic(measured: np.ndarray, epm_change: np.ndarray, valid: np.ndarray) -> float:
    """Wald statistic (chi^2, FEEDBACK_LAGS dof) that past ``measured`` predicts ``epm_change``.

    Least squares of epm_change[k] on a constant, its own FEEDBACK_LAGS past values and the
    FEEDBACK_LAGS past values of ``measured``; the statistic tests the last block for zero.
    Rows whose past measurements include a dropped frame are left out.
    """
    lags = FEEDBACK_LAGS
    y = epm_change[lags:]
    own = _lagged(epm_change, lags)
    other = _lagged(measured, lags)
    rows = np.all(_lagged(valid.astype(float), lags) > 0, axis=1)
    y, own, other = y[rows], own[rows], other[rows]
    x = np.column_stack([np.ones(len(y)), own, other])
    if len(y) <= x.shape[1] or not np.any(other):
        return 0.0
    # Normal equations: 9 unknowns, so the 9 x 9 Gram matrix is cheap and (pseudo-)inverted once.
    gram_inv = np.linalg.pinv(x.T @ x)
    coef = gram_inv @ (x.T @ y)
    resid = y - x @ coef
    sigma2 = float(resid @ resid) / (len(y) - x.shape[1])
    if sigma2 <= 0:
        return 0.0
    block = slice(1 + lags, 1 + 2 * lags)
    beta = coef[block]
    return float(beta @ np.linalg.pinv(sigma2 * gram_inv[block, block]) @ beta)


def _feedback_statistic(t_s: np.ndarray, camera_m: np.ndarray, epm_m: np.ndarray) -> tuple[float, int]:
    """Q of the camera-noise -> later-EPM-velocity-change test (module docstring), frames used."""
    valid = np.all(np.isfinite(camera_m), axis=1)
    filled = np.column_stack([np.interp(t_s, t_s[valid], camera_m[valid, k]) for k in range(2)])
    noise = filled - savgol_filter(filled, _HIGHPASS_FRAMES, _HIGHPASS_ORDER, axis=0)
    velocity = np.diff(epm_m[:, :2], axis=0) / np.diff(t_s)[:, None]
    # change[k] = velocity over (k, k+1) - velocity over (k-1, k): the EPM's reaction to frame k.
    change = np.vstack([np.zeros((1, 2)), np.diff(velocity, axis=0), np.zeros((1, 2))])
    q = sum(_granger_statistic(noise[:, axis], change[:, axis], valid) for axis in range(2))
    return q, int(valid.sum())


def check_open_loop(log: RunLog) -> LoopCheck:
    """Check a run log for signs of closed-loop control (see the module docstring).

    Parameters
    ----------
    log : RunLog
        The log (:func:`~capsule_mpc.learning.logs.read_run_log`); without camera columns
        (``log.camera_m`` None) only the metadata is checked.

    Returns
    -------
    LoopCheck
    """
    controller = run_controller(log.path)
    camera_m = log.camera_m
    dof = 2 * FEEDBACK_LAGS
    q = p = None
    n = 0
    note = ""
    if camera_m is None:
        note = "no camera columns (meas_x_m, meas_y_m): the content test did not run"
    elif int(np.all(np.isfinite(camera_m), axis=1).sum()) < _MIN_FRAMES:
        note = f"fewer than {_MIN_FRAMES} camera frames: the content test did not run"
    else:
        q, n = _feedback_statistic(log.t_s, camera_m, log.epm_m)
        p = float(stats.chi2.sf(q, dof))
    reasons = []
    if controller is not None and controller not in OPEN_LOOP_CONTROLLERS:
        reasons.append(f"run.json names the feedback controller {controller!r}")
    if p is not None and p < FEEDBACK_P_VALUE:
        reasons.append(
            f"the EPM's velocity changes follow the camera's noise 1-{FEEDBACK_LAGS} frames later "
            f"(Q = {q:.0f}, p = {p:.1g}; open loop gives Q ~ {dof} +- {np.sqrt(2 * dof):.0f})"
        )
    reason = " and ".join(reasons) if reasons else note
    return LoopCheck(log.path, controller, q, dof, p, n, bool(reasons), reason)
