"""MPC speed: build and start-up times, and per-frame times in closed loop, for N = 10, 20, 40, 60.

The same code as ``capsule-mpc bench`` (:mod:`capsule_mpc.experiments.bench`): for each horizon and each
scheme with each QP solver, the build time uncompiled, the first start compiled with an empty
cache (gcc) and with a warm one (fresh processes), and the median / p95 / p99 / max of the
controller step (Python included) and of the solve alone over a closed-loop run on
configs/rectangle.yaml. Prints tables and writes JSON with the machine info (CPU count, load
average, casadi version) and the config used, and a figure of the time distributions beside it.

    .venv/bin/python benchmarks/mpc_bench.py [--horizons 10 20 40 60] [--schemes rti sqp ipopt]
        [--qp-solvers hpipm piqp] [--frames 300] [--repeats 1]
        [--out results/benchmarks/mpc_bench.json]
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from _args import int_at_least

from capsule_mpc.budget import MAX_RUNS
from capsule_mpc.errors import ConfigError
from capsule_mpc.experiments.bench import (
    DEFAULT_FRAMES,
    DEFAULT_HORIZONS,
    DEFAULT_QP_SOLVERS,
    DEFAULT_SCHEMES,
    check_bench,
)
from capsule_mpc.experiments.bench_report import (
    DEFAULT_OUT,
    REPORT_NAME,
    benchmark_into,
    out_problem,
    report_file,
)
from capsule_mpc.mpc.solver import QP_SOLVERS
from capsule_mpc.outputs import output_file_problem


def parser() -> argparse.ArgumentParser:
    """The options of ``capsule-mpc bench`` (whose help says more of each)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=None, help="scenario YAML (default: packaged rectangle.yaml)")
    p.add_argument(
        "--horizons",
        type=int_at_least(2, 200),
        nargs="+",
        default=list(DEFAULT_HORIZONS),
        metavar="N",
        help="horizons N to measure, each in [2, 200] (default: %(default)s)",
    )
    p.add_argument(
        "--schemes",
        nargs="+",
        default=list(DEFAULT_SCHEMES),
        choices=("rti", "sqp", "ipopt"),
        help="per-frame schemes (default: %(default)s)",
    )
    p.add_argument(
        "--qp-solvers",
        nargs="+",
        default=list(DEFAULT_QP_SOLVERS),
        choices=QP_SOLVERS,
        help="QP solvers of the rti and sqp schemes (default: %(default)s)",
    )
    p.add_argument(
        "--frames",
        type=int_at_least(0),
        default=DEFAULT_FRAMES,
        help="camera frames of motion per closed-loop run; 0: the whole path (default %(default)s)",
    )
    p.add_argument(
        "--repeats",
        type=int_at_least(1, MAX_RUNS),
        default=1,
        help="closed-loop runs per variant and N; the median one is reported (default 1)",
    )
    p.add_argument("--seed", type=int_at_least(0), default=None, help="random seed (default: sim.seed)")
    p.add_argument(
        "--out",
        default=DEFAULT_OUT,
        help=f"JSON file (.json), or folder for {REPORT_NAME} "
        "(default %(default)s); the figure (.png) goes beside it",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Check the options, run the benchmark, print its tables and write its report and figure."""
    args = parser().parse_args(argv)
    out = report_file(args.out)
    problem = out_problem(args.out) or output_file_problem(out, REPORT_NAME)
    problem = problem or output_file_problem(out.with_suffix(".png"), REPORT_NAME)
    if problem:
        print(f"mpc_bench: --out: {problem}", file=sys.stderr)
        return 2
    try:
        check_bench(args.config, args.horizons, args.frames or None)
    except ConfigError as exc:
        print(f"mpc_bench: {exc}", file=sys.stderr)
        return 2
    say = None if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    text, written, figure = benchmark_into(
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
    print(f"wrote {written}, {figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
