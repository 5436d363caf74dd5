"""``capsule-mpc bench``: build, start-up and closed-loop times of the MPC (JSON, table, figure).

The benchmark is :func:`capsule_mpc.experiments.bench.run_benchmark`, its report's files and tables
:mod:`capsule_mpc.experiments.bench_report`. Every option is checked before any work: the numbers
when parsed, ``--out`` (a ``.json`` file or a folder that can be written), then the config and what
the closed-loop runs need (:func:`capsule_mpc.experiments.bench.check_bench`). Exit status: 0 when
the run finished (whether or not the targets were met), 2 on a bad config or option.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ..config import ConfigError
from ..experiments import bench, bench_report
from ..experiments.bench import DEFAULT_FRAMES, DEFAULT_HORIZONS, DEFAULT_QP_SOLVERS, DEFAULT_SCHEMES
from ..experiments.bench_report import DEFAULT_OUT, REPORT_NAME
from ..mpc.solver import QP_SOLVERS
from ..overwrite import refuse_overwrite
from .arguments import int_at_least, run_count, seed, write_problem

__all__ = ["bench_out", "register", "run"]


def bench_out(text: str) -> str:
    """An argparse ``type``: a ``.json`` file, or a folder (existing, or a new name without an
    extension), where the report and its figure can be written."""
    target = bench_report.report_file(text)
    problem = bench_report.out_problem(text) or write_problem(target, folder=False)
    problem = problem or write_problem(target.with_suffix(".png"), folder=False)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text


def register(sub: Any) -> None:
    """Add the ``bench`` command."""
    p = sub.add_parser(
        "bench",
        help="benchmark the MPC: build and start-up times, closed-loop controller and solve times",
        description=(
            "For each horizon N and each scheme with each QP solver: build time uncompiled, first start "
            "compiled with an empty cache (gcc) and with a warm cache (fresh processes); per-frame "
            "controller-step time (Python included) and solve time (median, p95, p99, max), recoveries "
            "and failures of a closed-loop run. Prints tables, writes JSON and a figure of the time "
            "distributions."
        ),
    )
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged rectangle.yaml)")
    p.add_argument(
        "--horizons",
        type=int_at_least(2, 200),
        nargs="+",
        default=list(DEFAULT_HORIZONS),
        metavar="N",
        help=f"horizons N to measure, each in [2, 200] (default: {' '.join(map(str, DEFAULT_HORIZONS))})",
    )
    p.add_argument(
        "--schemes",
        nargs="+",
        default=list(DEFAULT_SCHEMES),
        choices=("rti", "sqp", "ipopt"),
        help=f"per-frame schemes (default: {' '.join(DEFAULT_SCHEMES)})",
    )
    p.add_argument(
        "--qp-solvers",
        nargs="+",
        default=list(DEFAULT_QP_SOLVERS),
        choices=QP_SOLVERS,
        help=f"QP solvers of the rti and sqp schemes (default: {' '.join(DEFAULT_QP_SOLVERS)})",
    )
    p.add_argument(
        "--frames",
        type=int_at_least(0),
        default=DEFAULT_FRAMES,
        help="camera frames of motion "
        f"per closed-loop run, >= 0; 0: the whole path (default {DEFAULT_FRAMES})",
    )
    p.add_argument(
        "--repeats",
        type=run_count,
        default=1,
        help="closed-loop runs per variant and N, in "
        "[1, 10000]; the run with the median step time is reported, the spread over the runs "
        "beside it (default 1)",
    )
    p.add_argument(
        "--seed",
        type=seed,
        default=None,
        help="random seed, an integer in [0, 2**63 - 1] (default: sim.seed of the config)",
    )
    p.add_argument(
        "--out",
        type=bench_out,
        default=DEFAULT_OUT,
        help=f"JSON file (.json), or folder for "
        f"{REPORT_NAME} ({DEFAULT_OUT}); the figure (.png) goes beside it",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the benchmark, print the tables and write the JSON report and its figure."""
    try:
        is_folder = not str(args.out).endswith(".json")
        refuse_overwrite({"--out": (args.out, is_folder)}, {"--config": args.config})
        bench.check_bench(args.config, args.horizons, args.frames or None)
    except ConfigError as exc:
        print(f"capsule-mpc bench: {exc}", file=sys.stderr)
        return 2
    say = None if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    text, out, figure = bench_report.benchmark_into(
        args.out,
        args.config,
        args.horizons,
        args.schemes,
        args.frames or None,
        args.seed,
        qp_solvers=args.qp_solvers,
        repeats=args.repeats,
        progress=say,
    )
    print(text)
    print(f"wrote {out}, {figure}")
    return 0
