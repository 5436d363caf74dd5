"""``capsule-mpc benchmark``: score controllers or Gymnasium policies on the task suite.

The work is :mod:`capsule_mpc.experiments.benchmark` (its docstring says what it writes). Exit
status: 0 when every entrant ran every run, 1 when an entrant raised on a run (its row holds the
error; the tables are written all the same), 2 on bad input, 130 on Ctrl-C.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..outputs import output_folder

__all__ = ["register", "run"]

#: Evaluation draws per task and preset by default.
DEFAULT_DRAWS = 20


def _draws(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer in [1, 1000], got {text!r}") from None
    if not 1 <= value <= 1000:
        raise argparse.ArgumentTypeError(f"must be an integer in [1, 1000], got {value}")
    return value


def register(sub: Any) -> None:
    """Add the ``benchmark`` command."""
    p = sub.add_parser(
        "benchmark",
        help="score controllers or Gymnasium policies on the benchmark's task suite",
        description=(
            "Run each entrant (a registered controller, --controller, or a Gymnasium policy factory, "
            "--policy module:function) on every task of the suite (rectangle, pipe at three speeds, an "
            "unseen path, placement at a target), each on lab and hard plant draws, over the evaluation "
            "seeds 5000, 5001, ... (--draws of them). Writes runs.csv (one row per run), "
            "leaderboard.csv / .json / .md (per entrant, task and preset: success rate, mean ± sd and "
            "worst of the task's score, the tracking RMS and the final error). docs/benchmark.md says "
            "how a policy is written."
        ),
        epilog="Exit status: 0 every run ran, 1 an entrant raised on a run, 2 bad input, 130 Ctrl-C.",
    )
    p.add_argument("--controller", action="append", default=[], help="a registered controller (repeatable)")
    p.add_argument(
        "--policy",
        action="append",
        default=[],
        metavar="MODULE:FUNCTION",
        help="a policy factory f(env) -> policy(observation) -> action (repeatable)",
    )
    p.add_argument(
        "--draws",
        type=_draws,
        default=DEFAULT_DRAWS,
        help=f"evaluation draws per task and preset, in [1, 1000] (default {DEFAULT_DRAWS})",
    )
    p.add_argument("--task", action="append", default=None, help="only this task (repeatable; default all)")
    p.add_argument(
        "--preset",
        action="append",
        default=None,
        choices=("lab", "hard"),
        help="only this preset (repeatable)",
    )
    p.add_argument("--out", required=True, type=Path, help="output folder")
    p.add_argument("--no-progress", action="store_true", help="do not print a line per run")
    p.set_defaults(func=run)


def source_commit() -> str | None:
    """The git commit of the package's source checkout, None if it is not one (an installed copy)."""
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(
            ["git", "-C", str(here), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        )
    except (OSError, subprocess.CalledProcessError):
        return None
    return out.stdout.strip() or None


def command_line(args: argparse.Namespace) -> str:
    """The command that reproduces the run (its options, ``--out`` aside)."""
    words = ["capsule-mpc", "benchmark"]
    words += [w for c in args.controller for w in ("--controller", c)]
    words += [w for p in args.policy for w in ("--policy", p)]
    words += [w for t in args.task or () for w in ("--task", t)]
    words += [w for p in args.preset or () for w in ("--preset", p)]
    return " ".join([*words, "--draws", str(args.draws)])


def _entrants(args: argparse.Namespace) -> list[Any]:
    from ..experiments.benchmark import Entrant
    from ..experiments.runs import check_controller

    if not args.controller and not args.policy:
        raise ConfigError("benchmark: give at least one --controller or --policy")
    for name in args.controller:
        check_controller(name)
    return [Entrant.of_controller(c) for c in args.controller] + [Entrant.of_policy(p) for p in args.policy]


def _progress_line(row: dict[str, Any]) -> str:
    what = row["error"] or f"score {row['score']:.2f}, {row['outcome']}"
    where = f"{row['entrant']} {row['task']}-{row['preset']} seed {row['seed']}"
    return f"  {where}: {what} ({row['cpu_s']:.1f} s CPU)"


def run(args: argparse.Namespace) -> int:
    """Run the benchmark into ``--out``; exit status 1 if an entrant raised on a run, 2 on bad input."""
    from ..envs.tasks import PRESETS, eval_seeds, get_task  # lazy: the library loads when work starts
    from ..experiments import benchmark as bench

    try:
        entrants = _entrants(args)
        tasks = None if args.task is None else [get_task(t).name for t in args.task]
        for entrant in entrants:
            if entrant.policy is not None:
                bench.load_policy(entrant.policy)
    except ConfigError as exc:
        print(f"capsule-mpc benchmark: {exc}", file=sys.stderr)
        return 2
    seeds = eval_seeds(args.draws)
    presets = tuple(args.preset) if args.preset else PRESETS
    show = None if args.no_progress else (lambda row: print(_progress_line(row), file=sys.stderr))
    commit = source_commit()  # the code that runs, before anything changes it
    with output_folder(args.out, "benchmark") as folder:
        rows: list[dict[str, Any]] = []
        for entrant in entrants:
            rows += bench.run_entrant(entrant, seeds, tasks=tasks, presets=presets, on_run=show)
        meta = {
            "command": command_line(args),
            "seeds": seeds,
            "draws": args.draws,
            "commit": commit,
        }
        paths = bench.write_benchmark(rows, folder.path, meta)
        errors = [r for r in rows if r.get("error")]
        folder.status = 1 if errors else 0
    print(paths["leaderboard_md"].read_text(encoding="utf-8"), end="")
    for row in errors:
        print(
            f"capsule-mpc benchmark: {row['entrant']} failed on {row['task']}-{row['preset']} seed "
            f"{row['seed']}: {row['error']}",
            file=sys.stderr,
        )
    return folder.status
