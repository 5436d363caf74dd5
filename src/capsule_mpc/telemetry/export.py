"""A run folder converted to MCAP: the channels the live telemetry writes, from the run's files.

Inputs (in the run folder): ``log.csv`` (every frame), ``run.json`` (controller, seed, outcome),
``config.yaml`` (the rig drawn in the scene, the arm's placement, the path), and when present
``joint_trajectory.csv`` (the arm's joint commands: the arm is drawn and its joint states written,
each frame taking the latest arm tick at or before its time, the first one before the
trajectory starts) and ``predictions.npz`` (the controller's predicted paths).

What a run folder cannot give: the controller's estimate (``/capsule/estimate`` is not written)
and the injected faults' events (their counts are in ``run.json``). A path read from a waypoint
file that is no longer there is drawn through the run's reference points instead.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from foxglove.messages import LogLevel

from ..config import Scenario, load_config
from ..errors import ConfigError
from ..paths import path_from_scenario
from ..sim.log import PREDICTIONS_FILE, read_log, read_predictions
from .messages import Clock, RigGeometry
from .observer import end_level
from .publisher import RunPublisher
from .sinks import Sinks

__all__ = ["JOINTS_FILE", "RunFolder", "RunFolderError", "export_run", "read_run_folder"]

#: The arm's joint commands in a run folder (``capsule_mpc.arm.export``).
JOINTS_FILE = "joint_trajectory.csv"
_REQUIRED = ("log.csv", "run.json", "config.yaml")


#: How many frame periods a log's time span may differ from the run's length (the last step of a
#: run that ends between frames, a failure row).
_FRAMES_SLACK = 1.5


class RunFolderError(ConfigError):
    """A run folder cannot be converted: a file is missing or unreadable (the message names it)."""


@dataclass(frozen=True)
class RunFolder:
    """A run folder's contents (see the module docstring)."""

    path: Path
    log: dict[str, np.ndarray]
    summary: dict[str, Any]
    scenario: Scenario
    joints: dict[str, np.ndarray] | None
    predictions: np.ndarray | None


def _summary(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise RunFolderError(f"{path}: unreadable: {exc}") from None
    missing = [
        k for k in ("controller", "seed", "metrics", "flags") if not isinstance(data, dict) or k not in data
    ]
    if missing:
        raise RunFolderError(f"{path}: not a run's summary (missing {missing})")
    return data


def _joints(path: Path) -> dict[str, np.ndarray] | None:
    if not path.is_file():
        return None
    # lazy: the arm package loads Pinocchio; a run folder without the arm's file never needs it
    from ..arm.export import read_joint_trajectory_csv

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # numpy warns of a file without data rows: refused too
            joints = read_joint_trajectory_csv(path)
    except (OSError, ValueError, IndexError, UserWarning) as exc:
        raise RunFolderError(f"{path}: unreadable: {exc}") from None
    t, q = joints["t_s"], joints["q_rad"]
    if len(t) == 0 or q.shape[1] == 0 or not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))):
        raise RunFolderError(f"{path}: needs at least one row of finite t_s and q columns")
    return joints


def _predictions(folder: Path, n_rows: int) -> np.ndarray | None:
    path = folder / PREDICTIONS_FILE
    if not path.is_file():
        return None
    try:
        _, xy = read_predictions(folder)
    except (OSError, ValueError, KeyError) as exc:
        raise RunFolderError(f"{path}: unreadable: {exc}") from None
    if xy.ndim != 3 or xy.shape[0] != n_rows or xy.shape[2] != 2:
        raise RunFolderError(
            f"{path}: capsule_xy_m must be ({n_rows}, N, 2) (one path per log row), got {xy.shape}"
        )
    return xy


def _check_complete(folder: Path, t_s: np.ndarray, summary: dict[str, Any], rate_hz: float) -> None:
    """Refuse a log that covers less (or more) time than its run lasted (``run.json``'s
    ``timing.sim_time_s``, from the first row): a file cut at a row boundary reads as a shorter run."""
    timing = summary.get("timing")
    lasted = timing.get("sim_time_s") if isinstance(timing, dict) else None
    if not isinstance(lasted, int | float) or not math.isfinite(lasted):
        return  # an older summary without the run's length: nothing to check against
    covered = float(t_s[-1] - t_s[0])
    if abs(covered - lasted) > _FRAMES_SLACK / rate_hz:
        raise RunFolderError(
            f"{folder / 'log.csv'}: covers {covered:.3f} s (t = {t_s[0]:.3f} to {t_s[-1]:.3f} s, "
            f"{len(t_s)} rows) but {folder / 'run.json'} says the run lasted {lasted:.3f} s: the log is "
            "cut short or not this run's"
        )


