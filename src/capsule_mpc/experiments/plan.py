"""The whole path planned offline into a folder (what ``capsule-mpc plan`` runs): the plan solved
(:func:`capsule_mpc.planner.plan_path`), its files written (:func:`capsule_mpc.planner.write_plan`:
``epm_plan.csv``, ``plan.json``, ``config.yaml``, ``plan.png``) and, unless skipped, the arm's
joint commands (:func:`capsule_mpc.arm.export_arm_trajectory`).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

from ..arm import ArmError, export_arm_trajectory
from ..atomic import write_text_atomic
from ..config import Scenario
from ..paths import ReferencePath
from ..planner import PLAN_JSON, plan_path, plan_summary, write_plan

__all__ = ["plan_into", "plan_lines"]


def plan_lines(summary: dict[str, Any]) -> list[str]:
    """A plan's ``plan.json`` summary in words: solve, duration, tracking, the limits it keeps."""
    c = summary["constraints"]
    lim = summary["limits"]
    res = summary["residual"] or {}
    nan = float("nan")
    arrival = c["arrival_s"] if c["arrival_s"] is not None else nan
    return [
        f"{summary['variant']} plan: {summary['status']} in {summary['iterations']} iterations, "
        f"solve {summary['solve_s']:.2f} s (build {summary['build_s']:.2f} s), {summary['n_steps']} steps "
        f"of {summary['dt_s'] * 1e3:.1f} ms",
        f"  T = {summary['duration_s']:.2f} s vs nominal {summary['nominal_duration_s']:.2f} s "
        f"({summary['duration_over_nominal']:.2f}x); capsule at the end from t = {arrival:.2f} s",
        f"  capsule cross-track max {c['cross_track_max_m'] * 1e3:.3f} mm, rms "
        f"{c['cross_track_rms_m'] * 1e3:.3f} mm; dynamics residual {res.get('position_m', nan):.1e} m",
        f"  EPM speed {c['max_speed_mps']:.4f} (limit {lim['speed_mps']}) m/s, accel "
        f"{c['max_accel_mps2']:.3f} (limit {lim['accel_mps2']}) m/s^2, coupling "
        f"{c['max_coupling_m'] * 1e3:.1f} (limit {lim['max_lead_m'] * 1e3:.1f}) mm, F_N "
        f"[{c['min_normal_force_n']:.3f}, {c['max_normal_force_n']:.3f}] N "
        f"(limits [{lim['normal_force_min_n']}, {lim['normal_force_max_n']}])",
    ]


def plan_into(
    scenario: Scenario,
    path: ReferencePath,
    meta: dict[str, Any],
    out: Path,
    variant: Literal["fixed", "min_time"],
    *,
    arm: bool = True,
    progress: bool = True,
    say: Callable[[str], None] = print,
) -> int:
    """Solve, write and export into the prepared folder ``out``; the exit status.

    Parameters
    ----------
    scenario, path, meta
        What :func:`capsule_mpc.experiments.runs.prepare_run` returns.
    out : Path
        The output folder (:func:`capsule_mpc.outputs.output_folder`).
    variant : {'fixed', 'min_time'}
        The plan: the reference tracked at the nominal speed, or the fastest within a tube.
    arm : bool
        Also export the arm's joint commands.
    progress : bool
        A progress bar on stderr while the NLP is built and solved.
    say : callable
        Where the summary lines go (default ``print``).

    Returns
    -------
    int
        0; 1 if the solve failed (``plan.json`` holds its diagnostics) or the arm cannot follow
        the plan (the failure on stderr).
    """
    plan = plan_path(scenario, path, variant, progress=progress)
    if not plan.success:
        summary = plan_summary(scenario, plan, path, meta)
        write_text_atomic(out / PLAN_JSON, json.dumps(summary, indent=2) + "\n")
        print(f"capsule-mpc plan: {plan.failure}; diagnostics in {out / PLAN_JSON}", file=sys.stderr)
        return 1
    paths = write_plan(scenario, plan, path, out, meta)
    for line in plan_lines(json.loads(paths["json"].read_text(encoding="utf-8"))):
        say(line)
    if arm:
        try:
            exported = export_arm_trajectory(scenario, plan.t_s, plan.epm_position_m, out)
        except (ArmError, ValueError) as exc:
            print(f"capsule-mpc plan: arm export failed: {exc}", file=sys.stderr)
            return 1
        paths |= exported.paths
        s = exported.summary
        say(
            f"  arm: {s['n_setpoints']} setpoints at {s['arm_rate_hz']:.0f} Hz, "
            f"worst IK error {s['ik']['max_position_error_m']:.1e} m"
        )
    for kind, file in paths.items():
        say(f"  {kind:10s} {file}")
    return 0
