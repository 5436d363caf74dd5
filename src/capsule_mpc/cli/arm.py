"""``capsule-mpc arm-export``: an EPM plan CSV -> jerk-limited setpoints -> joint commands for the robot.

The scenario (limits, arm) is ``--config``, or else the ``config.yaml`` beside the plan (``plan``
and ``simulate`` write one beside ``epm_plan.csv`` and ``log.csv``); the command says which it
used. Without either it is refused: a plan checked against another rig's limits is not checked.

Exit status: 0 when the files were written; 2 when nothing was written: an unreadable or malformed
plan, a row beyond the limits or outside the workspace (the file, the 1-based data row and the
field are named), a plan longer than the budget allows (rows, span, the setpoints' memory:
:mod:`capsule_mpc.budget`), a trajectory the arm cannot follow or that fails its final check
(time and EPM position named), no or a bad config, or an output folder that cannot be written.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from ..arm import ArmError, export_arm_trajectory, read_epm_plan_csv
from ..config import ConfigError, load_config
from ..outputs import output_folder
from .arguments import input_files

__all__ = ["PLAN_CONFIG", "plan_config", "register", "run"]

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


def register(sub: Any) -> None:
    """Add the ``arm-export`` command."""
    p = sub.add_parser(
        "arm-export",
        help="turn an EPM trajectory CSV into arm-rate setpoints and UR5 joint commands",
        description=(
            "Smooth an EPM Cartesian trajectory (CSV with t_s, epm_x_m, epm_y_m[, epm_z_m]) with "
            "Ruckig at the arm rate, solve the UR5 inverse kinematics, and write epm_trajectory.csv, "
            "joint_trajectory.csv, joint_trajectory.yaml (ROS JointTrajectory), joint_trajectory.png "
            "and arm_summary.json. Every row is checked first (finite, times strictly increasing, "
            "steps within the speed and acceleration limits, inside the EPM workspace) and the "
            "result before it is written (forward kinematics within a fifth of limits.max_lead_m "
            "of the plan, workspace, joint limits). The scenario is --config, else the config.yaml "
            "beside the plan (as plan and simulate write it). Exit status 0 when written; 2 when "
            "nothing was written (the message names the file and data row, or the time)."
        ),
    )
    p.add_argument(
        "--plan", required=True,
        help="EPM trajectory CSV (e.g. epm_plan.csv or a run log): at most 3600000 rows spanning at most "
        "3600 s, whose arm setpoints fit in half the memory available (capsule_mpc.budget)",
    )  # fmt: skip
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument(
        "--config", default=None,
        help="scenario YAML the plan was made for (default: config.yaml beside the plan; required "
        "without one)",
    )  # fmt: skip
    p.add_argument("--no-plot", action="store_true", help="skip the joint figure")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Export ``--plan`` into ``--out``; 2 if anything fails (nothing written), else 0."""
    from ..arm.checks import check_epm_plan, default_max_deviation_m
    from ..budget import check_arm_export

    try:
        config, source = plan_config(args.plan, args.config)
    except ConfigError as exc:
        print(f"capsule-mpc arm-export: {exc} (nothing written)", file=sys.stderr)
        return 2
    scenario = load_config(config)
    print(f"config: {config} ({source})")
    try:
        t, p = read_epm_plan_csv(args.plan, default_height_m=scenario.plate.epm_height_m)
        # Every row first (span included), then what the setpoints need: before any Ruckig or IK work.
        check_epm_plan(scenario, t, p, default_max_deviation_m(scenario))
        check_arm_export(scenario, float(t[-1] - t[0]), f"{args.plan}: t_s")
        wall0 = time.perf_counter()
        inputs = input_files(args, "--plan", "--config")
        refusals = (ArmError, ValueError, OSError)  # nothing written: what was is removed
        with output_folder(args.out, "arm-export", refusals=refusals, inputs=inputs) as folder:
            result = export_arm_trajectory(scenario, t, p, folder.path, plot=not args.no_plot)
    except (ArmError, ValueError, OSError) as exc:
        where = f"{args.plan}: " if isinstance(exc, ArmError) else ""
        print(f"capsule-mpc arm-export: {where}{exc} (nothing written)", file=sys.stderr)
        return 2
    wall = time.perf_counter() - wall0
    s = result.summary
    smoothing = s.get("smoothing", {})
    check = s["check"]
    ik = s["ik"]
    rate, n_set, dur = s["arm_rate_hz"], s["n_setpoints"], s["duration_s"]
    print(f"{len(t)} plan points -> {n_set} setpoints at {rate:g} Hz ({dur:.2f} s)")
    dev_rms = smoothing.get("rms_deviation_m", 0.0) * 1e3
    lag = smoothing.get("end_lag_s", 0.0)
    print(
        f"  EPM deviation from the plan max {check['max_deviation_m'] * 1e3:.2f} mm (tolerance "
        f"{check['tolerance_m'] * 1e3:.2f} mm), rms {dev_rms:.2f} mm; end {lag:.3f} s late"
    )
    jerk = max(s["max_fd_jerk_mps3"])
    print(f"  worst finite-difference jerk {jerk:.4f} m/s^3 (limit {max(s['limits']['jerk_mps3'])})")
    steps = ik["total_iterations"] / max(ik["n_points"], 1)
    ik_err = ik["max_position_error_m"]
    print(f"  IK: worst EPM position error {ik_err:.2e} m, {steps:.2f} Newton steps per point")
    used = max(a / b for a, b in zip(s["max_joint_speed_radps"], s["joint_speed_limit_radps"]))
    margin = min(s["min_joint_margin_rad"])
    print(f"  joints: closest to a position limit {margin:.3f} rad; speed {used:.1%} of allowed")
    print(f"  Ruckig + IK + checks + files: {wall:.2f} s")
    for kind, path in result.paths.items():
        print(f"  {kind:10s} {path}")
    return 0
