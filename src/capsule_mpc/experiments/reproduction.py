"""The paper's experiments under its protocol, and what its v -> 0.8 v change depends on.

The protocol (paper §IV-D): its rig (``configs/paper.yaml`` for the plate, ``configs/pipe.yaml``
for the pipe); its controller, the arm running the path point to point at v (``follow``) and at
0.8 v (``paper_0.8v``); its metric, the standard deviation of the EPM-IPM distance ``|P_E - P_I|``
while the arm moves (:func:`paper_std_mm` over :func:`motion_windows`). The paper measured the
capsule with a camera, so the metric is given on the true positions and on the camera's.

:func:`protocol_rows` runs the experiments on the nominal rig and on plant draws;
:func:`sensitivity_rows` varies one plant constant at a time (mu0, the rate-and-state a and b, whose
difference is the steady-state slope c of the paper's c(v) law, and the camera noise) on the
nominal rig and runs both controllers at each value.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import Scenario, config_from_dict, load_config, packaged_config_path, scenario_data
from ..metrics import MOVING_SPEED_MPS
from ..paths import ReferencePath, path_from_scenario
from ..sim import simulate

__all__ = [
    "PAPER_RESULTS",
    "SENSITIVITY",
    "SPEED_LAWS",
    "Experiment",
    "lead_by_heading_mm",
    "motion_windows",
    "paper_std_mm",
    "pipe_speed_rows",
    "protocol_rows",
    "protocol_run",
    "scenario_variant",
    "sensitivity_rows",
]

#: The paper's numbers (paper §IV-D, Fig. 8 and 9): STD of |P_E - P_I| during motion, mm.
PAPER_RESULTS: dict[str, float] = {
    "plate_v": 3.5,
    "plate_0.8v": 3.3,
    "plate_change_pct": -5.6,
    "pipe_0.005": 5.1,
    "pipe_0.02": 4.7,
    "pipe_0.045": 4.9,
}
#: The sensitivity's axes: a scenario field (dotted) and its values; the nominal rig's value is
#: among them. a - b is the slope c of the steady-state law mu = mu0 - c ln(v*/v + 1).
SENSITIVITY: dict[str, tuple[float, ...]] = {
    "friction.mu0": (0.11, 0.22, 0.33, 0.44),
    "friction.rate_state.a": (0.015, 0.03, 0.045, 0.06),
    "friction.rate_state.b": (0.0, 0.015, 0.03, 0.045, 0.06),
    "camera.noise_std_m": (0.0, 3e-4, 1e-3, 2e-3),
}
#: Friction laws the pipe runs under at the paper's three speeds: the nominal rig's (a - b = 0.03:
#: friction grows with speed) and one that weakens with speed (b = 0.06: a - b = -0.015).
SPEED_LAWS: dict[str, dict[str, float]] = {
    "nominal": {},
    "weakening": {"friction.rate_state.b": 0.06},
}
#: The paper's pipe speeds, m/s.
PIPE_SPEEDS_MPS = (0.005, 0.02, 0.045)
#: The metrics a protocol run reports (mm, ratio).
_KEPT = ("tracking_rms_mm", "final_error_mm", "arrival_ratio", "lead_mean_mm")


@dataclass(frozen=True)
class Experiment:
    """One of the paper's experiments: a packaged scenario at a path speed.

    Attributes
    ----------
    name : str
        ``plate`` or ``pipe_<speed>``.
    config : str
        Packaged scenario (``paper`` or ``pipe``).
    speed_mps : float
        The arm's speed v, m/s.
    """

    name: str
    config: str
    speed_mps: float


#: The paper's experiments: the plate at 0.02 m/s, the pipe at its three speeds.
EXPERIMENTS: tuple[Experiment, ...] = (
    Experiment("plate", "paper", 0.02),
    Experiment("pipe_0.005", "pipe", 0.005),
    Experiment("pipe_0.02", "pipe", 0.02),
    Experiment("pipe_0.045", "pipe", 0.045),
)


def motion_windows(log: Mapping[str, np.ndarray]) -> np.ndarray:
    """The frames (bool mask) at t >= 0 while the EPM moves: horizontal speed above
    :data:`~capsule_mpc.metrics.MOVING_SPEED_MPS` (the paper's shaded windows of Fig. 8)."""
    t = np.asarray(log["t_s"], dtype=float)
    speed = np.hypot(np.asarray(log["epm_vx_mps"], dtype=float), np.asarray(log["epm_vy_mps"], dtype=float))
    return np.asarray((t >= 0) & (speed > MOVING_SPEED_MPS))


def paper_std_mm(log: Mapping[str, np.ndarray], source: str = "truth") -> float:
    """The paper's metric: std (ddof 0) of ``|P_E - P_I|`` over :func:`motion_windows`, mm.

    Parameters
    ----------
    log : mapping of str to numpy.ndarray
        A run log (``t_s``, ``epm_*``, ``capsule_*``, ``meas_*`` columns).
    source : {"truth", "camera"}
        The capsule position used: the true one, or the camera's (frames without a measurement
        left out; the camera's latency, bias and noise included, as the paper's rig measured it).

    Returns
    -------
    float
        NaN when no frame is in the windows.
    """
    if source not in ("truth", "camera"):
        raise ValueError(f"source: must be 'truth' or 'camera', got {source!r}")
    cols = ("capsule_x_m", "capsule_y_m") if source == "truth" else ("meas_x_m", "meas_y_m")
    cap = np.column_stack([np.asarray(log[c], dtype=float) for c in cols])
    epm = np.column_stack([np.asarray(log[c], dtype=float) for c in ("epm_x_m", "epm_y_m")])
    mask = motion_windows(log) & np.all(np.isfinite(cap), axis=1)
    if not np.any(mask):
        return math.nan
    d = epm[mask] - cap[mask]
    return float(np.std(np.hypot(d[:, 0], d[:, 1]))) * 1e3


def lead_by_heading_mm(log: Mapping[str, np.ndarray]) -> dict[str, float]:
    """The EPM-IPM distance ``|P_E - P_I|`` over :func:`motion_windows`, split by the arm's heading.

    Returns
    -------
    dict
        ``lead_x_legs_mm`` / ``lead_y_legs_mm``: its mean while the EPM moves mostly along x / y
        (NaN without such frames); ``paper_std_within_legs_mm``: the root of the pooled variance
        within the two groups, the part of :func:`paper_std_mm` (true positions) the heading does
        not explain.
    """
    mask = motion_windows(log)
    d = np.hypot(
        np.asarray(log["epm_x_m"], dtype=float) - np.asarray(log["capsule_x_m"], dtype=float),
        np.asarray(log["epm_y_m"], dtype=float) - np.asarray(log["capsule_y_m"], dtype=float),
    )[mask]
    along_x = np.abs(np.asarray(log["epm_vx_mps"], dtype=float)) >= np.abs(np.asarray(log["epm_vy_mps"]))
    groups = [d[along_x[mask]], d[~along_x[mask]]]
    means = [float(np.mean(g)) * 1e3 if g.size else math.nan for g in groups]
    pooled = sum(float(np.sum((g - np.mean(g)) ** 2)) for g in groups if g.size)
    within = math.sqrt(pooled / d.size) * 1e3 if d.size else math.nan
    return {"lead_x_legs_mm": means[0], "lead_y_legs_mm": means[1], "paper_std_within_legs_mm": within}


def scenario_variant(config: str, updates: Mapping[str, Any]) -> Scenario:
    """A packaged scenario with dotted fields replaced, e.g. ``{"plant.preset": "ideal"}``.

    Raises
    ------
    ConfigError
        A value out of its field's range (named as usual).
    """
    base = load_config(packaged_config_path(config))
    data: dict[str, Any] = scenario_data(base)
    for dotted, value in updates.items():
        *parents, leaf = dotted.split(".")
        node = data
        for key in parents:
            node = node[key]
        node[leaf] = value
    scenario = config_from_dict(data)
    scenario.source_path = base.source_path
    return scenario


def protocol_run(scenario: Scenario, path: ReferencePath, controller: str, seed: int) -> dict[str, Any]:
    """One run of ``controller`` scored the paper's way and the package's way.

    Returns
    -------
    dict
        ``paper_std_mm`` (truth) and ``paper_std_camera_mm`` over the motion windows,
        ``paper_std_window_mm`` (the package's ``paper_std_mm``, over t = 0 to the motion's end),
        the :func:`lead_by_heading_mm` split, ``tracking_rms_mm``, ``final_error_mm``,
        ``arrival_ratio``, ``lead_mean_mm``, ``completed``.
    """
    result = simulate(scenario, controller, path, seed)
    m = result.metrics
    row: dict[str, Any] = {
        "paper_std_mm": paper_std_mm(result.log, "truth"),
        "paper_std_camera_mm": paper_std_mm(result.log, "camera"),
        "paper_std_window_mm": float(m["paper_std_mm"]),
    }
    row.update(lead_by_heading_mm(result.log))
    row.update({k: float(m[k]) for k in _KEPT})
    row["completed"] = bool(m["completed"])
    return row


def protocol_rows(
    plants: Sequence[tuple[str, Sequence[int]]],
    controllers: Sequence[str] = ("follow", "paper_0.8v"),
    on_row: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """Every experiment of :data:`EXPERIMENTS` on each plant preset and its seeds, per controller.

    Parameters
    ----------
    plants : sequence of (str, sequence of int)
        Plant presets and the seeds of their draws, e.g. ``[("ideal", [0]), ("lab", range(10))]``.
    controllers : sequence of str
        The controllers (default the paper's two).
    on_row : callable, optional
        Called with each row as it is done.
    """
    rows = []
    for exp in EXPERIMENTS:
        for preset, seeds in plants:
            scenario = scenario_variant(exp.config, {"plant.preset": preset, "path.speed_mps": exp.speed_mps})
            path = path_from_scenario(scenario)
            for seed in seeds:
                for controller in controllers:
                    row = {
                        "experiment": exp.name,
                        "plant": preset,
                        "seed": int(seed),
                        "controller": controller,
                    }
                    row.update(protocol_run(scenario, path, controller, int(seed)))
                    rows.append(row)
                    if on_row is not None:
                        on_row(row)
    return rows


def sensitivity_rows(
    seed: int = 0,
    axes: Mapping[str, Sequence[float]] = SENSITIVITY,
    on_row: Callable[[dict[str, Any]], None] | None = None,
) -> list[dict[str, Any]]:
    """The plate experiment on the nominal rig (``plant.preset: ideal``), one field of ``axes`` varied
    at a time, ``follow`` and ``paper_0.8v`` at each value (the rows of :func:`protocol_run` with
    ``parameter``, ``value``, ``controller``)."""
    rows = []
    for field, values in axes.items():
        for value in values:
            scenario = scenario_variant("paper", {"plant.preset": "ideal", field: value})
            path = path_from_scenario(scenario)
            for controller in ("follow", "paper_0.8v"):
                row = {"parameter": field, "value": float(value), "controller": controller, "seed": seed}
                row.update(protocol_run(scenario, path, controller, seed))
                rows.append(row)
                if on_row is not None:
                    on_row(row)
    return rows


def pipe_speed_rows(
    seed: int = 0, on_row: Callable[[dict[str, Any]], None] | None = None
) -> list[dict[str, Any]]:
    """The pipe on the nominal rig at :data:`PIPE_SPEEDS_MPS` under each friction law of
    :data:`SPEED_LAWS`, ``follow`` (the rows of :func:`protocol_run` with ``law``, ``speed_mps``)."""
    rows = []
    for law, updates in SPEED_LAWS.items():
        for speed in PIPE_SPEEDS_MPS:
            scenario = scenario_variant("pipe", {"plant.preset": "ideal", "path.speed_mps": speed, **updates})
            row: dict[str, Any] = {"law": law, "speed_mps": speed, "controller": "follow", "seed": seed}
            row.update(protocol_run(scenario, path_from_scenario(scenario), "follow", seed))
            rows.append(row)
            if on_row is not None:
                on_row(row)
    return rows
