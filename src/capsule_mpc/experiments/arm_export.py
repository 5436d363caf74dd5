"""An EPM plan file exported for the robot (what ``capsule-mpc arm-export`` runs): the scenario it
is checked with, every row checked before any Ruckig or IK work, the export into a folder
(:func:`capsule_mpc.arm.export_arm_trajectory`) and its figures in words.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ..arm import (
    ArmError,
    ArmExport,
    check_epm_plan,
    default_max_deviation_m,
    export_arm_trajectory,
    read_epm_plan_csv,
)
from ..budget import check_arm_export
from ..config import ConfigError, Scenario
from ..outputs import output_folder

__all__ = ["PLAN_CONFIG", "PlanExport", "export_lines", "export_plan", "plan_config"]

#: The scenario file ``plan`` and ``simulate`` write beside their results.
PLAN_CONFIG = "config.yaml"


def plan_config(plan: str | Path, config: str | Path | None) -> tuple[Path, str]:
    """The scenario an EPM plan is checked and exported with, and where it came from in words.

    ``config`` if given; else the :data:`PLAN_CONFIG` beside the plan.

    Raises
    ------
    ConfigError
        Neither exists (``--config: required ...``).
    """
    if config is not None:
        return Path(config), "--config"
    beside = Path(plan).resolve().parent / PLAN_CONFIG
    if beside.is_file():
        return beside, "the config beside the plan"
    raise ConfigError(
        f"--config: required: no {PLAN_CONFIG} beside {plan}; give the scenario the plan was made for "
        "(its limits, workspace and arm), e.g. --config configs/paper.yaml"
    )


@dataclass(frozen=True)
class PlanExport:
    """An exported plan: how many rows it had, the export, and its wall time (Ruckig, IK, checks
    and files), s."""

    n_points: int
    export: ArmExport
    wall_s: float


def export_plan(
    scenario: Scenario,
    plan: str | Path,
    out: str | Path,
    *,
    plot: bool = True,
    inputs: Mapping[str, str | Path | None] | None = None,
) -> PlanExport:
    """Read the EPM plan CSV ``plan``, check it, and export it into the output folder ``out``.

    Every row is checked first (:func:`capsule_mpc.arm.check_epm_plan`, its span included), then
    what the setpoints need (:func:`capsule_mpc.budget.check_arm_export`): before any Ruckig or
    IK work. A refusal leaves nothing written.

    Parameters
    ----------
    scenario : Scenario
        Limits, workspace and arm (:func:`plan_config`).
    plan : str or Path
        The CSV (``t_s, epm_x_m, epm_y_m[, epm_z_m]``).
    out : str or Path
        The output folder (:func:`capsule_mpc.outputs.output_folder`).
    plot : bool
        Also draw the joint figure.
    inputs : mapping, optional
        The command's input files by option, which the folder must not hold.

    Raises
    ------
    ArmError
        A row or the arm's trajectory refused (time and position named).
    ValueError
        An unreadable plan or one beyond the budget (a :class:`ConfigError`), or an output folder
        refused (:class:`~capsule_mpc.errors.OutputError`).
    OSError
        A file that cannot be written.
    """
    t, p = read_epm_plan_csv(plan, default_height_m=scenario.plate.epm_height_m)
    check_epm_plan(scenario, t, p, default_max_deviation_m(scenario))
    check_arm_export(scenario, float(t[-1] - t[0]), f"{plan}: t_s")
    wall0 = time.perf_counter()
    refusals = (ArmError, ValueError, OSError)  # nothing written: what was is removed
    with output_folder(out, "arm-export", refusals=refusals, inputs=inputs) as folder:
        result = export_arm_trajectory(scenario, t, p, folder.path, plot=plot)
    return PlanExport(len(t), result, time.perf_counter() - wall0)


def export_lines(done: PlanExport) -> list[str]:
    """An export in words: setpoints, deviation from the plan, jerk, IK, joints, time, files."""
    s = done.export.summary
    smoothing = s.get("smoothing", {})
    check = s["check"]
    ik = s["ik"]
    rate, n_set, dur = s["arm_rate_hz"], s["n_setpoints"], s["duration_s"]
    dev_rms = smoothing.get("rms_deviation_m", 0.0) * 1e3
    lag = smoothing.get("end_lag_s", 0.0)
    jerk = max(s["max_fd_jerk_mps3"])
    steps = ik["total_iterations"] / max(ik["n_points"], 1)
    used = max(a / b for a, b in zip(s["max_joint_speed_radps"], s["joint_speed_limit_radps"]))
    margin = min(s["min_joint_margin_rad"])
    ik_err = ik["max_position_error_m"]
    return [
        f"{done.n_points} plan points -> {n_set} setpoints at {rate:g} Hz ({dur:.2f} s)",
        f"  EPM deviation from the plan max {check['max_deviation_m'] * 1e3:.2f} mm (tolerance "
        f"{check['tolerance_m'] * 1e3:.2f} mm), rms {dev_rms:.2f} mm; end {lag:.3f} s late",
        f"  worst finite-difference jerk {jerk:.4f} m/s^3 (limit {max(s['limits']['jerk_mps3'])})",
        f"  IK: worst EPM position error {ik_err:.2e} m, {steps:.2f} Newton steps per point",
        f"  joints: closest to a position limit {margin:.3f} rad; speed {used:.1%} of allowed",
        f"  Ruckig + IK + checks + files: {done.wall_s:.2f} s",
        *(f"  {kind:10s} {path}" for kind, path in done.export.paths.items()),
    ]
