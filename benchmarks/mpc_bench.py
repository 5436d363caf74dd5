"""MPC speed: build and start-up times, and per-frame solve times in closed loop, for N = 10, 20, 40.

The same code as ``capsule-mpc bench`` (:mod:`capsule_mpc.mpc.bench`): for each horizon and
scheme, the build time uncompiled, the first start compiled with an empty cache (gcc) and with a
warm one (fresh processes), and the median / p99 / max solve time over a closed-loop run on
configs/rectangle.yaml, compiled and uncompiled. Prints tables and writes JSON with the machine
info (CPU count, load average, casadi version) and the config used.

    .venv/bin/python benchmarks/mpc_bench.py [--horizons 10 20 40] [--schemes rti ipopt]
        [--frames 300] [--out results/benchmarks/mpc_bench.json]
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
