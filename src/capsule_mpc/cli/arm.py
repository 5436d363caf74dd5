"""``capsule-mpc arm-export``: an EPM plan CSV -> jerk-limited setpoints -> joint commands for the robot.

The scenario (limits, arm) is ``--config``, or else the ``config.yaml`` beside the plan (``plan``
and ``simulate`` write one beside ``epm_plan.csv`` and ``log.csv``); the command says which it
used. Without either it is refused: a plan checked against another rig's limits is not checked.

Exit status: 0 when the files were written; 2 when nothing was written: an unreadable or malformed
plan, a row beyond the limits or outside the workspace (the file, the 1-based data row and the
field are named), a plan longer than the budget allows (rows, span, the setpoints' memory:
:mod:`capsule_mpc.budget`), a trajectory the arm cannot follow or that fails its final check
(time and EPM position named), no or a bad config, or an output folder that cannot be written.

The work is :mod:`capsule_mpc.experiments.arm_export`.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ..arm import ArmError
from ..config import ConfigError, load_config
from ..experiments.arm_export import export_lines, export_plan, plan_config
from .arguments import input_files

__all__ = ["register", "run"]


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
        "--plan",
        required=True,
        help="EPM trajectory CSV (e.g. epm_plan.csv or a run log): at most 3600000 rows spanning at most "
        "3600 s, whose arm setpoints fit in half the memory available (capsule_mpc.budget)",
    )
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument(
        "--config",
        default=None,
        help="scenario YAML the plan was made for (default: config.yaml beside the plan; required "
        "without one)",
    )
    p.add_argument("--no-plot", action="store_true", help="skip the joint figure")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Export ``--plan`` into ``--out``; 2 if anything fails (nothing written), else 0."""
    try:
        config, source = plan_config(args.plan, args.config)
    except ConfigError as exc:
        print(f"capsule-mpc arm-export: {exc} (nothing written)", file=sys.stderr)
        return 2
    scenario = load_config(config)
    print(f"config: {config} ({source})")
    try:
        inputs = input_files(args, "--plan", "--config")
        done = export_plan(scenario, args.plan, args.out, plot=not args.no_plot, inputs=inputs)
    except (ArmError, ValueError, OSError) as exc:
        where = f"{args.plan}: " if isinstance(exc, ArmError) else ""
        print(f"capsule-mpc arm-export: {where}{exc} (nothing written)", file=sys.stderr)
        return 2
    print("\n".join(export_lines(done)))
    return 0
