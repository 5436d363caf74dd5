"""``capsule-mpc sweep``: a campaign over seeded plant draws, every chosen controller on each, in parallel.

Run ``k`` of ``--runs N`` uses the seed ``seed + k``. As in ``compare --runs``, a seed fixes the
plant drawn around the nominal scenario (the ``plant`` section,
:func:`capsule_mpc.sim.draw_plant_truth`), the start offset and the camera noise; every controller
runs on that draw and the runs of one seed are scored on their common window
(:func:`capsule_mpc.experiments.compare.run_seed_controllers`). ``--vary plant.FIELD=LO:HI`` replaces
that field's draw by a uniform draw in [LO, HI] from the run's own stream
(``default_rng([seed, VARY_STREAM, i])``, ``i`` the field's index in
:data:`capsule_mpc.config.PLANT_FIXED`): the other fields draw as they would without it, and the
controllers are given the nominal scenario only (their belief), never the plant's values.

A run (one seed, every controller) is one task. The tasks run on a local process pool
(``concurrent.futures.ProcessPoolExecutor``, ``--workers`` processes, default the CPU count) or,
with ``--executor dask``, on Dask distributed: a ``LocalCluster`` of ``--workers`` processes, or
the cluster whose scheduler is at ``--scheduler``. A task's result does not depend on where it
runs: the same seeds give the same results on any executor and any number of workers, except the
wall-clock figures (:data:`WALL_CLOCK_KEYS`) and with ``plant.compute_delay_mode: solve_time``.

Writes, into ``--out``:

* ``sweep.json``: what the sweep is (the scenario with its overrides, the path, seeds,
  controllers and ``--vary`` ranges);
* ``runs/seed_<S>.json``, one per run as soon as it finishes (written atomically): the seed, the
  common window, each controller's metrics and flags as in ``compare``'s ``runs`` (or its
  ``error``), the plant's drawn values (``plant``) and the varied ones (``varied``);
* ``summary.json``, in the schema of ``compare --runs`` (``controllers.NAME.METRIC`` means,
  ``controllers.NAME.spread.METRIC`` ``{sd, min, max, n}``, ``runs``: every seed's file;
  :func:`capsule_mpc.experiments.compare.aggregate_runs`), plus ``plant_preset``, ``vary`` and
  ``worst`` (:func:`worst_runs`: per controller and metric the seeds of the worst runs, the
  seeds where a flag was raised, and those that failed);
* ``summary.md`` (the table of ``compare --runs``, printed too, and the worst runs);
* ``metrics.png`` (the distributions of tracking RMS, cross-track RMS and final error) and one
  ``distribution_<metric>.png`` per metric of the table (a box plot per controller, every run a
  point).

Resume: a sweep re-run into its folder with the same arguments (the executor and ``--workers``
may differ) skips the runs whose files are there and runs the others; with other arguments it is
refused (exit 2, naming the difference). A worker process that dies loses its run only: the run
is recorded as crashed (every controller failed, with the reason), the others go on, and a
resumed sweep runs it again. Exit status: 0 when every controller ran on every seed; 1 when any
controller failed or a run crashed (each named on stderr); 2 on bad input (nothing is written);
130 on Ctrl-C, 143 on SIGTERM, 129 on SIGHUP (the workers are stopped, the finished runs' files are
kept, no summary is written, the manifest says ``interrupted``).
"""

from __future__ import annotations

import argparse
import os
import sys
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..budget import Workload, check_processes
from ..errors import ConfigError
from ..experiments.sweep.tasks import EXECUTORS
from ..experiments.sweep.vary import parse_vary
from ..outputs import output_folder
from .arguments import input_files, int_at_least, run_count
from .compare import check_controllers
from .simulate import add_run_arguments

__all__ = ["register", "run"]


