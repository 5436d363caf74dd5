"""``capsule-mpc demonstrate``: the ``follow`` baseline at several speeds and breakaway experiments,
all on one rig (a plant preset and the seed of its draw), written as run logs."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..budget import MAX_RUNS, check_run, speed_source
from ..config import ConfigError, Scenario, config_from_dict, load_config
from ..learning.demonstrations import (
    BREAKAWAY_DIRECTIONS,
    BREAKAWAY_PULL_M,
    BREAKAWAY_REST_S,
    BREAKAWAY_SPEED_MPS,
    DEMO_PATHS,
    BreakawayPlan,
    breakaway_path,
    demo_path,
    run_demonstrations,
)
from ..outputs import output_folder
from .arguments import input_files, positive_speed, refuse_repeats, run_count, seed
from .learn import output_problem

__all__ = [
    "DEFAULT_SPEEDS_MPS",
    "add_rig_arguments",
    "breakaway_plan",
    "check_demonstrations",
    "register",
    "rig_scenario",
    "run",
]

#: The default demonstration speeds, m/s (inside and around the paper's 0.005-0.04 m/s range).
DEFAULT_SPEEDS_MPS = (0.005, 0.01, 0.02, 0.03, 0.04)


def check_demonstrations(
    scenario: Scenario,
    speeds_mps: Sequence[float],
    path_kinds: Sequence[str],
    repeats: int = 1,
    breakaway: BreakawayPlan | None = None,
) -> None:
    """Refuse demonstrations the rig or the machine cannot run, before any of them runs.

    No speed or path kind given twice, at most :data:`capsule_mpc.budget.MAX_RUNS` runs, and each
    run within the budget's bounds (:func:`capsule_mpc.budget.check_run`, the slowest speed on
    each path kind). :func:`~capsule_mpc.learning.demonstrations.run_demonstrations` checks the
    speeds against the EPM's limit.

    Raises
    ------
    ConfigError
        Naming ``--speeds``, ``--paths``, ``--repeats`` or ``--pull-speed`` and the allowed range.
    """
    refuse_repeats("--speeds", list(speeds_mps))
    refuse_repeats("--paths", list(path_kinds))
    runs = len(speeds_mps) * len(path_kinds) * repeats
    n_break = 0 if breakaway is None else len(breakaway.rest_s) * len(breakaway.directions) * repeats
    if runs + n_break > MAX_RUNS:
        raise ConfigError(
            f"--repeats {repeats}: {len(path_kinds)} paths x {len(speeds_mps)} speeds x {repeats} repeats = "
            f"{runs} runs and {n_break} breakaway runs; at most {MAX_RUNS} in all "
            "(capsule_mpc.budget.MAX_RUNS)"
        )
    if breakaway is not None:
        limit = scenario.limits.speed_mps
        if breakaway.speed_mps > limit:
            raise ConfigError(
                f"--pull-speed: must be in (0, {limit:g}] m/s (limits.speed_mps), got {breakaway.speed_mps:g}"
            )
        for direction in breakaway.directions:
            path = breakaway_path(scenario, direction, breakaway)
            check_run(
                scenario, path.length_m, breakaway.speed_mps, f"--pull-speed {breakaway.speed_mps:g} m/s"
            )
    slowest = min(speeds_mps)
    paths = sorted(
        ((demo_path(scenario, kind, slowest), kind) for kind in path_kinds), key=lambda p: -p[0].length_m
    )
    for path, kind in paths:  # the longest first: the speed it needs suits the others
        check_run(scenario, path.length_m, slowest, f"{speed_source('--speeds', slowest)} ({kind})")


def add_rig_arguments(p: argparse.ArgumentParser, seed_default: int | None = 0) -> None:
    """Add ``--plant`` and ``--seed``: the rig every run runs on (a plant preset and its draw's seed)."""
    p.add_argument(
        "--plant",
        choices=("ideal", "lab", "hard"),
        default=None,
        help="the rig's plant preset: the simulated truth around the nominal rig (default: the config's "
        "plant.preset)",
    )
    default = "sim.seed of the config" if seed_default is None else str(seed_default)
    p.add_argument(
        "--seed",
        type=seed,
        default=seed_default,
        help=f"seed of the rig's plant draw, an integer >= 0 (default {default}); every run runs on that "
        "one draw, each with its own camera-noise seed derived from it",
    )


def rig_scenario(scenario: Scenario, plant_preset: str | None) -> Scenario:
    """``scenario`` with ``plant.preset`` set to ``plant_preset`` (unchanged for None)."""
    if plant_preset is None or plant_preset == scenario.plant.preset:
        return scenario
    data = scenario.model_dump(mode="json", exclude_none=True)
    data["plant"]["preset"] = plant_preset
    if isinstance(scenario.friction.learned, Path):  # keep a relative model file loadable
        data["friction"]["learned"] = scenario.controller_friction().model_dump(
            mode="json", exclude_none=True
        )
    out = config_from_dict(data)
    out.source_path = scenario.source_path
    return out


def breakaway_plan(args: argparse.Namespace) -> BreakawayPlan | None:
    """The breakaway experiments the options ask for; None with ``--no-breakaway``.

    Raises
    ------
    ConfigError
        Naming the option and the allowed range.
    """
    if args.no_breakaway:
        return None
    refuse_repeats("--rest-times", list(args.rest_times))
    try:
        return BreakawayPlan(
            rest_s=tuple(args.rest_times),
            speed_mps=args.pull_speed,
            pull_m=args.pull,
            directions=tuple(BREAKAWAY_DIRECTIONS),
        )
    except ValueError as exc:
        text = str(exc)
        for field, option in (
            ("rest_s", "--rest-times"),
            ("speed_mps", "--pull-speed"),
            ("pull_m", "--pull"),
        ):
            text = text.replace(f"breakaway {field}", option)
        raise ConfigError(text) from None


def add_breakaway_arguments(p: argparse.ArgumentParser) -> None:
    """Add the breakaway experiments' options."""
    g = p.add_argument_group("breakaway experiments (static friction)")
    g.add_argument("--no-breakaway", action="store_true", help="do not run the breakaway experiments")
    g.add_argument("--rest-times", type=float, nargs="+", default=list(BREAKAWAY_REST_S), metavar="T",
                   help="rest times before each pull, s, each in [0, 30] (default "
                   + " ".join(f"{t:g}" for t in BREAKAWAY_REST_S) + ")")  # fmt: skip
    g.add_argument("--pull-speed", type=positive_speed, default=BREAKAWAY_SPEED_MPS,
                   help=f"pull speed, m/s, in (0, limits.speed_mps] "
                   f"(default {BREAKAWAY_SPEED_MPS:g})")  # fmt: skip
    g.add_argument("--pull", type=float, default=BREAKAWAY_PULL_M,
                   help="pull length along x and along y, m, in (0, 0.035) "
                   f"(default {BREAKAWAY_PULL_M:g})")  # fmt: skip


def register(sub: Any) -> None:
    """Add the ``demonstrate`` command."""
    p = sub.add_parser(
        "demonstrate",
        help="record demonstrations for learn-friction: the follow baseline at several speeds, breakaways",
        description=(
            "On one rig (--plant, --seed: one plant draw), run the `follow` baseline in the simulator at "
            "each speed on straight and rectangular paths (as the paper recorded its samples), and breakaway "
            "experiments (the capsule rests T seconds under the still EPM, then the EPM is pulled slowly "
            "along x, and along y, until the capsule slides). One run folder per run (log.csv, config.yaml, "
            "run.json, demonstration.json). Finished runs with the same config, rig, path, speed and seed "
            "are reused."
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
                   help="runs per path and speed, and per breakaway (default 1); at most 10000 runs "
                   "in all")  # fmt: skip
    add_rig_arguments(p)
    p.add_argument("--no-cache", action="store_true", help="re-run even if a matching run exists")
    add_breakaway_arguments(p)
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
    inputs = input_files(args, "--config")
    try:
        plan = breakaway_plan(args)
        check_demonstrations(scenario, args.speeds, args.paths, args.repeats, plan)
    except ConfigError as exc:
        print(f"capsule-mpc demonstrate: {exc}", file=sys.stderr)
        return 2
    print(f"capsule-mpc demonstrate: on one rig: plant preset {scenario.plant.preset!r}, seed {args.seed}")
    try:
        # The folder is a cache of runs: earlier ones are kept (and reused when unchanged).
        with output_folder(args.out, "demonstrate", replace_previous=False, inputs=inputs) as folder:
            folder.status = 2  # until the runs are done: a bad value or a write error (below) is exit 2
            runs = run_demonstrations(
                scenario, args.speeds, args.out, repeats=args.repeats, seed=args.seed,
                path_kinds=args.paths, use_cache=not args.no_cache, progress=True, breakaway=plan,
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
    n_break = sum(r.experiment == "breakaway" for r in runs)
    print(
        f"{len(runs)} demonstration run(s) ({n_break} breakaway, {cached} cached), {frames} frames, in "
        f"{args.out} ({time.perf_counter() - start:.1f} s)"
    )
    for r in failed:
        print(f"  warning: {r.run_dir} failed: {r.status}; its log is usable up to the failure")
    return folder.status
