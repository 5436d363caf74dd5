"""``capsule-mpc bench``: build, start-up and closed-loop times of the MPC (JSON, table, figure).

The logic is :func:`capsule_mpc.experiments.bench.run_benchmark`; ``benchmarks/mpc_bench.py`` runs the
same code. Every option is checked before any work: the numbers when parsed, ``--out`` (a
``.json`` file or a folder that can be written), then the config and what the closed-loop runs
need (:func:`capsule_mpc.budget.check_run`). Exit status: 0 when the run finished (whether or
not the targets were met), 2 on a bad config or option.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import write_text_atomic
from ..config import ConfigError
from .arguments import int_at_least, run_count, seed, write_problem

__all__ = [
    "add_bench_arguments",
    "bench_out",
    "check_bench",
    "format_report",
    "plot_report",
    "register",
    "report_file",
    "run",
    "write_report",
]

#: Default JSON output (a folder gets ``mpc_bench.json`` inside it); the figure goes beside it.
DEFAULT_OUT = "results/benchmarks/mpc_bench.json"
#: Name of the report in an ``--out`` folder.
REPORT_NAME = "mpc_bench.json"
#: Horizons the benchmark accepts (as ``mpc.horizon``).
_HORIZONS = (2, 200)


def report_file(out: str | Path) -> Path:
    """The JSON file of ``--out``: itself if it ends in ``.json``, else ``mpc_bench.json`` inside it."""
    target = Path(out)
    return target if target.suffix == ".json" else target / REPORT_NAME


def bench_out(text: str) -> str:
    """An argparse ``type``: a ``.json`` file, or a folder (existing, or a new name without an
    extension), where the report and its figure can be written."""
    path = Path(text)
    if path.suffix != ".json" and not path.is_dir():
        if path.exists():
            raise argparse.ArgumentTypeError(f"{text}: is not a folder; give a folder or a .json file")
        if path.suffix:
            raise argparse.ArgumentTypeError(
                f"{text}: must be a .json file or a folder; a new name with another extension "
                f"({path.suffix}) is neither"
            )
    target = report_file(path)
    problem = write_problem(target, folder=False) or write_problem(target.with_suffix(".png"), folder=False)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return text


def add_bench_arguments(p: argparse.ArgumentParser) -> None:
    """The options ``capsule-mpc bench`` and ``benchmarks/mpc_bench.py`` share."""
    from ..experiments.bench import DEFAULT_FRAMES, DEFAULT_HORIZONS, DEFAULT_QP_SOLVERS, DEFAULT_SCHEMES
    from ..mpc.solver import QP_SOLVERS

    p.add_argument("--config", default=None, help="scenario YAML (default: packaged rectangle.yaml)")
    p.add_argument(
        "--horizons", type=int_at_least(*_HORIZONS), nargs="+", default=list(DEFAULT_HORIZONS), metavar="N",
        help=f"horizons N to measure, each in [2, 200] (default: {' '.join(map(str, DEFAULT_HORIZONS))})",
    )  # fmt: skip
    p.add_argument(
        "--schemes", nargs="+", default=list(DEFAULT_SCHEMES), choices=("rti", "sqp", "ipopt"),
        help=f"per-frame schemes (default: {' '.join(DEFAULT_SCHEMES)})",
    )  # fmt: skip
    p.add_argument(
        "--qp-solvers", nargs="+", default=list(DEFAULT_QP_SOLVERS), choices=QP_SOLVERS,
        help=f"QP solvers of the rti and sqp schemes (default: {' '.join(DEFAULT_QP_SOLVERS)})",
    )  # fmt: skip
    p.add_argument(
        "--frames", type=int_at_least(0), default=DEFAULT_FRAMES,
        help=f"camera frames of motion per closed-loop run, >= 0; 0: the whole path (default "
        f"{DEFAULT_FRAMES})",
    )  # fmt: skip
    p.add_argument(
        "--repeats", type=run_count, default=1,
        help="closed-loop runs per variant and N, in [1, 10000]; the run with the median step time is "
        "reported, the spread over the runs beside it (default 1)",
    )  # fmt: skip
    p.add_argument(
        "--seed",
        type=seed,
        default=None,
        help="random seed, an integer >= 0 (default: sim.seed of the config)",
    )
    p.add_argument(
        "--out", type=bench_out, default=DEFAULT_OUT,
        help=f"JSON file (.json), or folder for {REPORT_NAME} ({DEFAULT_OUT}); the figure (.png) goes "
        "beside it",
    )  # fmt: skip
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


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
    add_bench_arguments(p)
    p.set_defaults(func=run)


def check_bench(config: str | Path | None, horizons: list[int], frames: int | None) -> None:
    """Refuse a benchmark whose config is bad or whose closed-loop runs exceed the budget's bounds
    (:func:`capsule_mpc.budget.check_run`: one MPC run at the longest horizon at a time), before any
    work.

    Raises
    ------
    ConfigError
        A bad config, a horizon given twice, or runs beyond the bounds (naming ``path.speed_mps``).
    """
    from ..budget import Workload, check_run, speed_source
    from ..config import load_config, packaged_config_path
    from ..experiments.bench import path_first_frames
    from ..paths import path_from_scenario
    from .arguments import refuse_repeats

    refuse_repeats("--horizons", horizons)
    base = load_config(config if config is not None else packaged_config_path("rectangle"))
    longest = base.model_copy(update={"mpc": base.mpc.model_copy(update={"horizon": max(horizons)})})
    path = path_from_scenario(base)
    if frames:
        path = path_first_frames(path, frames, base.camera.rate_hz)
    check_run(
        longest, path.length_m, path.speed_mps, speed_source(None, path.speed_mps), Workload(predicting=1)
    )


def run(args: argparse.Namespace) -> int:
    """Run the benchmark, print the tables and write the JSON report and its figure."""
    from ..experiments.bench import run_benchmark

    try:
        check_bench(args.config, args.horizons, args.frames or None)
    except ConfigError as exc:
        print(f"capsule-mpc bench: {exc}", file=sys.stderr)
        return 2

    def say(msg: str) -> None:
        if not args.quiet:
            print(msg, file=sys.stderr, flush=True)

    report = run_benchmark(
        args.config, args.horizons, args.schemes, args.frames or None, args.seed, progress=say,
        qp_solvers=args.qp_solvers, repeats=args.repeats,
    )  # fmt: skip
    out = write_report(report, args.out)
    figure = plot_report(report, out.with_suffix(".png"))
    print(format_report(report))
    print(f"wrote {out}, {figure}")
    return 0


def write_report(report: dict[str, Any], out: str | Path) -> Path:
    """Write ``report`` as JSON to ``out`` (a ``.json`` file, or a folder: ``out/mpc_bench.json``)."""
    return write_text_atomic(report_file(out), json.dumps(report, indent=2) + "\n")


def plot_report(report: dict[str, Any], out: str | Path) -> Path:
    """The distribution of the controller-step and solve times, per variant and horizon (PNG).

    One panel per horizon; per variant a box (median, quartiles; whiskers at p1 and p99) of the
    controller step and one of the solve alone, the maximum as a cross, on a log time axis, with
    the targets of that horizon as dashed lines.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import LogLocator, ScalarFormatter

    from ..experiments.bench import TARGETS

    horizons = report["settings"]["horizons"]
    labels = report["settings"]["variants"]
    fig, axes = plt.subplots(1, len(horizons), figsize=(3.2 + 2.4 * len(horizons), 4.2), squeeze=False)
    for ax, horizon in zip(axes[0], horizons, strict=True):
        cases = {c["variant"]: c for c in report["cases"] if c["horizon"] == horizon}
        data, names, colours = [], [], []
        for label in labels:
            times = cases[label]["closed_loop"]["frame_times"]
            for key, colour in (("controller_ms", "tab:blue"), ("solve_ms", "tab:orange")):
                data.append(np.asarray(times[key], dtype=float))
                names.append(label if key == "controller_ms" else "")
                colours.append(colour)
        pos = np.arange(len(data), dtype=float) + np.repeat(np.arange(len(labels)) * 0.6, 2)
        boxes = ax.boxplot(data, positions=pos, whis=(1, 99), showfliers=False, patch_artist=True, widths=0.7)
        for patch, colour in zip(boxes["boxes"], colours, strict=True):
            patch.set_facecolor(colour)
            patch.set_alpha(0.6)
        ax.plot(pos, [float(np.max(d)) for d in data], "kx", ms=5, label="max")
        for key, style in (("median_ms", "-"), ("p99_ms", "--"), ("max_ms", ":")):
            if key in TARGETS.get(horizon, {}):
                limit = TARGETS[horizon][key]
                ax.axhline(limit, color="tab:red", ls=style, lw=0.8, label=f"target {key[:-3]} {limit:g} ms")
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(ScalarFormatter())
        ax.yaxis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))
        ax.yaxis.set_minor_formatter(ScalarFormatter())
        ax.set_xticks(pos[::2] + 0.5, [n for n in names if n], rotation=30, ha="right")
        ax.set_title(f"N = {horizon}")
        ax.grid(axis="y", which="both", alpha=0.3)
        ax.legend(fontsize=6, loc="upper left")
    axes[0][0].set_ylabel("time per frame, ms (blue: controller step, orange: solve)")
    mach = report["machine"]
    load = " ".join(f"{x:.1f}" for x in mach.get("load_average") or [])
    fig.suptitle(f"MPC closed loop, {mach['cpu_count']} CPUs, load average {load}", fontsize=9)
    fig.tight_layout()
    target = Path(out)
    target.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(target, dpi=120)
    plt.close(fig)
    return target


