"""``capsule-mpc demonstrate``: run the ``follow`` baseline at several speeds and write the run logs."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..budget import MAX_RUNS, check_run, speed_source
from ..config import ConfigError, Scenario, load_config
from ..learning.demonstrations import DEMO_PATHS, demo_path, run_demonstrations
from ..outputs import output_folder
from .arguments import input_files, positive_speed, refuse_repeats, run_count, seed
from .learn import output_problem

__all__ = ["DEFAULT_SPEEDS_MPS", "check_demonstrations", "register", "run"]

#: The default demonstration speeds, m/s (inside and around the paper's 0.005-0.04 m/s range).
DEFAULT_SPEEDS_MPS = (0.005, 0.01, 0.02, 0.03, 0.04)


def check_demonstrations(
    scenario: Scenario, speeds_mps: Sequence[float], path_kinds: Sequence[str], repeats: int = 1
) -> None:
    """Refuse demonstrations the rig or the machine cannot run, before any of them runs.

    No speed or path kind given twice, at most :data:`capsule_mpc.budget.MAX_RUNS` runs, and each
    run within the budget's bounds (:func:`capsule_mpc.budget.check_run`, the slowest speed on
    each path kind). :func:`~capsule_mpc.learning.demonstrations.run_demonstrations` checks the
    speeds against the EPM's limit.

    Raises
    ------
    ConfigError
        Naming ``--speeds``, ``--paths`` or ``--repeats`` and the allowed range.
    """
    refuse_repeats("--speeds", list(speeds_mps))
    refuse_repeats("--paths", list(path_kinds))
    runs = len(speeds_mps) * len(path_kinds) * repeats
    if runs > MAX_RUNS:
        raise ConfigError(
            f"--repeats {repeats}: {len(path_kinds)} paths x {len(speeds_mps)} speeds x {repeats} repeats = "
            f"{runs} runs; at most {MAX_RUNS} (capsule_mpc.budget.MAX_RUNS)"
        )
    slowest = min(speeds_mps)
    paths = sorted(
        ((demo_path(scenario, kind, slowest), kind) for kind in path_kinds), key=lambda p: -p[0].length_m
    )
    for path, kind in paths:  # the longest first: the speed it needs suits the others
        check_run(scenario, path.length_m, slowest, f"{speed_source('--speeds', slowest)} ({kind})")


def register(sub: Any) -> None:
    """Add the ``demonstrate`` command."""
    p = sub.add_parser(
        "demonstrate",
        help="record demonstrations for learn-friction: the follow baseline at several speeds",
        description=(
            "Run the `follow` baseline in the simulator at each speed on straight and rectangular paths "
            "(as the paper recorded its samples) and write one run folder per run (log.csv, config.yaml, "
            "run.json). Finished runs with the same config, path, speed and seed are reused."
        ),
    )
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    p.add_argument("--speeds", type=positive_speed, nargs="+", default=list(DEFAULT_SPEEDS_MPS),
                   help="arm speeds, m/s, each in (0, limits.speed_mps] and fast enough for a run within an "
                   "hour of simulated time (default 0.005 0.01 0.02 0.03 0.04)")  # fmt: skip
    p.add_argument("--paths", nargs="+", choices=DEMO_PATHS, default=list(DEMO_PATHS),
                   help="demonstration paths (default: all)")  # fmt: skip
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the run folders")
    p.add_argument("--repeats", type=run_count, default=1,
                   help="runs per path and speed (default 1); at most 10000 runs in all")  # fmt: skip
    p.add_argument("--seed", type=seed, default=0, help="base seed, an integer >= 0 (default 0)")
    p.add_argument("--no-cache", action="store_true", help="re-run even if a matching run exists")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the demonstrations; exit status 1 if a run decoupled or dropped the capsule, 2 on bad input.

    Each run folder is complete or absent (its files are written atomically); a write error
    stops the command with exit 2, leaving the runs finished before it.
    """
    start = time.perf_counter()
    scenario = load_config(args.config)
    problem = output_problem("--out", Path(args.out), folder=True)
    if problem:
        print(f"capsule-mpc demonstrate: {problem}", file=sys.stderr)
        return 2
    inputs = input_files(args, "--config")
    try:
        check_demonstrations(scenario, args.speeds, args.paths, args.repeats)
    except ConfigError as exc:
        print(f"capsule-mpc demonstrate: {exc}", file=sys.stderr)
        return 2
    try:
        # The folder is a cache of runs: earlier ones are kept (and reused when unchanged).
        with output_folder(args.out, "demonstrate", replace_previous=False, inputs=inputs) as folder:
            folder.status = 2  # until the runs are done: a bad value or a write error (below) is exit 2
            runs = run_demonstrations(
                scenario, args.speeds, args.out, repeats=args.repeats, seed=args.seed,
                path_kinds=args.paths, use_cache=not args.no_cache, progress=True,
            )  # fmt: skip
            failed = [r for r in runs if r.status in ("decoupled", "dropped")]
            folder.status = 1 if failed else 0
    except ValueError as exc:
        print(f"capsule-mpc demonstrate: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"capsule-mpc demonstrate: cannot write {exc.filename or args.out}: {exc.strerror or exc}",
              file=sys.stderr)  # fmt: skip
        return 2
    frames = sum(r.n_frames for r in runs)
    cached = sum(r.cached for r in runs)
    print(
        f"{len(runs)} demonstration run(s) ({cached} cached), {frames} frames, in {args.out} "
        f"({time.perf_counter() - start:.1f} s)"
    )
    for r in failed:
        print(f"  warning: {r.run_dir} failed: {r.status}; its log is usable up to the failure")
    return folder.status
