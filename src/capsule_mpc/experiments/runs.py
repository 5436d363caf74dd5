"""One closed-loop run as the commands make it: the scenario with its overrides checked against the
machine's bounds, and the files a run leaves beside its log (the prediction figure, the arm's
joint commands)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np

from ..arm import ArmError, check_run_trajectory, export_arm_trajectory, write_arm_outputs
from ..budget import Workload, check_run, speed_source
from ..config import Scenario, config_from_dict, load_config
from ..magnetics import force_map
from ..metrics import stack_predictions
from ..mpc.grid import prediction_steps_s
from ..path_reach import check_epm_height, check_epm_workspace
from ..paths import ReferencePath, path_from_scenario
from ..plots import plot_prediction
from ..sim import RunResult

__all__ = ["ARM_CONTROLLERS", "PREDICTION_FIGURE", "export_run_arm", "prepare_run", "write_prediction_figure"]

#: Controllers whose runs also get the arm outputs by default (their EPM trajectory is new).
ARM_CONTROLLERS = ("mpc",)
#: File name of the predicted-vs-actual figure.
PREDICTION_FIGURE = "mpc_prediction.png"


def prepare_run(
    config: str | Path | None,
    waypoints: str | Path | None,
    speed: float | None,
    plant_preset: str | None = None,
    work: Workload = Workload(),
) -> tuple[Scenario, ReferencePath, dict[str, Any]]:
    """Load a scenario, apply the ``--waypoints`` / ``--speed`` / ``--plant`` overrides, and build the path.

    Then, before any work, refuses what the machine cannot do (:func:`capsule_mpc.budget.check_run`
    with ``work``, a :class:`~capsule_mpc.budget.Workload`: runs beyond the maximum simulated time
    or the memory allowance, naming ``--speed`` or
    ``path.speed_mps``). Also makes sure the finite-magnet force map is cached (computing it,
    with a progress bar, on first use), and refuses a path whose EPM would have to leave its
    workspace (:func:`capsule_mpc.path_reach.check_epm_workspace`). The returned scenario carries
    the overrides (``path.kind: waypoints`` with the absolute file, ``path.speed_mps``), so its
    dump beside the results reproduces the run.

    Returns
    -------
    (Scenario, ReferencePath, dict)
        The scenario actually used, its reference path and provenance for ``run.json``.

    Raises
    ------
    ConfigError
        A bad config, override or waypoint file, work beyond the machine's bounds, or a path the
        EPM cannot follow inside its workspace (naming the waypoint).
    """
    base = load_config(config)
    path = path_from_scenario(base, waypoints=waypoints, speed=speed)
    scenario = base
    if waypoints is not None or speed is not None or plant_preset is not None:
        data = base.model_dump(mode="json", exclude_none=True)
        data["path"]["speed_mps"] = path.speed_mps
        if plant_preset is not None:
            data["plant"]["preset"] = plant_preset
        if waypoints is not None:
            data["path"]["kind"] = "waypoints"
            data["path"]["waypoints_file"] = str(Path(waypoints).resolve())
        scenario = config_from_dict(data)
        scenario.source_path = base.source_path
    source = speed_source("--speed" if speed is not None else None, path.speed_mps)
    check_run(scenario, path.length_m, path.speed_mps, source, work)
    check_epm_height(scenario)  # before a force map is computed for a height the code cannot model
    force_map(scenario, progress=True)  # computed once and cached: show progress on a fresh machine
    check_epm_workspace(scenario, path, source=waypoints)  # the EPM leads the capsule: room for it?
    meta = {
        "config": str(base.source_path) if base.source_path else None,
        "waypoints_file": str(Path(waypoints).resolve()) if waypoints is not None else None,
    }
    return scenario, path, meta


def write_prediction_figure(result: RunResult, out: str | Path) -> Path | None:
    """``mpc_prediction.png`` of a run whose controller predicts (see :func:`plot_prediction`).

    Returns the file, or None if the run holds no prediction.
    """
    stacked = stack_predictions(result.predictions)
    if stacked is None:
        return None
    first_s, step_s = prediction_steps_s(result.scenario)[[0, -1]]
    return plot_prediction(
        result.log, stacked, result.path, Path(out), float(step_s), result.controller, float(first_s)
    )


def export_run_arm(result: RunResult, out_dir: str | Path) -> dict[str, Path] | None:
    """Arm outputs of the EPM trajectory a run actually followed (frames at t >= 0).

    Calls :func:`capsule_mpc.arm.export_arm_trajectory`. If the arm cannot follow the
    trajectory (:class:`~capsule_mpc.arm.ArmError`, e.g. an unreachable target), a message
    naming the time and position is printed to stderr and nothing is written: the run itself
    is still a result.

    Returns
    -------
    dict of str to Path or None
        The files written, or None if the export was skipped.
    """
    if result.arm_run is not None:  # the robot arm ran the loop: its own joint commands
        return _export_robot_run(result, out_dir)
    log = result.log
    moving = np.asarray(log["t_s"]) >= 0
    if np.count_nonzero(moving) < 2:
        print("  arm: skipped (the run has fewer than two frames at t >= 0)", file=sys.stderr)
        return None
    epm = np.column_stack([log["epm_x_m"], log["epm_y_m"], log["epm_z_m"]])[moving]
    try:
        arm = export_arm_trajectory(result.scenario, log["t_s"][moving], epm, out_dir)
    except ArmError as exc:
        print(
            f"  arm: the robot arm cannot follow this EPM trajectory; arm files skipped: {exc}",
            file=sys.stderr,
        )
        return None
    s = arm.summary
    print(
        f"  arm: {s['n_setpoints']} setpoints at {s['arm_rate_hz']:.0f} Hz, worst IK error "
        f"{s['ik']['max_position_error_m']:.1e} m -> {', '.join(p.name for p in arm.paths.values())}"
    )
    return dict(arm.paths)


def _export_robot_run(result: RunResult, out_dir: str | Path) -> dict[str, Path] | None:
    """Write the joint commands the robot arm actually ran (checked in the run: ``arm_ok``)."""
    if result.flags.arm_failure:
        print(f"  arm: the joint commands fail their check; arm files skipped: {result.flags.arm_failure}",
              file=sys.stderr)  # fmt: skip
        return None
    assert result.arm_run is not None
    cart, joints = result.arm_run
    _check, summary = check_run_trajectory(result.scenario, cart, joints)
    paths = write_arm_outputs(out_dir, cart, joints, summary)
    print(
        f"  arm: the {summary['n_setpoints']} joint commands the arm ran at {summary['arm_rate_hz']:.0f} Hz, "
        f"worst IK error {summary['ik']['max_position_error_m']:.1e} m -> "
        f"{', '.join(p.name for p in paths.values())}"
    )
    return dict(paths)
