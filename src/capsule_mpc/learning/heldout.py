"""Held-out check of a learned c(v): the steady EPM-capsule lead it predicts vs a run's.

A learned friction law is only useful if it predicts what the capsule does. The
observable it predicts most directly is the steady lead at a constant speed
(:func:`~capsule_mpc.learning.predict.steady_lead`); a straight run at a speed the
fit never saw measures it.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
from scipy.signal import savgol_filter

from ..config import LearnedFrictionModel, Scenario
from .data import LearningDataError
from .logs import LogOptions, RunLog, frame_period
from .predict import law_mu, steady_lead

__all__ = ["SteadyLead", "measured_steady_lead", "predicted_steady_lead"]

#: A frame is "steady" when the EPM and the capsule both move within this fraction of the
#: run's median EPM cruising speed.
_STEADY_SPEED_TOL = 0.05


@dataclass(frozen=True)
class SteadyLead:
    """The lead a run settles to while moving at constant speed.

    Attributes
    ----------
    lead_m : numpy.ndarray (2,)
        Mean EPM - capsule lead over the steady frames, m.
    std_m : numpy.ndarray (2,)
        Its standard deviation per axis, m.
    speed_mps : float
        Median EPM speed over those frames, m/s.
    direction : numpy.ndarray (2,)
        Mean unit direction of motion.
    n_frames : int
        Steady frames averaged.
    """

    lead_m: np.ndarray
    std_m: np.ndarray
    speed_mps: float
    direction: np.ndarray
    n_frames: int


def measured_steady_lead(
    log: RunLog, options: LogOptions | None = None, trim_fraction: float = 0.2
) -> SteadyLead:
    """The steady lead of a straight constant-speed run.

    Parameters
    ----------
    log : RunLog
        A run log read with ``truth=True`` (the simulator's capsule position; the lead is
        then exact at each frame, no latency).
    options : LogOptions, optional
        Savitzky-Golay window/order for the speeds.
    trim_fraction : float
        Fraction of the steady frames dropped at each end (start-up and stopping), in [0, 0.45].

    Raises
    ------
    LearningDataError
        If the log is not from the truth columns or has fewer than 10 steady frames.
    """
    if log.source != "truth":
        raise LearningDataError(f"{log.path}: read the log with truth=True for the measured steady lead")
    if not 0 <= trim_fraction <= 0.45:
        raise ValueError(f"trim_fraction: must be in [0, 0.45], got {trim_fraction}")
    options = options or LogOptions()
    dt = frame_period(log.t_s)
    sg = {"window_length": options.window_frames(dt), "polyorder": options.polyorder, "delta": dt, "axis": 0}
    # Savitzky-Golay needs uniform samples: resample the (jittered) frames onto a uniform grid.
    t = log.t_s[0] + dt * np.arange(int((log.t_s[-1] - log.t_s[0]) / dt + 1e-6) + 1)
    if len(t) < sg["window_length"]:
        raise LearningDataError(f"{log.path}: shorter than the {sg['window_length']}-frame filter window")
    epm = np.column_stack([np.interp(t, log.t_s, log.epm_m[:, k]) for k in range(2)])
    capsule = np.column_stack([np.interp(t, log.t_s, log.capsule_m[:, k]) for k in range(2)])
    v_e = savgol_filter(epm, deriv=1, **sg)
    v_i = savgol_filter(capsule, deriv=1, **sg)
    speed_e = np.linalg.norm(v_e, axis=1)
    cruise = float(np.median(speed_e[speed_e > 0.5 * speed_e.max()]))
    steady = (np.abs(speed_e - cruise) <= _STEADY_SPEED_TOL * cruise) & (
        np.linalg.norm(v_i - v_e, axis=1) <= _STEADY_SPEED_TOL * cruise
    )
    idx = np.flatnonzero(steady)
    cut = int(trim_fraction * len(idx))
    idx = idx[cut : len(idx) - cut]
    if len(idx) < 10:
        raise LearningDataError(f"{log.path}: only {len(idx)} steady frame(s), need at least 10")
    lead = epm[idx] - capsule[idx]
    direction = np.mean(v_e[idx] / speed_e[idx, None], axis=0)
    return SteadyLead(
        lead_m=lead.mean(axis=0),
        std_m=lead.std(axis=0),
        speed_mps=float(np.median(speed_e[idx])),
        direction=direction / np.linalg.norm(direction),
        n_frames=len(idx),
    )


def predicted_steady_lead(
    scenario: Scenario,
    model: LearnedFrictionModel,
    speed_mps: float,
    direction: np.ndarray | tuple[float, float],
    force_model: str | None = None,
    height_m: float | None = None,
    force_fn: ca.Function | None = None,
) -> np.ndarray:
    """The steady lead (m) a learned model predicts at ``speed_mps`` along ``direction``.

    mu from the model's law (paper eq. 10, c held at its end values outside the validity
    range), then :func:`~capsule_mpc.learning.predict.steady_lead` with ``force_model``
    (default: the one the model was learned with, else ``scenario.force_model``);
    ``force_fn`` is that model if already built.
    """
    kind = force_model or model.force_model or scenario.force_model
    mu = law_mu(model, scenario)(speed_mps)
    return steady_lead(scenario, mu, direction, force_model=kind, height_m=height_m, force_fn=force_fn)
