"""Solver-fault campaign: at least 1,000 injected solver faults over lab runs of the MPC, checked.

Runs the MPC on configs/rectangle.yaml (the ``lab`` plant, 0.02 m/s) with solver failures, NaN
solutions and late solves injected (``faults.solver_*_probability``, per frame) and the deadline
enforced (``mpc.enforce_deadline``: a late solve's command is replaced by the shifted plan, as on
the rig), seed after seed until at least ``--target`` solver faults were injected (and at least
``--runs`` runs). Every command in the logs is then checked against the limits, independently of
the controller's own counters: finite, per-axis speed <= ``limits.speed_mps``, change from one
frame to the next <= ``limits.accel_mps2 / camera.rate_hz`` (no jump), and the EPM inside the
workspace. Reports those counts, the recovery times after the solver faults
(:func:`capsule_mpc.sim.faults.recovery_times`, from the fault's end: ``recovery_s`` until the
tracking error is back within max(1 mm, its mean over the 0.5 s before) -- an upper bound that
includes the path's own error excursions -- and ``recovery_vs_fault_free_s`` until it is within
0.5 mm of the fault-free run of the same seed, or below 1 mm), and the tracking of the same
seeds without faults. The late solves are decided by the reported solve time, so a real solve past
the frame deadline on a loaded machine also makes the MPC fall back (``late_real`` per run:
frames whose solve was late without an injected late solve).

    .venv/bin/python benchmarks/fault_campaign.py [--runs 8] [--target 1000] [--probability 0.1]
        [--out results/benchmarks/fault_campaign.json]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from _args import int_at_least

from capsule_mpc.config import FaultsConfig, Scenario, packaged_config_path
from capsule_mpc.experiments.runs import prepare_run
from capsule_mpc.metrics import tracking_errors
from capsule_mpc.mpc import MPCController
from capsule_mpc.outputs import output_file_problem, write_report_file
from capsule_mpc.paths import ReferencePath
from capsule_mpc.sim import RunResult, simulate
from capsule_mpc.sim.faults import SOLVER_FAULT_KINDS, recovery_times

#: Most runs before the campaign gives up on reaching the target.
MAX_RUNS = 60
#: Slack of the limit checks for floating-point rounding, in the checked quantity's unit.
TOL = 1e-9


def _probability(text: str) -> float:
    value = float(text)
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], got {text}")
    return value


def faulty_scenario(scenario: Scenario, probability: float) -> Scenario:
    """``scenario`` with each solver fault at ``probability`` per frame and the deadline enforced."""
    faults = FaultsConfig(
        solver_failure_probability=probability,
        solver_nan_probability=probability,
        solver_late_probability=probability,
    )
    mpc = scenario.mpc.model_copy(update={"enforce_deadline": True})
    return scenario.model_copy(update={"faults": faults, "mpc": mpc})


def check_commands(result: RunResult) -> dict[str, int]:
    """Count the logged commands that break a limit (from the log alone)."""
    log, lim = result.log, result.scenario.limits
    dt = 1.0 / result.scenario.camera.rate_hz
    u = np.stack([log["cmd_vx_mps"], log["cmd_vy_mps"], log["cmd_vz_mps"]], axis=1)
    finite = np.all(np.isfinite(u), axis=1)
    epm = np.stack([log["epm_x_m"], log["epm_y_m"], log["epm_z_m"]], axis=1)
    lo, hi = np.asarray(lim.workspace_min_m), np.asarray(lim.workspace_max_m)
    du = np.abs(np.diff(u, axis=0))
    return {
        "commands": len(u),
        "non_finite": int(np.sum(~finite)),
        "over_speed": int(np.sum(np.any(np.abs(u) > lim.speed_mps + TOL, axis=1))),
        "jumps": int(np.sum(np.any(du > lim.accel_mps2 * dt + TOL, axis=1))),
        "outside_workspace": int(np.sum(np.any((epm < lo - TOL) | (epm > hi + TOL), axis=1))),
    }


def _distribution(values: list[float]) -> dict[str, float]:
    if not values:
        return {"n": 0}
    a = np.asarray(values)
    q = np.percentile(a, [50, 90, 99])
    return {"n": len(a), "mean": float(a.mean()), "median": float(q[0]), "p90": float(q[1]),
            "p99": float(q[2]), "max": float(a.max())}  # fmt: skip


def _mean_sd_worst(values: list[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=float)
    return {
        "mean": float(a.mean()),
        "sd": float(a.std(ddof=1)) if len(a) > 1 else 0.0,
        "worst": float(a.max()),
    }


def run_campaign(
    scenario: Scenario, path: ReferencePath, runs: int, target: int, probability: float
) -> dict[str, Any]:
    """Run seeds 0, 1, ... until ``target`` solver faults and ``runs`` runs; the report."""
    faulty = faulty_scenario(scenario, probability)
    per_run: list[dict[str, Any]] = []
    recovery: dict[str, list[float]] = {k: [] for k in SOLVER_FAULT_KINDS}
    unrecovered = dict.fromkeys(SOLVER_FAULT_KINDS, 0)
    recovery_twin: dict[str, list[float]] = {k: [] for k in SOLVER_FAULT_KINDS}
    unrecovered_twin = dict.fromkeys(SOLVER_FAULT_KINDS, 0)
    totals = dict.fromkeys(("commands", "non_finite", "over_speed", "jumps", "outside_workspace"), 0)
    injected = dict.fromkeys(SOLVER_FAULT_KINDS, 0)
    t0 = time.perf_counter()
    seed = 0
    while seed < MAX_RUNS and (seed < runs or sum(injected.values()) < target):
        res = simulate(faulty, MPCController(), path, seed)
        clean = simulate(scenario, MPCController(), path, seed)
        checks = check_commands(res)
        for key in totals:
            totals[key] += checks[key]
        events = [e for e in res.fault_events if e.kind in SOLVER_FAULT_KINDS]
        t, err = res.log["t_s"], 1e3 * tracking_errors(res.log)
        rec = recovery_times(t, err, events)
        clean_err = np.interp(t, clean.log["t_s"], 1e3 * tracking_errors(clean.log))
        twin = recovery_times(t, err, events, clean_err)
        for kind in SOLVER_FAULT_KINDS:
            injected[kind] += int(res.metrics[f"faults_injected_{kind}"])
            recovery[kind] += rec.times_s.get(kind, [])
            unrecovered[kind] += rec.unrecovered.get(kind, 0)
            recovery_twin[kind] += twin.times_s.get(kind, [])
            unrecovered_twin[kind] += twin.unrecovered.get(kind, 0)
        status, frames_t = res.log["solver_status"], res.log["t_s"]
        injected_late = {round(e.start_s, 6) for e in events if e.kind == "solver_late"}
        per_run.append({
            "seed": seed,
            **{f"faults_injected_{k}": int(res.metrics[f"faults_injected_{k}"]) for k in SOLVER_FAULT_KINDS},
            "failed_frames": int(np.sum(res.log["solver_failed"])),
            "late_real": int(sum(s.startswith("late:") and round(float(t), 6) not in injected_late
                                 for s, t in zip(status, frames_t))),
            "checks": checks,
            "outcome": res.metrics["outcome"],
            "decoupled": bool(res.metrics["decoupled"]), "dropped": bool(res.metrics["dropped"]),
            "tracking_rms_mm": res.metrics["tracking_rms_mm"],
            "tracking_rms_mm_no_faults": clean.metrics["tracking_rms_mm"],
            "final_error_mm": res.metrics["final_error_mm"],
            "final_error_mm_no_faults": clean.metrics["final_error_mm"],
        })  # fmt: skip
        n_faults = sum(per_run[-1][f"faults_injected_{k}"] for k in SOLVER_FAULT_KINDS)
        print(
            f"seed {seed}: {n_faults} solver faults, "
            f"tracking RMS {res.metrics['tracking_rms_mm']:.2f} mm ({clean.metrics['tracking_rms_mm']:.2f} "
            f"without), {res.metrics['outcome']}",
            file=sys.stderr,
        )
        seed += 1
    every = [x for times in recovery.values() for x in times]
    every_twin = [x for times in recovery_twin.values() for x in times]
    return {
        "scenario": "rectangle (lab plant)",
        "controller": "mpc",
        "fault_probability_per_frame": probability,
        "enforce_deadline": True,
        "runs": len(per_run),
        "solver_faults_injected": sum(injected.values()),
        "solver_faults_by_kind": injected,
        "command_checks": totals,
        "decoupled_runs": sum(r["decoupled"] for r in per_run),
        "dropped_runs": sum(r["dropped"] for r in per_run),
        "recovery_s": {"all": _distribution(every), **{k: _distribution(v) for k, v in recovery.items()}},
        "unrecovered": unrecovered,
        "recovery_vs_fault_free_s": {
            "all": _distribution(every_twin),
            **{k: _distribution(v) for k, v in recovery_twin.items()},
        },
        "unrecovered_vs_fault_free": unrecovered_twin,
        "tracking_rms_mm": _mean_sd_worst([r["tracking_rms_mm"] for r in per_run]),
        "tracking_rms_mm_no_faults": _mean_sd_worst([r["tracking_rms_mm_no_faults"] for r in per_run]),
        "final_error_mm": _mean_sd_worst([r["final_error_mm"] for r in per_run]),
        "final_error_mm_no_faults": _mean_sd_worst([r["final_error_mm_no_faults"] for r in per_run]),
        "per_run": per_run,
        "wall_time_s": time.perf_counter() - t0,
        "python": platform.python_version(),
        "machine": platform.machine(),
        "load_average": list(os.getloadavg()),
    }


def _finite(value: Any) -> Any:
    """``value`` with every non-finite float replaced by None (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def main(argv: list[str] | None = None) -> int:
    """Run the campaign and write the report; exit status 2 (and nothing written) for a bad ``--out``,
    1 when a command broke a limit or the target was not reached."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int_at_least(1), default=8, help="least number of runs (seeds 0..)")
    parser.add_argument("--target", type=int_at_least(1), default=1000, help="least solver faults injected")
    parser.add_argument("--probability", type=_probability, default=0.1,
                        help="per-frame probability of each solver fault, (0, 1]")  # fmt: skip
    parser.add_argument("--out", default="results/benchmarks/fault_campaign.json", help="JSON report file")
    args = parser.parse_args(argv)
    out = Path(args.out)
    problem = output_file_problem(out, "fault_campaign.json")
    if problem is not None:
        print(f"fault_campaign: --out: {problem}", file=sys.stderr)
        return 2
    scenario, path, _ = prepare_run(packaged_config_path("rectangle"), None, None)
    report = run_campaign(scenario, path, args.runs, args.target, args.probability)
    text = json.dumps(_finite(report), indent=2)
    print(text)
    if write_report_file(out, text + "\n", "fault_campaign") != 0:
        return 2
    bad = sum(v for k, v in report["command_checks"].items() if k != "commands")
    return 0 if bad == 0 and report["solver_faults_injected"] >= args.target else 1


if __name__ == "__main__":
    raise SystemExit(main())
