"""``capsule-mpc bench``: build, start-up and closed-loop solve times of the MPC (JSON + table).

The logic is :func:`capsule_mpc.mpc.bench.run_benchmark`; ``benchmarks/mpc_bench.py`` runs the
same code. Exit status: 0 when the run finished (whether or not the targets were met), 2 on a
bad config or option.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

__all__ = ["add_bench_arguments", "register", "run"]

#: Default JSON output (a folder gets ``mpc_bench.json`` inside it).
DEFAULT_OUT = "results/benchmarks/mpc_bench.json"


def add_bench_arguments(p: argparse.ArgumentParser) -> None:
    """The options ``capsule-mpc bench`` and ``benchmarks/mpc_bench.py`` share."""
    from ..mpc.bench import DEFAULT_FRAMES, DEFAULT_HORIZONS, DEFAULT_SCHEMES

    p.add_argument("--config", default=None, help="scenario YAML (default: packaged rectangle.yaml)")
    p.add_argument(
        "--horizons", type=int, nargs="+", default=list(DEFAULT_HORIZONS), metavar="N",
        help=f"horizons N to measure (default: {' '.join(map(str, DEFAULT_HORIZONS))})",
    )  # fmt: skip
    p.add_argument(
        "--schemes", nargs="+", default=list(DEFAULT_SCHEMES), choices=("rti", "sqp", "ipopt"),
        help=f"per-frame schemes (default: {' '.join(DEFAULT_SCHEMES)})",
    )  # fmt: skip
    p.add_argument(
        "--frames", type=int, default=DEFAULT_FRAMES,
        help=f"camera frames of motion per closed-loop run; 0: the whole path (default {DEFAULT_FRAMES})",
    )  # fmt: skip
    p.add_argument("--seed", type=int, default=None, help="random seed (default: sim.seed of the config)")
    p.add_argument(
        "--out", default=DEFAULT_OUT, help=f"JSON file, or folder for mpc_bench.json ({DEFAULT_OUT})"
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def register(sub: Any) -> None:
    """Add the ``bench`` command."""
    p = sub.add_parser(
        "bench",
        help="benchmark the MPC: build and start-up times, closed-loop solve times",
        description=(
            "For each horizon N and scheme: build time uncompiled, first start compiled with an empty "
            "cache (gcc) and with a warm cache (fresh processes); per-frame solve times (median, p99, "
            "max, failures) of a closed-loop run, compiled and uncompiled. Prints tables and writes JSON."
        ),
    )
    add_bench_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the benchmark, print the tables and write the JSON report."""
    from ..mpc.bench import format_report, run_benchmark, write_report

    if args.frames < 0:
        print(f"capsule-mpc bench: --frames must be >= 0, got {args.frames}", file=sys.stderr)
        return 2
    bad = [n for n in args.horizons if not 2 <= n <= 200]
    if bad:
        print(f"capsule-mpc bench: --horizons must each be in [2, 200], got {bad}", file=sys.stderr)
        return 2

    def say(msg: str) -> None:
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    report = run_benchmark(
        args.config, args.horizons, args.schemes, args.frames or None, args.seed, progress=say
    )
    out = write_report(report, args.out)
    print(format_report(report))
    print(f"wrote {out}")
    return 0
