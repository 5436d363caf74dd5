"""Argument types and checks shared by the commands (and the benchmark scripts).

Each ``type=`` function here turns a bad value into an argparse error (exit status 2, before any
work) that says what the option must be and what it got; argparse names the option.
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ..budget import MAX_RUNS
from ..experiments.inputs import refuse_repeats

if TYPE_CHECKING:
    from ..learning.demonstrations import BreakawayPlan

__all__ = [
    "MAX_SEED",
    "add_breakaway_arguments",
    "add_rig_arguments",
    "add_run_arguments",
    "input_files",
    "int_at_least",
    "out_folder",
    "positive_speed",
    "refuse_repeats",
    "refuse_seed_overflow",
    "run_count",
    "seed",
    "write_problem",
]


def input_files(args: argparse.Namespace, *options: str) -> dict[str, str | Path | None]:
    """The input files a command was given, by option (``--config``, ``--waypoints``, ...; None for
    one not given): its output folder must not hold them
    (:func:`capsule_mpc.outputs.output_folder`)."""
    return {option: getattr(args, option.removeprefix("--").replace("-", "_"), None) for option in options}


def int_at_least(minimum: int, maximum: int | None = None, bound: str | None = None) -> Callable[[str], int]:
    """An argparse ``type``: an integer >= ``minimum`` (and <= ``maximum``, the limit ``bound``
    named in the message), else an argparse error (exit 2) saying so."""
    most = "" if maximum is None else f" and <= {maximum}" + (f" ({bound})" if bound else "")

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}{most}, got {text!r}") from None
        if value < minimum or (maximum is not None and value > maximum):
            raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}{most}, got {value}")
        return value

    return parse


#: The largest seed: the rig's and controller's messages carry it as a signed 64-bit integer.
MAX_SEED = 2**63 - 1


def seed(text: str) -> int:
    """An argparse ``type``: a random seed, an integer in [0, :data:`MAX_SEED`] (NumPy seeds cannot
    be negative), else an argparse error (exit 2) saying so."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= MAX_SEED:
        shown = repr(text) if value == -1 and text.strip() != "-1" else text
        raise argparse.ArgumentTypeError(f"must be an integer in [0, 2**63 - 1], got {shown}")
    return value


def refuse_seed_overflow(first: int | None, runs: int, default: int) -> str | None:
    """Why the seeds ``first`` (``default`` when None), ``first + 1``, ... of ``runs`` runs go past
    :data:`MAX_SEED`, or None."""
    start = default if first is None else first
    if start + runs - 1 > MAX_SEED:
        return (
            f"--seed: the last run's seed {start} + {runs} - 1 is past the largest seed 2**63 - 1; give "
            f"a seed <= {MAX_SEED - runs + 1}"
        )
    return None


#: A number of runs: an integer in [1, :data:`capsule_mpc.budget.MAX_RUNS`].
run_count = int_at_least(1, MAX_RUNS, "capsule_mpc.budget.MAX_RUNS")


def positive_speed(text: str) -> float:
    """An argparse ``type``: a speed > 0 m/s, a finite number (the upper bound is the rig's)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a speed > 0 m/s, got {text!r}")
    return value


def _nearest_existing(path: Path) -> Path:
    """``path`` or its closest ancestor that exists."""
    path = path.absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def _can_create_in(folder: Path) -> bool:
    """Whether a file can be created in ``folder`` (a probe file is created and removed at once:
    permission bits say nothing for the superuser or a read-only or virtual file system)."""
    try:
        fd, name = tempfile.mkstemp(dir=folder, prefix=".capsule-mpc-probe-")
    except OSError:
        return False
    os.close(fd)
    Path(name).unlink()
    return True


def write_problem(path: Path, folder: bool) -> str | None:
    """Why ``path`` cannot be written as a file (``folder`` False) or used as an output folder
    (created if missing), or None. The message starts with the path."""
    if folder and path.exists() and not path.is_dir():
        return f"{path}: is not a folder (a file or device of that name exists)"
    if not folder and path.is_dir():
        return f"{path}: is a folder; give a file name"
    if not folder and path.exists() and not path.is_file():
        return f"{path}: is not a regular file"
    base = _nearest_existing(path if folder else path.parent)
    if not base.is_dir():
        return f"{path}: cannot be created: {base} is not a folder"
    if not _can_create_in(base):
        return f"{path}: cannot be written: no file can be created in {base}"
    return None


def out_folder(text: str) -> str:
    """An argparse ``type``: an output folder that exists or can be created, and can be written."""
    problem = write_problem(Path(text), folder=True)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text


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
        help=f"seed of the rig's plant draw, an integer in [0, 2**63 - 1] (default {default}); every run "
        "runs on that one draw, each with its own camera-noise seed derived from it",
    )


def add_breakaway_arguments(p: argparse.ArgumentParser, defaults: BreakawayPlan) -> None:
    """Add the breakaway experiments' options, with the rest times, pull speed and pull length of
    ``defaults`` as their defaults."""
    g = p.add_argument_group("breakaway experiments (static friction)")
    g.add_argument("--no-breakaway", action="store_true", help="do not run the breakaway experiments")
    g.add_argument(
        "--rest-times",
        type=float,
        nargs="+",
        default=list(defaults.rest_s),
        metavar="T",
        help="rest times before each pull, s, each in [0, 30] (default "
        + " ".join(f"{t:g}" for t in defaults.rest_s)
        + ")",
    )
    g.add_argument(
        "--pull-speed",
        type=positive_speed,
        default=defaults.speed_mps,
        help=f"pull speed, m/s, in (0, limits.speed_mps] (default {defaults.speed_mps:g})",
    )
    g.add_argument(
        "--pull",
        type=float,
        default=defaults.pull_m,
        help=f"pull length along x and along y, m, in (0, 0.035) (default {defaults.pull_m:g})",
    )
    g.add_argument(
        "--pull-preload",
        type=float,
        default=defaults.preload,
        metavar="FRACTION",
        help="move the EPM quickly to the lead where the nominal force is this fraction of the nominal "
        f"sliding friction before the slow pull, in [0, 1); 0: none (default {defaults.preload:g})",
    )


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    """The options ``simulate`` and ``compare`` share."""
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged paper.yaml)")
    p.add_argument("--out", required=True, help="output folder (created)")
    p.add_argument(
        "--seed",
        type=seed,
        default=None,
        help="random seed, an integer in [0, 2**63 - 1] (default: sim.seed of the config)",
    )
    p.add_argument(
        "--waypoints",
        default=None,
        help="CSV with header x_m,y_m replacing the config's path (at most 10000 waypoints)",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=None,
        help="nominal path speed, m/s (overrides path.speed_mps); at most what the EPM can follow on the "
        "path (0.072 m/s on the rectangle with the default limits), and at least what keeps a run "
        "within an hour of simulated time and half the memory available (capsule_mpc.budget)",
    )
    p.add_argument(
        "--plant",
        choices=("ideal", "lab", "hard"),
        default=None,
        help="plant preset: the simulated truth around the nominal rig (overrides plant.preset)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
