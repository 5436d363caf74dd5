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

from capsule_mpc.cli.bench import add_bench_arguments, run


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_bench_arguments(parser)
    return run(parser.parse_args())


if __name__ == "__main__":
    sys.exit(main())
