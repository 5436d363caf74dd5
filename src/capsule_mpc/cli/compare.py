"""``capsule-mpc compare``: every available controller on the same plant, path and seeds.

The comparison is :func:`capsule_mpc.experiments.sweep.campaign.compare_controllers` (its docstring says
what it writes). Exit status: 0 when every controller ran on every seed, 1 when any failed (each
failure is also printed on stderr), 2 on bad input, 130 on Ctrl-C.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..experiments import compare as comparison
from ..experiments.compare import check_controllers
from ..experiments.runs import prepare_run
from ..outputs import output_folder
from .arguments import add_run_arguments, input_files, refuse_seed_overflow, run_count
from .sweep import add_dask_arguments

__all__ = ["register", "run"]


def register(sub: Any) -> None:
    """Add the ``compare`` command."""
    p = sub.add_parser(
        "compare",
        help="run every available controller on the same plant and seeds",
        description=(
            "Run controllers (default: every registered one: follow, paper_0.8v, plan if available, mpc) on "
            "the same plant, path and seed; with --runs N on N seeds (seed, seed + 1, ...), each drawing its "
            "own plant and start offset. The runs of one seed are scored on a common window (t = 0 to the "
            "latest end of a run); the seeds run in parallel on Dask (a LocalCluster of --workers "
            "processes, or the cluster at --scheduler; with one local worker, in this process). Writes "
            "one run folder per controller and seed, "
            "runs.csv (the run table: a row per seed and controller), summary.json (means, spreads and "
            "every run), summary.md (mean ± sd for N > 1), trajectories.png, errors.png, "
            "metrics.png (distributions for N > 1) and, with mpc, mpc_prediction.png. A controller that "
            "fails (e.g. the planner's solve does not converge) gets no metrics: its row reads 'failed: "
            "<why>' and the exit status is 1. Ctrl-C stops at once with status 130 and records no result; "
            "the runs in progress keep their log so far and a finalised MCAP."
        ),
    )
    add_run_arguments(p)
    p.add_argument(
        "--controllers", nargs="+", default=None, help="only these controllers (default: all available)"
    )
    p.add_argument(
        "--runs",
        type=run_count,
        default=1,
        metavar="N",
        help="seeds per controller, an integer in [1, 10000]: run k uses seed + k (default 1)",
    )
    add_dask_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Compare the controllers; exit status 1 if any controller failed on a seed, 2 on bad input."""
    from contextlib import ExitStack
    from dataclasses import replace

    from ..experiments.sweep.campaign import compare_controllers, local_workers, sweep_failures
    from ..experiments.sweep.tasks import dask_client

    overflow = refuse_seed_overflow(args.seed, args.runs, 0)
    if overflow:
        print(f"capsule-mpc compare: {overflow}", file=sys.stderr)
        return 2
    names = check_controllers(args.controllers)
    local = local_workers(args.runs, args.workers, args.scheduler)
    work = replace(comparison.run_figures(names, args.runs), processes=local or 1)
    scenario, path, meta = prepare_run(args.config, args.waypoints, args.speed, args.plant, work)
    seed = scenario.sim.seed if args.seed is None else args.seed
    with ExitStack() as stack:
        client = stack.enter_context(dask_client(args.scheduler, None)) if args.scheduler else None
        folder = stack.enter_context(
            output_folder(args.out, "compare", inputs=input_files(args, "--config", "--waypoints"))
        )
        summary = compare_controllers(
            scenario, path, folder.path, seed, controllers=names, meta=meta, progress=not args.no_progress,
            runs=args.runs, workers=local, client=client,
        )  # fmt: skip
        failures = sweep_failures(summary)
        folder.status = 1 if failures else 0
    print(comparison.summary_table(summary["controllers"], args.runs), end="")
    for failure in failures:
        print(f"capsule-mpc compare: {failure}", file=sys.stderr)
    folders = (
        "one folder per controller" if args.runs == 1 else f"{comparison.RUNS_FOLDER}/seed_<S>/<controller>/"
    )
    print(f"results in {Path(args.out).resolve()} (summary.json, summary.md, runs.csv, *.png, {folders})")
    return folder.status
