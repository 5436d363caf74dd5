"""``capsule-mpc bench``: build, start-up and closed-loop solve times of the MPC (JSON + table).

The logic is :func:`capsule_mpc.mpc.bench.run_benchmark`; ``benchmarks/mpc_bench.py`` runs the
same code. Exit status: 0 when the run finished (whether or not the targets were met), 2 on a
bad config or option.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ..atomic import write_text_atomic

__all__ = ["add_bench_arguments", "format_report", "register", "run", "write_report"]

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
    from ..mpc.bench import run_benchmark

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


def write_report(report: dict[str, Any], out: str | Path) -> Path:
    """Write ``report`` as JSON to ``out`` (a ``.json`` file, or a folder: ``out/mpc_bench.json``)."""
    target = Path(out)
    if target.suffix != ".json":
        target = target / "mpc_bench.json"
    return write_text_atomic(target, json.dumps(report, indent=2) + "\n")


def format_report(report: dict[str, Any]) -> str:
    """The report as text tables: build and start-up times, closed-loop solve times, targets."""
    mach, st = report["machine"], report["settings"]
    load = " ".join(f"{x:.2f}" for x in mach["load_average"] or [])
    lines = [
        f"MPC benchmark: {report['config']['path']}, seed {st['seed']},"
        f" path {st['path_length_m'] * 1e3:.0f} mm ({st['path_duration_s']:.1f} s);"
        f" {mach['cpu_count']} CPUs, load average at start {load}; casadi {mach['casadi']}",
        "",
        "Build / first start, fresh process, s (process incl. interpreter and imports in brackets)",
        f"{'scheme':>7s} {'N':>4s} {'vars':>5s} {'uncompiled':>17s} {'compiled, cold':>17s}"
        f" {'compiled, warm':>17s}",
    ]

    def build_cell(b: dict[str, Any] | None) -> str:
        return "-" if b is None else f"{b['build_s']:.2f} ({b['process_s']:.2f})"

    for c in report["cases"]:
        b = c["build"]
        lines.append(
            f"{c['scheme']:>7s} {c['horizon']:4d} {c['n_variables']:5d} {build_cell(b['uncompiled']):>17s}"
            f" {build_cell(b.get('compiled_cold')):>17s} {build_cell(b.get('compiled_warm')):>17s}"
        )
    lines += [
        "",
        "Closed loop, solve time per frame, ms (first = the converged IPOPT initialisation, left out of"
        " the rest; cpu: CPU time of the solver calls; std: steady frames, one warm-started step after"
        " another)",
        f"{'scheme':>7s} {'N':>4s} {'variant':>10s} {'frames':>6s} {'first':>7s} {'median':>7s} {'p99':>7s}"
        f" {'max':>7s} {'cpu med':>7s} {'cpu p99':>7s} {'std med':>7s} {'std p99':>7s}"
        f" {'>5ms':>5s} {'recov':>5s} {'fail':>4s}"
        f" {'CT RMS mm':>9s}",
    ]
    for c in report["cases"]:
        for variant, r in c["closed_loop"].items():
            s, cpu, std = r["solve"], r["solve_cpu"], r["solve_steady"]
            lines.append(
                f"{c['scheme']:>7s} {c['horizon']:4d} {variant:>10s} {r['frames']:6d}"
                f" {r['first_solve']['solve_ms']:7.1f} {s['median_ms']:7.2f} {s['p99_ms']:7.2f}"
                f" {s['max_ms']:7.1f} {cpu['median_ms']:7.2f} {cpu['p99_ms']:7.2f}"
                f" {std['median_ms']:7.2f} {std['p99_ms']:7.2f}"
                f" {r['frames_over_p99_target']:5d} {r['recoveries']:5d} {r['failures']:4d}"
                f" {r['metrics']['cross_track_rms_mm']:9.3f}"
            )
    if report["targets"]:
        tg = report["settings"]["targets"]
        lines += [
            "",
            f"Targets at N = {tg['horizon']}: median <= {tg['median_ms']} ms, p99 <= {tg['p99_ms']} ms,"
            f" second start <= {tg['warm_start_s']} s",
        ]
        for t in report["targets"]:
            text = (
                f"  {t['scheme']} {t['variant']}: median {t['median_ms']:.2f} ms"
                f" {'met' if t['median_met'] else 'MISSED'}, p99 {t['p99_ms']:.2f} ms"
                f" {'met' if t['p99_met'] else 'MISSED'}"
            )
            text += (
                f" (CPU {t['cpu_median_ms']:.2f} / {t['cpu_p99_ms']:.2f} ms; steady frames"
                f" {t['steady_median_ms']:.2f} / {t['steady_p99_ms']:.2f} ms)"
            )
            if "warm_start_met" in t:
                text += (
                    f", second start {t['warm_start_build_s']:.2f} s"
                    f" {'met' if t['warm_start_met'] else 'MISSED'}"
                )
            lines.append(text)
    end = " ".join(f"{x:.2f}" for x in mach.get("load_average_end") or [])
    lines += ["", f"load average at end {end}; total {report['total_s']:.0f} s"]
    return "\n".join(lines)