def _build_cell(b: dict[str, Any] | None) -> str:
    return "-" if b is None else f"{b['build_s']:.2f} ({b['process_s']:.2f})"


def _spread(repeats: list[dict[str, Any]], part: str, key: str) -> str:
    """``min - max`` of ``part[key]`` over the closed-loop repeats, ms."""
    values = [r[part][key] for r in repeats]
    return f"{min(values):5.2f} - {max(values):5.2f}"


def format_report(report: dict[str, Any]) -> str:
    """The report as text tables: build and start-up times, closed-loop times, targets."""
    mach, st = report["machine"], report["settings"]
    load = " ".join(f"{x:.2f}" for x in mach["load_average"] or [])
    lines = [
        f"MPC benchmark: {report['config']['path']}, seed {st['seed']},"
        f" path {st['path_length_m'] * 1e3:.0f} mm ({st['path_duration_s']:.1f} s);"
        f" {mach['cpu_count']} CPUs, load average at start {load}; casadi {mach['casadi']}",
        "",
        "Build / first start, fresh process, s (process incl. interpreter and imports in brackets)",
        f"{'variant':>11s} {'N':>4s} {'vars':>5s} {'uncompiled':>17s} {'compiled, cold':>17s}"
        f" {'compiled, warm':>17s}",
    ]
    for c in report["cases"]:
        b = c["build"]
        lines.append(
            f"{c['variant']:>11s} {c['horizon']:4d} {c['n_variables']:5d} {_build_cell(b['uncompiled']):>17s}"
            f" {_build_cell(b.get('compiled_cold')):>17s} {_build_cell(b.get('compiled_warm')):>17s}"
        )
    lines += [
        "",
        "Closed loop, per frame, ms: controller step (Python included; wall, and CPU in brackets) and the"
        " solve alone; first = the converged IPOPT initialisation, left out of the rest",
        f"{'variant':>11s} {'N':>4s} {'frames':>6s} {'first':>6s} | {'step med':>8s} {'p95':>6s} {'p99':>6s}"
        f" {'max':>6s} {'(cpu med':>8s} {'p99)':>6s} | {'solve med':>9s} {'p95':>6s} {'p99':>6s} {'max':>6s}"
        f" | {'recov':>5s} {'held':>4s} {'fail':>4s} {'ipopt':>5s} {'CT RMS mm':>9s}",
    ]
    for c in report["cases"]:
        r = c["closed_loop"]
        s, cpu, sol = r["controller_step"], r["controller_step_cpu"], r["solve"]
        lines.append(
            f"{c['variant']:>11s} {c['horizon']:4d} {r['frames']:6d} {r['first_solve']['solve_ms']:6.1f} |"
            f" {s['median_ms']:8.2f} {s['p95_ms']:6.2f} {s['p99_ms']:6.2f} {s['max_ms']:6.1f}"
            f" {cpu['median_ms']:8.2f} {cpu['p99_ms']:6.2f} | {sol['median_ms']:9.2f} {sol['p95_ms']:6.2f}"
            f" {sol['p99_ms']:6.2f} {sol['max_ms']:6.1f} | {r['recoveries']:5d} {r['held']:4d}"
            f" {r['failures']:4d} {r['ipopt_after_first']:5d} {r['metrics']['cross_track_rms_mm']:9.3f}"
        )
    if st.get("repeats", 1) > 1:
        lines += [
            "",
            f"Spread over the {st['repeats']} closed-loop runs of each case (the table above shows the run"
            " with the median step median), ms: min - max",
            f"{'variant':>11s} {'N':>4s} | {'step med':>13s} {'p99':>13s} {'max':>13s} | {'solve med':>13s}",
        ]
        for c in report["cases"]:
            reps = c["closed_loop_repeats"]
            cells = [_spread(reps, "controller_step", key) for key in ("median_ms", "p99_ms", "max_ms")]
            lines.append(
                f"{c['variant']:>11s} {c['horizon']:4d} | {' '.join(f'{x:>13s}' for x in cells)}"
                f" | {_spread(reps, 'solve', 'median_ms'):>13s}"
            )
    if report["targets"]:
        lines += ["", f"Targets (controller step; second start <= {st['warm_start_target_s']} s)"]
        for t in report["targets"]:
            parts = [
                f"{key[:-3]} {t[key]:.2f} ms {'met' if t[key.replace('_ms', '_met')] else 'MISSED'}"
                for key in ("median_ms", "p99_ms", "max_ms")
                if key in t
            ]
            text = f"  {t['variant']} N={t['horizon']}: " + ", ".join(parts)
            text += f" (CPU {t['cpu_median_ms']:.2f} / {t['cpu_p99_ms']:.2f} ms); IPOPT after the first frame"
            text += f" {t['ipopt_after_first']}"
            if "warm_start_met" in t:
                text += (
                    f"; second start {t['warm_start_build_s']:.2f} s"
                    f" {'met' if t['warm_start_met'] else 'MISSED'}"
                )
            lines.append(text)
    end = " ".join(f"{x:.2f}" for x in mach.get("load_average_end") or [])
    lines += ["", f"load average at end {end}; total {report['total_s']:.0f} s"]
    return "\n".join(lines)
