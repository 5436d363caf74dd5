"""``capsule-mpc demonstrate``: run the ``follow`` baseline at several speeds and write the run logs."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

from ..config import load_config
from ..learning.demonstrations import DEMO_PATHS, run_demonstrations
from ..outputs import output_folder
from .arguments import input_files
from .learn import output_problem

__all__ = ["register", "run"]

#: The issue's default demonstration speeds, m/s (inside and around the paper's 0.005-0.04 m/s range).
DEFAULT_SPEEDS_MPS = (0.005, 0.01, 0.02, 0.03, 0.04)


def _speed(text: str) -> float:
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a speed > 0 m/s, got {text}")
    return value


def _count(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text}")
    return value


def _seed(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text}")
    return value


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
    p.add_argument("--speeds", type=_speed, nargs="+", default=list(DEFAULT_SPEEDS_MPS),
                   help="arm speeds, m/s (default 0.005 0.01 0.02 0.03 0.04)")  # fmt: skip
    p.add_argument("--paths", nargs="+", choices=DEMO_PATHS, default=list(DEMO_PATHS),
                   help="demonstration paths (default: all)")  # fmt: skip
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the run folders")
    p.add_argument("--repeats", type=_count, default=1, help="runs per path and speed (default 1)")
    p.add_argument("--seed", type=_seed, default=0, help="base seed (default 0)")
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