def read_run_folder(run_dir: str | Path) -> RunFolder:
    """Read and check a run folder (see the module docstring).

    Raises
    ------
    RunFolderError
        ``run_dir`` is not a folder, or one of its files is missing or unreadable (named).
    """
    folder = Path(run_dir)
    if not folder.is_dir():
        raise RunFolderError(f"RUN_DIR: {folder} is not a folder")
    for name in _REQUIRED:
        if not (folder / name).is_file():
            raise RunFolderError(f"{folder / name}: missing (a run folder holds {', '.join(_REQUIRED)})")
    try:
        log = read_log(folder / "log.csv")
    except (OSError, ValueError) as exc:
        raise RunFolderError(f"{folder / 'log.csv'}: unreadable: {exc}") from None
    if len(log["t_s"]) == 0:
        raise RunFolderError(f"{folder / 'log.csv'}: holds no frame")
    summary = _summary(folder / "run.json")
    try:
        scenario = load_config(folder / "config.yaml")
    except ConfigError as exc:
        raise RunFolderError(f"{folder / 'config.yaml'}: {exc}") from None
    _check_complete(folder, log["t_s"], summary, scenario.camera.rate_hz)
    joints = _joints(folder / JOINTS_FILE)
    return RunFolder(folder, log, summary, scenario, joints, _predictions(folder, len(log["t_s"])))


def _path_points(run: RunFolder) -> np.ndarray:
    """The path's vertices from the run's config; the reference points of the log if the config's
    path cannot be built any more (a waypoint file that is gone)."""
    try:
        return path_from_scenario(run.scenario).vertices_m
    except (ConfigError, OSError):
        return np.column_stack([run.log["ref_x_m"], run.log["ref_y_m"]])


def _joint_rows(joints: dict[str, np.ndarray], t_s: np.ndarray) -> np.ndarray:
    """For each frame time, the index of the latest arm tick at or before it (the first before it)."""
    idx = np.searchsorted(joints["t_s"], np.asarray(t_s) + 1e-9, side="right") - 1
    return np.clip(idx, 0, len(joints["t_s"]) - 1)


def export_run(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """Convert a run folder to MCAP (written atomically); the file written.

    Parameters
    ----------
    run_dir : path
        The run folder (``capsule-mpc simulate --out``).
    out : path, optional
        The MCAP file; default ``run.mcap`` in the run folder.

    Raises
    ------
    RunFolderError
        See :func:`read_run_folder`.
    """
    run = read_run_folder(run_dir)
    target = Path(out) if out is not None else run.path / "run.mcap"
    robot = None
    if run.joints is not None:
        # lazy: Pinocchio and example-robot-data load only for a run with the arm's joints
        from .robot import robot_view

        robot = robot_view(run.scenario.arm)
        width = run.joints["q_rad"].shape[1]
        if width != robot.kin.nq or run.joints["dq_radps"].shape[1] != width:
            raise RunFolderError(
                f"{run.path / JOINTS_FILE}: needs {robot.kin.nq} q and dq columns ({run.scenario.arm.robot}),"
                f" got {width} and {run.joints['dq_radps'].shape[1]}"
            )
    log, summary = run.log, run.summary
    t = np.asarray(log["t_s"], dtype=float)
    clock = Clock(float(t[0]))
    pub = RunPublisher(
        Sinks(target),
        clock,
        RigGeometry.of(run.scenario, _path_points(run)),
        robot,
        predicts=run.predictions is not None,
    )
    info = {
        "source": "export",
        "run_dir": str(run.path),
        "controller": str(summary["controller"]),
        "seed": str(summary["seed"]),
        "actuator": run.scenario.sim.actuator,
        "plant": run.scenario.plant.preset,
    }
    pub.start(float(t[0]), info, f"run started: controller {summary['controller']}, seed {summary['seed']}")
    _frames(pub, run)
    _end(pub, summary, float(t[-1]))
    return target


def _end(pub: RunPublisher, summary: dict[str, Any], t_end_s: float) -> None:
    """The plant's failure (if it failed) and the run's end, as ``run.json`` tells them."""
    flags, metrics = summary["flags"], summary["metrics"]
    if flags.get("decoupled") or flags.get("dropped"):
        fail_t = flags.get("failure_t_s")
        when = float(fail_t) if isinstance(fail_t, (int, float)) else t_end_s
        pub.event(when, LogLevel.Error, f"plant failed: {flags.get('failure', '')}")
    rms = metrics.get("tracking_rms_mm")
    rms_text = f"{rms:.2f}" if isinstance(rms, (int, float)) and math.isfinite(rms) else "n/a"
    outcome = _outcome(flags)
    text = f"run ended: {metrics.get('outcome', outcome)}; tracking RMS {rms_text} mm"
    pub.end(t_end_s, end_level(outcome), text)


def _outcome(flags: dict[str, Any]) -> str:
    """The run's outcome (a :class:`~capsule_mpc.sim.runner.RunOutcome` value) from its flags."""
    for name in ("decoupled", "dropped", "completed", "stalled", "timed_out"):
        if flags.get(name):
            return name
    return "running"


def _frames(pub: RunPublisher, run: RunFolder) -> None:
    """Every frame of the run's log."""
    log = run.log
    names = list(log)
    columns = [log[name].tolist() for name in names]
    joint_idx = _joint_rows(run.joints, log["t_s"]) if run.joints is not None else None
    for i, values in enumerate(zip(*columns)):
        row = dict(zip(names, values))
        q = dq = None
        if joint_idx is not None and run.joints is not None:
            j = int(joint_idx[i])
            q, dq = run.joints["q_rad"][j].tolist(), run.joints["dq_radps"][j].tolist()
        prediction = run.predictions[i] if run.predictions is not None else None
        pub.frame(row, q=q, dq=dq, prediction=prediction)
