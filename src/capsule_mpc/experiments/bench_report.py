"""The MPC benchmark's report as files and text: the JSON file, the figure of the time
distributions and the text tables (what ``capsule-mpc bench`` and ``benchmarks/mpc_bench.py`` write
and print of :func:`capsule_mpc.experiments.bench.run_benchmark`'s report)."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..atomic import write_text_atomic
from .bench import TARGETS, run_benchmark

__all__ = [
    "DEFAULT_OUT",
    "REPORT_NAME",
    "format_report",
    "out_problem",
    "plot_report",
    "report_file",
    "save_report",
    "write_report",
]

#: Default JSON output (a folder gets ``mpc_bench.json`` inside it); the figure goes beside it.
DEFAULT_OUT = "results/benchmarks/mpc_bench.json"
#: Name of the report in an output folder.
REPORT_NAME = "mpc_bench.json"


def report_file(out: str | Path) -> Path:
    """The JSON file of ``out``: itself if it ends in ``.json``, else ``mpc_bench.json`` inside it."""
    target = Path(out)
    return target if target.suffix == ".json" else target / REPORT_NAME


def out_problem(out: str) -> str | None:
    """Why ``out`` is neither a ``.json`` file nor a folder (an existing one, or a new name without an
    extension), or None. The message starts with ``out``."""
    path = Path(out)
    if path.suffix == ".json" or path.is_dir():
        return None
    if path.exists():
        return f"{out}: is not a folder; give a folder or a .json file"
    if path.suffix:
        return (
            f"{out}: must be a .json file or a folder; a new name with another extension "
            f"({path.suffix}) is neither"
        )
    return None


def save_report(report: dict[str, Any], out: str | Path) -> tuple[Path, Path]:
    """Write ``report`` as JSON (:func:`write_report`) and its figure beside it (:func:`plot_report`).

    Returns
    -------
    (Path, Path)
        The JSON file and the figure (``.png``).
    """
    written = write_report(report, out)
    return written, plot_report(report, written.with_suffix(".png"))


def write_report(report: dict[str, Any], out: str | Path) -> Path:
    """Write ``report`` as JSON to ``out`` (a ``.json`` file, or a folder: ``out/mpc_bench.json``)."""
    return write_text_atomic(report_file(out), json.dumps(report, indent=2) + "\n")


def plot_report(report: dict[str, Any], out: str | Path) -> Path:
    """The distribution of the controller-step and solve times, per variant and horizon (PNG).

    One panel per horizon; per variant a box (median, quartiles; whiskers at p1 and p99) of the
    controller step and one of the solve alone, the maximum as a cross, on a log time axis, with
    the targets of that horizon as dashed lines.
    """
    import matplotlib  # lazy: Matplotlib only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import LogLocator, ScalarFormatter

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
    """A build's time and its process's time in brackets, s; ``-`` for a build not made."""
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


def benchmark_into(
    out: str | Path,
    config: str | Path | None,
    horizons: Sequence[int],
    schemes: Sequence[str],
    frames: int | None,
    seed: int | None,
    *,
    qp_solvers: Sequence[str],
    repeats: int,
    progress: Callable[[str], None] | None,
) -> tuple[str, Path, Path]:
    """Run the benchmark (:func:`~.bench.run_benchmark`, the options checked beforehand with
    :func:`~.bench.check_bench`) and write its report and figure at ``out``
    (:func:`save_report`); returns (the tables as text, the report's path, the figure's path)."""
    report = run_benchmark(
        config, horizons, schemes, frames, seed, progress=progress, qp_solvers=qp_solvers, repeats=repeats
    )
    written, figure = save_report(report, out)
    return format_report(report), written, figure