def register(sub: Any) -> None:
    """Add the ``sweep`` command."""
    p = sub.add_parser(
        "sweep",
        help="a campaign: controllers on many seeded plant draws, in parallel",
        description=(
            "Run controllers (default: every registered one) on --runs plant draws (seeds seed, seed + 1, "
            "...; --vary plant.FIELD=LO:HI draws that field from U(LO, HI) instead of the preset's range; "
            "the controllers keep the nominal scenario), in parallel on a local process pool or on Dask. "
            "Writes runs/seed_<S>.json as each run finishes, then summary.json (the schema of compare "
            "--runs, plus the worst runs' seeds), summary.md, metrics.png and distribution_<metric>.png. "
            "Re-run with the same arguments, an interrupted sweep resumes and skips its finished runs. A "
            "worker that dies loses its run only (recorded as crashed; exit status 1)."
        ),
    )
    add_run_arguments(p)
    p.add_argument(
        "--runs", type=run_count, required=True, metavar="N", help="number of runs (seeds), in [1, 10000]"
    )
    p.add_argument(
        "--controllers", nargs="+", default=None, help="only these controllers (default: all available)"
    )
    p.add_argument(
        "--vary",
        type=parse_vary,
        action="append",
        default=None,
        metavar="plant.FIELD=LO:HI",
        help="draw this plant field uniformly from [LO, HI] in every run (repeatable); FIELD is a drawable "
        "field of the plant section and LO, HI lie in its allowed range (docs/config.md)",
    )
    p.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="process",
        help="process: a local process pool (default); dask: Dask distributed (a LocalCluster unless "
        "--scheduler is given)",
    )
    p.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="address of a running Dask scheduler (e.g. tcp://host:8786); only with --executor dask",
    )
    p.add_argument(
        "--workers",
        type=int_at_least(1),
        default=None,
        metavar="K",
        help="worker processes, >= 1 (default: the CPU count); not with --scheduler (the cluster has "
        "its own); at most as many as half the memory available holds, with their runs (capsule_mpc.budget)",
    )
    p.set_defaults(func=run)


def _check_executor_arguments(args: argparse.Namespace) -> None:
    if args.scheduler is not None and args.executor != "dask":
        raise ConfigError(f"--scheduler: needs --executor dask, got --executor {args.executor}")
    if args.scheduler is not None and args.workers is not None:
        raise ConfigError("--workers: not with --scheduler (the cluster's workers are its own)")


def run(args: argparse.Namespace) -> int:
    """Run the sweep; exit status 1 if a controller failed or a run crashed, 2 on bad input."""
    # lazy: the library (CasADi, Pinocchio, Dask) loads when the sweep starts, not for ``--help``
    from ..experiments.compare import RUNS_FOLDER, run_figures, summary_table
    from ..experiments.runs import prepare_run
    from ..experiments.sweep.campaign import sweep
    from ..experiments.sweep.results import check_resume, finished_runs, sweep_spec, worst_table
    from ..experiments.sweep.tasks import dask_client
    from ..experiments.sweep.vary import check_vary

    _check_executor_arguments(args)
    vary = list(args.vary or [])
    names = check_controllers(args.controllers)
    # Each local worker holds one seed's runs (every controller) at a time; the process pool starts
    # no more workers than there are runs, a Dask LocalCluster all of them; a remote cluster's
    # workers are its own (this machine then holds no run).
    workers = args.workers or os.cpu_count() or 1
    workers = 1 if args.scheduler else workers if args.executor == "dask" else min(workers, args.runs)
    check_processes(workers)
    work = replace(run_figures(names, 1), processes=workers) if not args.scheduler else Workload(runs=0)
    scenario, path, meta = prepare_run(args.config, args.waypoints, args.speed, args.plant, work)
    check_vary(scenario, vary)
    seed = scenario.sim.seed if args.seed is None else args.seed
    resume = check_resume(args.out, sweep_spec(scenario, path, seed, args.runs, names, vary))
    if resume:
        done = len(finished_runs(Path(args.out), [seed + k for k in range(args.runs)]))
        print(f"capsule-mpc sweep: resuming the sweep in {args.out}: {done} of {args.runs} runs done")
    with ExitStack() as stack:
        client = stack.enter_context(dask_client(args.scheduler, args.workers)) if args.scheduler else None
        folder = stack.enter_context(
            output_folder(
                args.out, "sweep", replace_previous=not resume, resume=resume,
                inputs=input_files(args, "--config", "--waypoints"),
            )
        )  # fmt: skip
        summary = sweep(
            scenario, path, folder.path, seed, args.runs, controllers=names, vary=vary,
            executor=args.executor, workers=args.workers, client=client, meta=meta,
            progress=not args.no_progress,
        )  # fmt: skip
        failures = _failures(summary)
        folder.status = 1 if failures else 0
    print(summary_table(summary["controllers"], args.runs), end="")
    print(worst_table(summary["worst"]), end="")
    for failure in failures:
        print(f"capsule-mpc sweep: {failure}", file=sys.stderr)
    print(
        f"results in {Path(args.out).resolve()} (summary.json, summary.md, *.png, "
        f"{RUNS_FOLDER}/seed_<S>.json)"
    )
    return folder.status


def _failures(summary: dict[str, Any]) -> list[str]:
    """What failed in a sweep: each crashed run, and each controller that failed on a seed."""
    failures = []
    for entry in summary["runs"]:
        if "crashed" in entry:
            failures.append(f"run of seed {entry['seed']} crashed: {entry['crashed']}")
            continue
        for name, result in entry["controllers"].items():
            if "error" in result:
                failures.append(f"controller {name!r} failed (seed {entry['seed']}): {result['error']}")
    return failures
