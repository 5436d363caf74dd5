"""``capsule-mpc demonstrate``: the ``follow`` baseline at several speeds and breakaway experiments,
all on one rig (a plant preset and the seed of its draw), written as run logs
(:mod:`capsule_mpc.experiments.demonstrate`)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from ..config import load_config
from ..experiments.demonstrate import (
    DEFAULT_SPEEDS_MPS,
    breakaway_plan,
    check_demonstrations,
    record_demonstrations,
    report_lines,
    rig_scenario,
)
from ..experiments.inputs import output_problem
from ..learning.demonstrations import DEMO_PATHS, BreakawayPlan
from .arguments import add_breakaway_arguments, add_rig_arguments, input_files, positive_speed, run_count

__all__ = ["register", "run"]


def register(sub: Any) -> None:
    """Add the ``demonstrate`` command."""
    p = sub.add_parser(
        "demonstrate",
        help="record demonstrations for learn-friction: the follow baseline at several speeds, breakaways",
        description=(
            "On one rig (--plant, --seed: one plant draw), run the `follow` baseline in the simulator at "
            "each speed on straight and rectangular paths (as the paper recorded its samples), and breakaway "
            "experiments at the start of the path (the capsule rests T seconds under the still EPM, then the "
            "EPM is pulled along x, and along y, quickly to a pre-load and then slowly until the capsule "
            "slides). One run folder per run (log.csv, config.yaml, run.json, demonstration.json). "
            "Finished runs with the same config, rig, path, speed and seed are reused."
        ),
    )
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    p.add_argument(
        "--speeds",
        type=positive_speed,
        nargs="+",
        default=list(DEFAULT_SPEEDS_MPS),
        help="arm speeds, m/s, each in (0, limits.speed_mps] and fast enough for a run within an "
        "hour of simulated time (default 0.005 0.01 0.02 0.03 0.04)",
    )
    p.add_argument(
        "--paths",
        nargs="+",
        choices=DEMO_PATHS,
        default=list(DEMO_PATHS),
        help="demonstration paths (default: all)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the run folders")
    p.add_argument(
        "--repeats",
        type=run_count,
        default=1,
        help="runs per path and speed, and per breakaway (default 1); at most 10000 runs in all",
    )
    add_rig_arguments(p)
    p.add_argument("--no-cache", action="store_true", help="re-run even if a matching run exists")
    add_breakaway_arguments(p, BreakawayPlan())
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the demonstrations; exit status 1 if a run decoupled or dropped the capsule, 2 on bad input.

    Each run folder is complete or absent (its files are written atomically); a write error
    stops the command with exit 2, leaving the runs finished before it.
    """
    start = time.perf_counter()
    scenario = rig_scenario(load_config(args.config), args.plant)
    problem = output_problem("--out", Path(args.out), folder=True)
    if problem:
        print(f"capsule-mpc demonstrate: {problem}", file=sys.stderr)
        return 2
    try:  # a bad value or an output folder refused is exit 2 (an OutputError is a ConfigError)
        plan = (
            None
            if args.no_breakaway
            else breakaway_plan(args.rest_times, args.pull_speed, args.pull, args.pull_preload)
        )
        check_demonstrations(scenario, args.speeds, args.paths, args.repeats, plan)
        print(
            f"capsule-mpc demonstrate: on one rig: plant preset {scenario.plant.preset!r}, seed {args.seed}"
        )
        runs, status = record_demonstrations(
            scenario,
            args.speeds,
            args.out,
            repeats=args.repeats,
            seed=args.seed,
            path_kinds=args.paths,
            use_cache=not args.no_cache,
            breakaway=plan,
            inputs=input_files(args, "--config"),
        )
    except ValueError as exc:
        print(f"capsule-mpc demonstrate: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(
            f"capsule-mpc demonstrate: cannot write {exc.filename or args.out}: {exc.strerror or exc}",
            file=sys.stderr,
        )
        return 2
    print("\n".join(report_lines(runs, args.out, time.perf_counter() - start)))
    return status
