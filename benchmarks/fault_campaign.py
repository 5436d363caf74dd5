"""Solver-fault campaign: at least 1,000 injected solver faults over lab runs of the MPC, checked.

Runs the MPC on ``--config`` (default configs/rectangle.yaml: the ``lab`` plant, 0.02 m/s) on the
draws of seeds 0 .. ``--runs - 1``, each draw as two variants of one campaign on the sweep's runner
(:func:`capsule_mpc.experiments.sweep.campaign.sweep`): ``faults``, with solver failures, NaN
solutions and late solves injected (``faults.solver_*_probability``, per frame) and the deadline
enforced (``mpc.enforce_deadline``: a late solve's command is replaced by the shifted plan), and
``no_faults``. Every command logged in a faulty run is checked against the limits, independently of
the controller's own counters: finite, per-axis speed <= ``limits.speed_mps``, change per frame <=
``limits.accel_mps2 / camera.rate_hz``, and the EPM inside the workspace. Per fault, the recovery
times from its end (:func:`capsule_mpc.sim.faults.recovery_times`): ``recovery_s`` to the error's
level before it, ``recovery_vs_fault_free_s`` to the fault-free run of the same seed. A real solve
past the frame deadline also makes the MPC fall back (``late_real``: late frames without an
injected late solve).

Writes the campaign's folder (``--out`` without ``.json``, resumable) and the report ``--out``,
aggregated from its run table. Exit status 1 when a command broke a limit, a run failed or fewer
than ``--target`` solver faults were injected (then raise ``--runs``); 2 for a bad ``--out``.

    .venv/bin/python benchmarks/fault_campaign.py [--runs 8] [--target 1000] [--probability 0.1]
        [--out results/benchmarks/fault_campaign.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from _args import campaign_report, exit_with, int_at_least

from capsule_mpc.atomic import json_ready
from capsule_mpc.config import packaged_config_path
from capsule_mpc.experiments.aggregate import aggregate
from capsule_mpc.experiments.runs import prepare_run
from capsule_mpc.experiments.sweep.campaign import local_workers, sweep, sweep_failures
from capsule_mpc.experiments.sweep.tasks import Variant, dask_client
from capsule_mpc.experiments.table import TABLE_FILE, read_table
from capsule_mpc.metrics import tracking_errors
from capsule_mpc.outputs import output_file_problem, write_report_file
from capsule_mpc.sim import RunResult
from capsule_mpc.sim.faults import SOLVER_FAULT_KINDS, recovery_times

#: Slack of the limit checks for floating-point rounding, in the checked quantity's unit.
TOL = 1e-9
#: The checks of every logged command, counted per run.
CHECKS = ("commands", "non_finite", "over_speed", "jumps", "outside_workspace")
#: The two variants of a draw and the run labels of their MPC.
FAULTS, CLEAN = "faults:mpc", "no_faults:mpc"


def _probability(text: str) -> float:
    value = float(text)
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"must be in (0, 1], got {text}")
    return value


def variants(probability: float) -> list[Variant]:
    """The faulty variant (each solver fault at ``probability`` per frame, deadline enforced) and
    the fault-free one, both run by the MPC."""
    faulty = {f"faults.{kind}_probability": probability for kind in SOLVER_FAULT_KINDS}
    faulty["mpc.enforce_deadline"] = True
    return [Variant("faults", faulty, ("mpc",)), Variant("no_faults", {}, ("mpc",))]


def check_commands(result: RunResult) -> dict[str, int]:
    """Count the logged commands that break a limit (from the log alone)."""
    log, lim = result.log, result.scenario.limits
    dt = 1.0 / result.scenario.camera.rate_hz
    u = np.stack([log["cmd_vx_mps"], log["cmd_vy_mps"], log["cmd_vz_mps"]], axis=1)
    epm = np.stack([log["epm_x_m"], log["epm_y_m"], log["epm_z_m"]], axis=1)
    lo, hi = np.asarray(lim.workspace_min_m), np.asarray(lim.workspace_max_m)
    counts = (
        len(u),
        np.sum(~np.all(np.isfinite(u), axis=1)),
        np.sum(np.any(np.abs(u) > lim.speed_mps + TOL, axis=1)),
        np.sum(np.any(np.abs(np.diff(u, axis=0)) > lim.accel_mps2 * dt + TOL, axis=1)),
        np.sum(np.any((epm < lo - TOL) | (epm > hi + TOL), axis=1)),
    )
    return {name: int(c) for name, c in zip(CHECKS, counts)}


def measure(results: Mapping[str, RunResult]) -> dict[str, dict[str, Any]]:
    """A draw's entries beside the faulty run's metrics (the runner's ``measure``): its command
    checks, failed and really late frames, and per fault kind the recovery times and the faults
    never recovered from, on their own and against the fault-free run."""
    if FAULTS not in results:
        return {}
    res, clean = results[FAULTS], results.get(CLEAN)
    events = [e for e in res.fault_events if e.kind in SOLVER_FAULT_KINDS]
    t, err = res.log["t_s"], 1e3 * tracking_errors(res.log)
    twin = None if clean is None else np.interp(t, clean.log["t_s"], 1e3 * tracking_errors(clean.log))
    late = {round(e.start_s, 6) for e in events if e.kind == "solver_late"}
    status = zip(res.log["solver_status"], t)
    entry: dict[str, Any] = {
        "checks": check_commands(res),
        "failed_frames": int(np.sum(res.log["solver_failed"])),
        "late_real": sum(s.startswith("late:") and round(float(x), 6) not in late for s, x in status),
    }
    for name, level in (("", None), ("_vs_fault_free", twin)):
        if name and twin is None:
            continue
        rec = recovery_times(t, err, events, level)
        entry[f"recovery{name}_s"] = {k: rec.times_s.get(k, []) for k in SOLVER_FAULT_KINDS}
        entry[f"unrecovered{name}"] = {k: rec.unrecovered.get(k, 0) for k in SOLVER_FAULT_KINDS}
    return {FAULTS: entry}


def distributions(faulty: pd.DataFrame, column: str) -> dict[str, dict[str, float]]:
    """Per fault kind (and ``all``) the distribution of the recovery times in ``column``, s."""
    times = [(k, x) for k in SOLVER_FAULT_KINDS for cell in faulty[f"{column}.{k}"] for x in json.loads(cell)]
    faults = pd.DataFrame(times, columns=["kind", "s"])
    faults = pd.concat([faults.assign(kind="all"), faults], ignore_index=True)
    stats = aggregate(faults, by=["kind"], metrics=["s"], quantiles={"p90": 0.9, "p99": 0.99})
    names = {"n": "n", "mean": "mean", "median": "median", "p90": "p90", "p99": "p99", "worst": "max"}
    return {
        k: {v: stats.loc[k, ("s", s)] for s, v in names.items()} if k in stats.index else {"n": 0}
        for k in ("all", *SOLVER_FAULT_KINDS)
    }


def report(table: pd.DataFrame, probability: float, scenario: str) -> dict[str, Any]:
    """The campaign's report from its run table."""
    stats = aggregate(table, by=["variant"])
    on, off = stats.loc["faults"], stats.loc["no_faults"]
    faulty = table[table["variant"] == "faults"]
    clean = table[table["variant"] == "no_faults"][["seed", "tracking_rms_mm", "final_error_mm"]]
    per_run = faulty.merge(clean, on="seed", suffixes=("", "_no_faults"))
    injected = {k: int(on[(f"faults_injected_{k}", "sum")]) for k in SOLVER_FAULT_KINDS}
    out: dict[str, Any] = {
        "scenario": scenario,
        "controller": "mpc",
        "fault_probability_per_frame": probability,
        "enforce_deadline": True,
        "runs": len(faulty),
        "solver_faults_injected": sum(injected.values()),
        "solver_faults_by_kind": injected,
        "command_checks": {c: int(on[(f"checks.{c}", "sum")]) for c in CHECKS},
        "decoupled_runs": int(on[("decoupled", "count")]),
        "dropped_runs": int(on[("dropped", "count")]),
    }
    for name in ("", "_vs_fault_free"):
        out[f"recovery{name}_s"] = distributions(faulty, f"recovery{name}_s")
        out[f"unrecovered{name}"] = {
            k: int(on[(f"unrecovered{name}.{k}", "sum")]) for k in SOLVER_FAULT_KINDS
        }
    for m in ("tracking_rms_mm", "final_error_mm"):
        for suffix, st in (("", on), ("_no_faults", off)):
            out[m + suffix] = {s: st[(m, s)] for s in ("mean", "sd", "worst")}
    keep = ["seed", *(f"faults_injected_{k}" for k in SOLVER_FAULT_KINDS), "failed_frames", "late_real"]
    keep += [*(f"checks.{c}" for c in CHECKS), "outcome", "decoupled", "dropped"]
    keep += ["tracking_rms_mm", "tracking_rms_mm_no_faults", "final_error_mm", "final_error_mm_no_faults"]
    return {**out, "per_run": per_run[keep].to_dict("records")}


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add = parser.add_argument
    add("--config", default=str(packaged_config_path("rectangle")), help="scenario (default: rectangle)")
    add("--runs", type=int_at_least(1), default=8, help="plant draws, seeds 0.. (default 8)")
    add("--target", type=int_at_least(1), default=1000, help="least solver faults injected (else exit 1)")
    add("--probability", type=_probability, default=0.1, help="per-frame probability of each solver fault")
    add("--workers", type=int_at_least(1), help="worker processes of the LocalCluster (default: CPU count)")
    add("--scheduler", help="address of a running Dask scheduler to run on instead")
    add("--out", type=campaign_report, default="results/benchmarks/fault_campaign.json", help="report")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the campaign and write the report (module docstring: the exit status)."""
    args = parse(argv)
    out = args.out
    problem = output_file_problem(out, "fault_campaign.json")
    if problem is not None:
        print(f"fault_campaign: --out: {problem}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    scenario, path, meta = prepare_run(args.config, None, None)
    local = local_workers(args.runs, args.workers, args.scheduler)
    with dask_client(args.scheduler, local) as client:
        summary = sweep(
            scenario, path, out.with_suffix(""), 0, args.runs, variants=variants(args.probability),
            client=client, meta=meta, measure=measure,
        )  # fmt: skip
    failures = sweep_failures(summary)
    for failure in failures:
        print(f"fault_campaign: {failure}", file=sys.stderr)
    name = f"{scenario.name} ({scenario.plant.preset} plant)"
    result = report(read_table(out.with_suffix("") / TABLE_FILE), args.probability, name)
    result.update(
        command=" ".join([Path(sys.argv[0]).name, *(argv if argv is not None else sys.argv[1:])]),
        wall_time_s=time.perf_counter() - t0,
        python=platform.python_version(),
        machine=platform.machine(),
        load_average=list(os.getloadavg()),
    )
    if write_report_file(out, json.dumps(json_ready(result), indent=2) + "\n", "fault_campaign") != 0:
        return 2
    print(f"{result['solver_faults_injected']} solver faults over {result['runs']} runs")
    bad = sum(v for k, v in result["command_checks"].items() if k != "commands")
    return 0 if not bad and not failures and result["solver_faults_injected"] >= args.target else 1


if __name__ == "__main__":
    exit_with(main)
