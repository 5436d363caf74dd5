"""``capsule-mpc plan``: the whole path as one optimal-control problem -> EPM plan (+ arm commands).

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
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..config import Scenario
    from ..paths import ReferencePath

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
        "--variant", choices=("fixed", "min_time"), default="fixed",
        help="fixed: track the reference at the nominal speed; min_time: fastest within a 0.5 mm tube",
    )  # fmt: skip
    p.add_argument(
        "--waypoints", default=None,
        help="CSV with header x_m,y_m replacing the config's path (at most 10000 waypoints)",
    )  # fmt: skip
    p.add_argument(
        "--speed", type=float, default=None,
        help="nominal path speed, m/s (overrides path.speed_mps); the fixed-time plan has a step per "
        "camera frame and must fit in half the memory available (capsule_mpc.budget)",
    )  # fmt: skip
    p.add_argument("--no-arm", action="store_true", help="skip the arm export (Ruckig + IK)")
    p.add_argument(
        "--no-progress", action="store_true", help="no progress bar (IPOPT iterations and elapsed time)"
    )
    p.set_defaults(func=run)


def _print_plan(summary: dict[str, Any]) -> None:
    c = summary["constraints"]
    lim = summary["limits"]
    res = summary["residual"] or {}
    nan = float("nan")
    arrival = c["arrival_s"] if c["arrival_s"] is not None else nan
    print(
        f"{summary['variant']} plan: {summary['status']} in {summary['iterations']} iterations, "
        f"solve {summary['solve_s']:.2f} s (build {summary['build_s']:.2f} s), {summary['n_steps']} steps "
        f"of {summary['dt_s'] * 1e3:.1f} ms"
    )
    print(
        f"  T = {summary['duration_s']:.2f} s vs nominal {summary['nominal_duration_s']:.2f} s "
        f"({summary['duration_over_nominal']:.2f}x); capsule at the end from t = {arrival:.2f} s"
    )
    print(
        f"  capsule cross-track max {c['cross_track_max_m'] * 1e3:.3f} mm, rms "
        f"{c['cross_track_rms_m'] * 1e3:.3f} mm; dynamics residual {res.get('position_m', nan):.1e} m"
    )
    print(
        f"  EPM speed {c['max_speed_mps']:.4f} (limit {lim['speed_mps']}) m/s, accel "
        f"{c['max_accel_mps2']:.3f} (limit {lim['accel_mps2']}) m/s^2, coupling "
        f"{c['max_coupling_m'] * 1e3:.1f} (limit {lim['max_lead_m'] * 1e3:.1f}) mm, F_N "
        f"[{c['min_normal_force_n']:.3f}, {c['max_normal_force_n']:.3f}] N "
        f"(limits [{lim['normal_force_min_n']}, {lim['normal_force_max_n']}])"
    )


def run(args: argparse.Namespace) -> int:
    """Plan, write the files, export the arm trajectory; see the module docstring for the status."""
    from ..budget import Workload
    from ..experiments.runs import prepare_run
    from ..outputs import output_folder
    from .arguments import input_files

    work = Workload(plan=args.variant, arm=not args.no_arm, closed_loop=False)
    scenario, path, meta = prepare_run(args.config, args.waypoints, args.speed, work=work)
    with output_folder(args.out, "plan", inputs=input_files(args, "--config", "--waypoints")) as folder:
        folder.status = _plan_into(args, scenario, path, meta, folder.path)
    return folder.status


def _plan_into(
    args: argparse.Namespace, scenario: Scenario, path: ReferencePath, meta: dict[str, Any], out: Path
) -> int:
    """Solve, write and export into the prepared folder ``out``; the exit status."""
    from ..arm import ArmError, export_arm_trajectory
    from ..atomic import write_text_atomic
    from ..planner import PLAN_JSON, plan_path, plan_summary, write_plan

    plan = plan_path(scenario, path, args.variant, progress=not args.no_progress)
    if not plan.success:
        summary = plan_summary(scenario, plan, path, meta)
        write_text_atomic(out / PLAN_JSON, json.dumps(summary, indent=2) + "\n")
        print(f"capsule-mpc plan: {plan.failure}; diagnostics in {out / PLAN_JSON}", file=sys.stderr)
        return 1
    paths = write_plan(scenario, plan, path, out, meta)
    _print_plan(json.loads(paths["json"].read_text(encoding="utf-8")))
    if not args.no_arm:
        try:
            arm = export_arm_trajectory(scenario, plan.t_s, plan.epm_position_m, out)
        except (ArmError, ValueError) as exc:
            print(f"capsule-mpc plan: arm export failed: {exc}", file=sys.stderr)
            return 1
        paths |= arm.paths
        ik = arm.summary["ik"]
        print(
            f"  arm: {arm.summary['n_setpoints']} setpoints at {arm.summary['arm_rate_hz']:.0f} Hz, "
            f"worst IK error {ik['max_position_error_m']:.1e} m"
        )
    for kind, file in paths.items():
        print(f"  {kind:10s} {file}")
    return 0
