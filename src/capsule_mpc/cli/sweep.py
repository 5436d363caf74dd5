"""``capsule-mpc sweep``: a campaign, controllers on many seeded plant draws, in parallel on Dask.

What it runs, writes and resumes, and its exit status: docs/usage.md, "Campaigns" (the code:
:mod:`capsule_mpc.experiments.sweep`); this command parses the options and calls
:func:`capsule_mpc.experiments.sweep.campaign.run_sweep`."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ..experiments.sweep.vary import parse_vary
from .arguments import add_run_arguments, int_at_least, refuse_seed_overflow, run_count

__all__ = ["add_dask_arguments", "register", "run"]


def register(sub: Any) -> None:
    """Add the ``sweep`` command."""
    p = sub.add_parser(
        "sweep",
        help="a campaign: controllers on many seeded plant draws, in parallel on Dask",
        description=(
            "Run controllers (default: every registered one) on --runs plant draws (seeds seed, seed + 1, "
            "...; --vary plant.FIELD=LO:HI draws that field from U(LO, HI) instead of the preset's range; "
            "the controllers keep the nominal scenario), one Dask task per seed, on a LocalCluster of "
            "--workers processes or on the cluster at --scheduler. Writes runs/seed_<S>.json as each run "
            "finishes, then runs.csv (the run table: a row per draw and controller), summary.json (the "
            "schema of compare --runs, plus the worst runs' seeds), summary.md, metrics.png and "
            "distribution_<metric>.png. Re-run with the same arguments, an "
            "interrupted sweep resumes and skips its finished runs (not with other capsule_mpc code: "
            "its folder records the code's SHA-256). A worker that dies loses its run only "
            "(recorded as crashed; exit status 1)."
        ),
    )
    add_run_arguments(p)
    p.add_argument("--runs", type=run_count, required=True, metavar="N", help="runs (seeds), in [1, 10000]")
    p.add_argument("--controllers", nargs="+", help="only these controllers (default: all available)")
    p.add_argument(
        "--vary",
        type=parse_vary,
        action="append",
        metavar="plant.FIELD=LO:HI",
        help="draw this plant field uniformly from [LO, HI] in every run (repeatable); FIELD is a drawable "
        "field of the plant section and LO, HI lie in its allowed range (docs/config.md)",
    )
    add_dask_arguments(p)
    p.set_defaults(func=run)


def add_dask_arguments(p: argparse.ArgumentParser) -> None:
    """``--scheduler`` and ``--workers``: where a campaign's draws run."""
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="address of a running Dask scheduler (e.g. tcp://host:8786) to run on, instead of a "
        "LocalCluster on this machine; its workers need capsule_mpc installed",
    )
    p.add_argument(
        "--workers",
        type=int_at_least(1),
        metavar="K",
        help="worker processes of the LocalCluster, >= 1 (default: the CPU count; no more than --runs); "
        "not with --scheduler; at most as many as half the memory available holds (capsule_mpc.budget)",
    )


def run(args: argparse.Namespace) -> int:
    """Run the sweep; exit status 1 if a controller failed or a run crashed, 2 on bad input."""
    # lazy: the library (CasADi, Pinocchio, Dask) loads when the sweep starts, not for ``--help``
    from ..experiments.sweep.campaign import run_sweep

    overflow = refuse_seed_overflow(args.seed, args.runs, 0)
    if overflow:
        print(f"capsule-mpc sweep: {overflow}", file=sys.stderr)
        return 2
    return run_sweep(
        args.config,
        args.out,
        args.runs,
        args.controllers,
        waypoints=args.waypoints,
        speed=args.speed,
        plant=args.plant,
        seed=args.seed,
        vary=args.vary or [],
        workers=args.workers,
        scheduler=args.scheduler,
        progress=not args.no_progress,
    )
