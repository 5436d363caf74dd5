"""``capsule-mpc plan``: the whole path as one optimal-control problem -> EPM plan (+ arm commands),
made by :func:`capsule_mpc.experiments.plan.plan_into`.

Writes into ``--out``: ``epm_plan.csv`` (t_s, EPM position and velocity, predicted capsule
position), ``plan.json`` (solver status, iterations, times, dynamics residual, T vs nominal,
constraint report, config path), ``config.yaml`` and ``plan.png``; unless ``--no-arm``, also the
arm outputs of :func:`capsule_mpc.arm.export_arm_trajectory` (``epm_trajectory.csv``,
``joint_trajectory.csv`` / ``.yaml``, ``joint_trajectory.png``, ``arm_summary.json``).

A progress bar on stderr (unless ``--no-progress``) shows the NLP being built, then IPOPT's
iterations with the elapsed time, the objective and the iterate's largest constraint violation.

Exit status: 0 on success, 1 if the solve failed or the arm cannot follow the plan, 2 on a bad
config, waypoint file or option, 130 on Ctrl-C (which IPOPT would otherwise report as a failed
solve; the files written by then are complete, the others are not written).
"""

from __future__ import annotations

import argparse
from typing import Any

from ..outputs import output_folder
from .arguments import input_files

__all__ = ["register", "run"]


def register(sub: Any) -> None:
    """Add the ``plan`` command."""
    p = sub.add_parser(
        "plan",
        help="plan the EPM trajectory for the whole path offline (fixed or minimum time)",
        description=(
            "Solve the whole path as one optimal-control problem on the controller's model "
            "(multiple shooting, implicit Euler, IPOPT) and write epm_plan.csv, plan.json, "
            "config.yaml, plan.png and (unless --no-arm) the arm's joint trajectory."
        ),
    )
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument(
        "--variant",
        choices=("fixed", "min_time"),
        default="fixed",
        help="fixed: track the reference at the nominal speed; min_time: fastest within a 0.5 mm tube",
    )
    p.add_argument(
        "--waypoints",
        default=None,
        help="CSV with header x_m,y_m replacing the config's path (at most 10000 waypoints)",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=None,
        help="nominal path speed, m/s (overrides path.speed_mps); the fixed-time plan has a step per "
        "camera frame and must fit in half the memory available (capsule_mpc.budget)",
    )
    p.add_argument("--no-arm", action="store_true", help="skip the arm export (Ruckig + IK)")
    p.add_argument(
        "--no-progress", action="store_true", help="no progress bar (IPOPT iterations and elapsed time)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Plan, write the files, export the arm trajectory; see the module docstring for the status."""
    # lazy: the planner (CasADi) and the arm (Pinocchio) load when the plan starts, not for ``--help``
    from ..budget import Workload
    from ..experiments.plan import plan_into
    from ..experiments.runs import prepare_run

    arm, progress = not args.no_arm, not args.no_progress
    work = Workload(plan=args.variant, arm=arm, closed_loop=False)
    scenario, path, meta = prepare_run(args.config, args.waypoints, args.speed, work=work)
    with output_folder(args.out, "plan", inputs=input_files(args, "--config", "--waypoints")) as folder:
        folder.status = plan_into(scenario, path, meta, folder.path, args.variant, arm=arm, progress=progress)
    return folder.status
