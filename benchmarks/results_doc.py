"""Render docs/results.md from the result files in docs/results/ and its template.

Every number in docs/results.md comes from a file written by a benchmark or a ``capsule-mpc``
command, copied into ``docs/results/``. ``docs/results/sources.json`` lists, per section, the file
it is rendered from and the provenance the file itself may not record (the command that wrote
it, the date, the machine, its load); ``docs/results/sections.md`` holds the prose: each section's
title, renderer and text. A campaign's data (a sweep's ``summary.json`` or ``runs.csv``, a friction
ablation's or fault campaign's report) is read as a run table (:mod:`capsule_mpc.experiments.table`)
and summarised by :func:`capsule_mpc.experiments.aggregate.aggregate` (mean ± sd (worst): the sample
standard deviation, ddof 1, and the largest value) and :func:`~capsule_mpc.experiments.aggregate.paired`.
The output depends on the files only, so running this twice gives the same file.

    python benchmarks/results_doc.py            # write docs/results.md
    python benchmarks/results_doc.py --check    # exit 1 if docs/results.md is not up to date
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from capsule_mpc.experiments.aggregate import aggregate, mean_sd_worst, paired
from capsule_mpc.experiments.table import run_label, table_from_entries

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "docs" / "results"
OUT = ROOT / "docs" / "results.md"
#: The manifest in the data folder: per section, its data file and provenance.
SOURCES = "sources.json"
#: The template in the data folder: the prose and the sections in order.
TEMPLATE = "sections.md"
COMMAND = "python benchmarks/results_doc.py"

#: Controllers of the comparison, in table order (others follow alphabetically).
CONTROLLER_ORDER = ("follow", "paper_0.8v", "plan", "mpc")
#: Friction-model variants of the ablation, in table order, with their labels.
ABLATION_VARIANTS = {
    "none": "none (μ = 0, no drag)",
    "paper": "paper's c(v)",
    "paper+preload": "paper's c(v), pre-load at the start",
    "learned": "learned on the draw",
    "online": "learned + online",
    "oracle": "oracle (the plant's own)",
    "learned+stick": "learned, static friction in the prediction",
    "learned+preload": "learned, pre-load at the start",
    "learned+sharp": "learned, friction smoothed over 2 mm/s",
    "learned+preload+sharp": "learned, pre-load, friction smoothed over 2 mm/s",
    "paper+endsharp": "paper's c(v), final stop with friction smoothed over 2 mm/s",
    "learned+endsharp": "learned, final stop with friction smoothed over 2 mm/s",
    "learned+preload+endsharp": "learned, pre-load, final stop with friction smoothed over 2 mm/s",
    "oracle+preload": "oracle, pre-load at the start",
    "oracle+preload+endsharp": "oracle, pre-load, final stop with friction smoothed over 2 mm/s",
}
ABLATION_METRICS = {
    "tracking_rms_mm": "tracking RMS (mm)",
    "cross_track_rms_mm": "cross-track RMS (mm)",
    "start_tracking_rms_mm": "first 1.5 s (mm)",
    "final_error_mm": "final error (mm)",
}
#: Final error counted as reached, mm (the benchmarks' default tolerance).
FINAL_TOL_MM = 0.5
#: The ablation's controller, and the baseline of its paired differences.
ABLATION_CONTROLLER, BASELINE = "mpc", "paper"
#: Typography of the Markdown, spelled out (ruff flags these characters in literals).
DASH, TIMES, MINUS = "\u2013", "\u00d7", "\u2212"


# ------------------------------------------------------------------------------------ run tables
def sweep_table(data: dict[str, Any]) -> pd.DataFrame:
    """The run table of a sweep's ``summary.json``."""
    return table_from_entries(data["runs"])


def ablation_table(data: dict[str, Any]) -> pd.DataFrame:
    """The run table of a friction ablation's report: its variants run by the MPC, ``paper_0.8v``
    on the paper's variant, each draw's learning as ``learning.*``."""
    entries = []
    for draw in data["draws"]:
        runs = {
            run_label(BASELINE, name) if name == "paper_0.8v" else run_label(name, ABLATION_CONTROLLER): run
            for name, run in draw["runs"].items()
        }
        entries.append({**draw, "controllers": runs, "runs": None})
    return table_from_entries(entries)


def _cell(stats: pd.Series, metric: str, total: int, digits: int = 2) -> str:
    """mean ± sd (worst) of a metric's finite values, with how many were finite when some were not."""
    n = int(stats[(metric, "n")]) if (metric, "n") in stats else 0
    if not n:
        return "n/a"
    text = mean_sd_worst(stats[(metric, "mean")], stats[(metric, "sd")], stats[(metric, "worst")], digits)
    return text if n == total else f"{text} [{n}/{total}]"


def _count(stats: pd.Series, flag: str) -> int:
    return int(stats[(flag, "count")]) if (flag, "count") in stats and stats[(flag, "n")] else 0


def _with_final_flag(table: pd.DataFrame) -> pd.DataFrame:
    table = table.copy()
    table["final_within_tol"] = (table["final_error_mm"] <= FINAL_TOL_MM).astype("boolean")
    return table


def _num(value: Any, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return f"{value:.{digits}f}"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


def _seeds(seeds: Sequence[int]) -> str:
    """``0-19`` (en dash) for a contiguous run of seeds, else the list."""
    s = sorted(seeds)
    if s and s == list(range(s[0], s[-1] + 1)):
        return f"{s[0]}{DASH}{s[-1]}" if len(s) > 1 else str(s[0])
    return ", ".join(map(str, s))


# ------------------------------------------------------------------------------------- sections
def render_sweep(data: dict[str, Any]) -> list[str]:
    """The controller comparison of a ``capsule-mpc sweep`` (its ``summary.json``), per controller
    over the runs: mean ± sd (worst)."""
    table = _with_final_flag(sweep_table(data))
    stats = aggregate(table, by=["controller"])
    present = list(stats.index)
    others = sorted(n for n in present if n not in CONTROLLER_ORDER)
    names = [n for n in CONTROLLER_ORDER if n in present] + others
    rows = []
    for name in names:
        st = stats.loc[name]
        total = int(st[("runs", "n")] + st[("failed", "n")])
        rows.append(
            [
                f"`{name}`",
                *(_cell(st, m, total) for m in ("tracking_rms_mm", "cross_track_rms_mm", "final_error_mm")),
                f"{_count(st, 'final_within_tol')}/{total}",
                f"{_count(st, 'stalled')}/{total}",
                f"{_count(st, 'decoupled')} / {_count(st, 'dropped')}",
                _cell(st, "epm_jerk_rms_mps3", total),
                _cell(st, "paper_std_mm", total),
                f"{_count(st, 'arm_ok')}/{total}",
            ]
        )
    seeds = [r["seed"] for r in data["runs"]]
    config = data.get("config")
    config = Path(config).name if isinstance(config, str) else "?"
    varied = "".join(
        f"; plant.{f} drawn from U({lo:g}, {hi:g})" for f, (lo, hi) in data.get("vary", {}).items()
    )
    head = [
        f"{len(seeds)} plant draws of `{data.get('plant_preset', '?')}` (seeds {_seeds(seeds)}){varied}; the "
        f"path of `{config}`, {data['path_length_m'] * 1e3:.0f} mm at {data['speed_mps']:g} m/s. Every "
        "controller runs on each draw, and the runs of a draw are scored on their common window.",
        "",
    ]
    header = ["controller", "tracking RMS (mm)", "cross-track RMS (mm)", "final error (mm)"]
    header += [f"final ≤ {FINAL_TOL_MM:g} mm", "stalled", "decoupled / dropped", "EPM jerk RMS (m/s³)"]
    return head + _table([*header, "paper's STD (mm)", "arm check passed"], rows)


#: Targets of the placement, as the camera sees it (mm): ``lab`` and ``hard`` draws.
PLACED_SEEN_MM = {"lab": 0.2, "hard": 0.3}
#: The truth may miss the target by the camera's bias plus this, mm.
PLACED_TRUTH_MARGIN_MM = 0.2
#: First motion within this multiple of the draw's arm-limited bound counts as prompt.
START_BOUND_FACTOR = 1.3


def _placement_row(name: str, runs: pd.DataFrame, seen_mm: float) -> list[str]:
    """One controller's (or variant's) placement figures over its runs."""
    n = len(runs)
    seen = runs["final_error_seen_mm"].astype(float)
    truth_ok = (
        runs["final_error_mm"].astype(float) <= runs["camera_bias_mm"].astype(float) + PLACED_TRUTH_MARGIN_MM
    )
    ttp = runs["time_to_place_s"].astype(float)
    moves = runs["placement_moves"].astype(float)
    ratio = (
        runs["first_motion_ratio"].astype(float) if "first_motion_ratio" in runs else pd.Series(dtype=float)
    )
    gave_up = (runs["end_phase"].astype(str) == "failed").sum() if "end_phase" in runs else 0
    stalled = runs["stalled"].astype(bool).sum() if "stalled" in runs else 0
    return [
        f"`{name}`",
        f"{seen.mean():.3f} ± {seen.std(ddof=1) if n > 1 else 0:.3f} ({seen.max():.3f})",
        f"{int((seen <= seen_mm).sum())}/{n}",
        f"{int(truth_ok.sum())}/{n}",
        f"{runs['camera_bias_mm'].astype(float).mean():.2f}",
        f"{ttp.median():.1f} / {ttp.quantile(0.95):.1f} ({ttp.max():.1f})",
        f"{moves.mean():.2f} ({int(moves.max())})",
        f"{int(stalled)} / {int(gave_up)}",
        f"{int((ratio <= START_BOUND_FACTOR).sum())}/{int(ratio.notna().sum())}" if len(ratio) else "n/a",
    ]


def render_placement(data: dict[str, Any]) -> list[str]:
    """The placement at the path's end of a ``capsule-mpc sweep`` (its ``summary.json``), per
    controller: as the camera sees it (the truth plus the draw's bias), the truth against the bias,
    the time to place from the path's nominal end (median / 95th percentile (worst)), the moves, and
    the start's first motion against the draw's arm-limited bound."""
    table = sweep_table(data)
    preset = data.get("plant_preset", "lab")
    seen_mm = PLACED_SEEN_MM.get(preset, 0.2)
    rows = [_placement_row(str(name), runs, seen_mm) for name, runs in table.groupby("controller")]
    seeds = [r["seed"] for r in data["runs"]]
    head = [
        f"{len(seeds)} plant draws of `{preset}` (seeds {_seeds(seeds)}), the UR5 in the loop.",
        "",
    ]
    header = [
        "controller",
        "final, as seen (mm)",
        f"seen ≤ {seen_mm:g} mm",
        f"truth ≤ bias + {PLACED_TRUTH_MARGIN_MM:g} mm",
        "mean camera bias (mm)",
        "time to place (s): median / p95 (worst)",
        "moves: mean (max)",
        "stalled / gave up",
        f"first motion ≤ {START_BOUND_FACTOR:g}x bound",
    ]
    return head + _table(header, rows)


def render_ablation(data: dict[str, Any]) -> list[str]:
    """The friction ablation (``benchmarks/friction_ablation.py``), per variant over the draws:
    mean ± sd (worst), and the paired difference to ``paper`` (mean, better on k of n)."""
    table = _with_final_flag(ablation_table(data))
    table = table[table["controller"] == ABLATION_CONTROLLER]
    n = int(table["seed"].nunique())
    stats = aggregate(table, by=["variant"])
    variants = [v for v in ABLATION_VARIANTS if v in stats.index and stats.loc[v, ("runs", "n")] == n]
    diffs = paired(table, {"variant": BASELINE}, list(ABLATION_METRICS), by=["variant"])
    rows = []
    for v in variants:
        cells = [ABLATION_VARIANTS[v]]
        for metric in ABLATION_METRICS:
            text = _cell(stats.loc[v], metric, n)
            if v != BASELINE and BASELINE in variants:
                d = diffs.loc[v]
                text += f"; {d[(metric, 'mean')]:+.2f} ({int(d[(metric, 'better')])})"
            cells.append(text)
        failures = stats.loc[v, ("solver_failures", "sum")] if ("solver_failures", "sum") in stats else 0
        cells += [f"{_count(stats.loc[v], 'final_within_tol')}/{n}", f"{_count(stats.loc[v], 'stalled')}/{n}"]
        rows.append([*cells, str(int(failures))])
    seeds = [d["seed"] for d in data["draws"]]
    started = data.get("seeds", seeds)
    failed = data.get("draws_failed", [])
    head = [
        f"{n} draws of `{data['plant']}` (seeds {_seeds(seeds)})"
        + (f" of the {len(started)} started" if len(started) != n else "")
        + (f"; {len(failed)} draws failed (seeds {_seeds([f['seed'] for f in failed])})" if failed else "")
        + f", config `{data['config']}`. Each cell: mean ± sd (worst) over the draws; after the "
        "semicolon, the paired difference to the paper's c(v): mean (better on k draws).",
        "",
    ]
    header = ["friction model", *ABLATION_METRICS.values(), f"final ≤ {FINAL_TOL_MM:g} mm", "stalled"]
    lines = head + _table([*header, "solver failures"], rows) + _breakaway_lines(data["draws"])
    partial = sum(bool(d.get("learning", {}).get("demonstrations_failed")) for d in data["draws"])
    if partial:
        what = "some demonstrations failed; the model was learned from those that ran."
        lines += ["", f"On {partial} draws {what}"]
    return lines


#: A placement counts as quick within this time from the path's nominal end, s.
QUICK_PLACE_S = 2.0


def render_placement_ablation(data: dict[str, Any]) -> list[str]:
    """The friction ablation with the placement (``benchmarks/friction_ablation.py``), per variant
    over the draws: the placement's moves (paired difference to ``paper``: mean, fewer on k), the
    time to place, how many were placed within :data:`QUICK_PLACE_S`, the final error as the camera
    sees it, stalls."""
    table = ablation_table(data)
    table = table[table["controller"] == ABLATION_CONTROLLER]
    n = int(table["seed"].nunique())
    stats = aggregate(table, by=["variant"])
    variants = [v for v in ABLATION_VARIANTS if v in stats.index and stats.loc[v, ("runs", "n")] == n]
    diffs = paired(table, {"variant": BASELINE}, ["placement_moves"], by=["variant"])
    rows = []
    for v in variants:
        runs = table[table["variant"] == v]
        moves = _cell(stats.loc[v], "placement_moves", n)
        if v != BASELINE and BASELINE in variants:
            d = diffs.loc[v]
            moves += (
                f"; {d[('placement_moves', 'mean')]:+.2f} (fewer on {int(d[('placement_moves', 'better')])})"
            )
        ttp = runs["time_to_place_s"].astype(float)
        rows.append(
            [
                ABLATION_VARIANTS[v],
                moves,
                f"{ttp.median():.1f}",
                f"{int((ttp <= QUICK_PLACE_S).sum())}/{n}",
                _cell(stats.loc[v], "final_error_seen_mm", n, 3),
                f"{_count(stats.loc[v], 'stalled')}/{n}",
            ]
        )
    seeds = [d["seed"] for d in data["draws"]]
    head = [
        f"{n} draws of `{data['plant']}` (seeds {_seeds(seeds)}), config `{data['config']}`, every "
        "default (the start's pre-load, the placement). Each cell: mean ± sd (worst) over the draws.",
        "",
    ]
    header = ["friction model", "placement moves", "time to place, median (s)"]
    header += [f"placed within {QUICK_PLACE_S:g} s", "final, as seen (mm)", "stalled"]
    return head + _table(header, rows)


def _breakaway_lines(draws: list[dict[str, Any]]) -> list[str]:
    """The learned breakaway coefficient against the plant's at the path's start, after 2 s at rest
    and (where recorded) after the rest the draw's capsule had before its run."""
    learning = pd.DataFrame([d["learning"] for d in draws if d.get("learning")])
    if "breakaway_mu_learned" not in learning or learning["breakaway_mu_learned"].isna().all():
        return []
    learned = learning[learning["breakaway_mu_learned"].notna()].copy()
    lines = [""]
    checks = [("after 2 s at rest", "breakaway_mu_learned", "breakaway_mu_plant")]
    if "breakaway_mu_plant_start" in learned and learned["breakaway_mu_plant_start"].notna().all():
        checks.append(
            ("after the rest before the draw's run", "breakaway_mu_learned_start", "breakaway_mu_plant_start")
        )
    for when, mine, plant in checks:
        errors = pd.DataFrame({"check": when, "error_pct": 100 * (learned[mine] / learned[plant] - 1).abs()})
        errors["within"] = (errors["error_pct"] <= 10).astype("boolean")
        st = aggregate(errors, by=["check"]).loc[when]
        text = mean_sd_worst(*(st[("error_pct", k)] for k in ("mean", "sd", "worst")), 1)
        lines.append(
            f"Learned breakaway friction {when}, against the plant's at the path's start: within 10 % "
            f"on {_count(st, 'within')} of {len(errors)} draws; |relative error| {text} %."
        )
    if len(learned) < len(learning):
        lines.append(f"No static friction was learned on {len(learning) - len(learned)} draws.")
    return lines


def render_breakaway(data: dict[str, Any]) -> list[str]:
    """The learned breakaway on each draw (``friction_ablation.py --learn-only``)."""
    draws = data["draws"]
    seeds = [d["seed"] for d in draws]
    lines = [f"{len(draws)} draws of `{data['plant']}` (seeds {_seeds(seeds)}), config `{data['config']}`."]
    return lines + _breakaway_lines(draws)


def render_dipole(data: dict[str, Any]) -> list[str]:
    """Point dipole against finite magnets (``benchmarks/dipole_vs_finite.py``)."""
    att, lat = data["rig_attraction_error_pct"], data["rig_lateral_error_n"]
    rig = data["rig"]
    heights = sorted({r["height_m"] for r in rig})
    offsets = sorted({abs(r["offset_from_equilibrium_m"]) for r in rig})
    lines = [
        f"The rig (4-block Halbach EPM, hollow IPM) at heights {heights[0] * 1e3:.0f}{DASH}"
        f"{heights[-1] * 1e3:.0f} mm "
        f"and leads up to ±{offsets[-1] * 1e3:.0f} mm from the rest lead along x and y ({len(rig)} points): "
        f"the dipole model overestimates the attraction toward the EPM by {att['min']:+.0f} … "
        f"{att['max']:+.0f} % (median {att['median']:+.0f} %); its lateral force is off by up to "
        f"{lat['max']:.2f} N (median {lat['median']:.2f} N).",
        "",
    ]
    rows = [
        [
            f"{c['distance_m'] * 1e3:.0f}",
            f"{c['finite_fz_n']:.3f}",
            f"{c['dipole_fz_n']:.3f}",
            f"{c['overestimate_pct']:+.0f}",
        ]
        for c in data["single_block_coaxial"]
    ]
    return lines + _table(
        [
            f"one 80 {TIMES} 60 {TIMES} 50 mm block, IPM on its axis at (mm)",
            "finite F_z (N)",
            "dipole F_z (N)",
            "dipole over (%)",
        ],
        rows,
    )


def render_mpc_bench(data: dict[str, Any]) -> list[str]:
    """MPC timing (``capsule-mpc bench`` / ``benchmarks/mpc_bench.py``)."""
    s = data["settings"]
    frames = "the whole path" if not s.get("frames") else f"the first {s['frames']} frames of motion"
    repeats = s.get("repeats", 1)
    lines = [
        f"Closed loop on {frames} (plant seed {s['seed']}), {repeats} run{'s' if repeats != 1 else ''} "
        "per case; the run with the median controller step is shown, and the range of the runs' "
        "medians. Controller step = the whole Python step (estimator, reference, solve, safety "
        "layer), wall clock, and the CPU time of the process, which a loaded machine inflates less; "
        "ms. Load average at "
        f"the start {_load(data['machine'].get('load_average'))}, at the end "
        f"{_load(data['machine'].get('load_average_end'))}.",
        "",
    ]
    rows = []
    for case in data["cases"]:
        loop = case["closed_loop"]
        step = loop["controller_step"]
        cpu = loop["controller_step_cpu"]
        medians = [r["controller_step"]["median_ms"] for r in case.get("closed_loop_repeats", [])]
        build = case["build"]
        rows.append(
            [
                case["variant"],
                str(case["horizon"]),
                f"{step['median_ms']:.2f} / {step['p99_ms']:.2f} / {step['max_ms']:.2f}",
                f"{cpu['median_ms']:.2f} / {cpu['p99_ms']:.2f}",
                f"{min(medians):.2f}{DASH}{max(medians):.2f}" if medians else "n/a",
                f"{loop['solve']['median_ms']:.2f}",
                str(loop["frames"]),
                f"{loop['recoveries']} / {loop['failures']} / {loop['ipopt_after_first']}",
                str(loop["deadline_misses"]),
                _num(build.get("compiled_cold", {}).get("build_s"), 1),
                _num(build.get("compiled_warm", {}).get("build_s"), 2),
            ]
        )
    return lines + _table(
        [
            "variant",
            "N",
            "step median / p99 / max (ms)",
            "step CPU time median / p99 (ms)",
            "medians of the runs (ms)",
            "solve median (ms)",
            "frames",
            "recoveries / failures / IPOPT after the first frame",
            "deadline misses",
            "first start, empty cache (s)",
            "second start (s)",
        ],
        rows,
    )


def _load(values: Sequence[float] | None) -> str:
    return "not recorded" if not values else " / ".join(f"{v:.2f}" for v in values)


def render_sim_speed(data: dict[str, Any]) -> list[str]:
    """Simulator speed (``benchmarks/sim_speed.py``)."""
    prof = data["per_step_profile_us"]
    walls = data["wall_time_s"]
    return [
        f"`{data['controller']}` on `{data['scenario']}`: {data['sim_time_s']:.1f} s simulated "
        f"({data['plant_steps']} plant steps at {data['plant_rate_hz']:.0f} Hz, camera at "
        f"{data['camera_rate_hz']:.0f} Hz), {len(walls)} runs of {min(walls):.1f}{DASH}{max(walls):.1f} s "
        f"wall clock: {data['realtime_factor_median']:.1f}{TIMES} real time (median; best "
        f"{data['realtime_factor_best']:.1f}{TIMES}). Per plant step: the force map "
        f"{prof['force_us']:.1f} µs, "
        f"the simplified arm {prof['arm_step_us']:.1f} µs, arm and plant together "
        f"{prof['arm_plus_plant_step_us']:.1f} µs.",
    ]


def render_planner(data: dict[str, Any]) -> list[str]:
    """Offline planner (``benchmarks/planner_bench.py``)."""
    rows = []
    for c in data["cases"]:
        con = c["constraints"]
        rows.append(
            [
                f"`{c['config']}`",
                c["variant"],
                c["status"],
                str(c["iterations"]),
                f"{c['build_s']:.1f}",
                f"{c['solve_s']:.1f}",
                f"{c['duration_s']:.2f} ({c['duration_over_nominal']:.2f}{TIMES})",
                f"{con['cross_track_max_m'] * 1e3:.2f}",
                f"{c['residual']['scaled']:.1e}",
            ]
        )
    return _table(
        [
            "config",
            "variant",
            "IPOPT status",
            "iterations",
            "build (s)",
            "solve (s)",
            f"plan duration, s ({TIMES} nominal)",
            "cross-track max (mm)",
            "dynamics residual (scaled)",
        ],
        rows,
    )


def render_arm(data: dict[str, Any]) -> list[str]:
    """Ruckig + inverse kinematics (``benchmarks/arm_bench.py``)."""
    rows = []
    for case in ("plan", "online"):
        r = data[case]
        rows.append(
            [
                case,
                str(r["n_setpoints"]),
                f"{r['wall_s_median']:.2f} ({r['wall_s_best']:.2f})",
                f"{r['us_per_setpoint']:.0f}",
                f"{r['max_ik_position_error_m']:.1e}",
                f"{r['jerk_over_limit']:.3f}",
                f"{r['velocity_over_limit']:.3f}",
                f"{r['acceleration_over_limit']:.3f}",
                f"{r['newton_steps_per_point']:.2f}",
            ]
        )
    online = data["online"]
    return [
        *_table(
            [
                "case",
                "setpoints",
                "wall median (best), s",
                "µs per setpoint",
                "worst IK error (m)",
                "jerk / limit",
                "velocity / limit",
                "acceleration / limit",
                "Newton steps per point",
            ],
            rows,
        ),
        "",
        f"{data['duration_s']:.0f} s of motion at {data['arm_rate_hz']:.0f} Hz. `plan`: a plan through "
        "Ruckig and IK, as `capsule-mpc arm-export` does; `online`: the simulator's robot actuator, "
        f"one Ruckig update and one IK solve per arm tick, {online['real_time_factor']:.1f}{TIMES} real "
        "time.",
    ]


def render_learning(data: dict[str, Any]) -> list[str]:
    """Friction learning (``benchmarks/learning_bench.py``)."""
    ft = data["fit_time"]
    lines = _table(
        ["fit of the paper's sample count", "min (ms)", "median (ms)"],
        [
            [name.replace("_", " "), f"{ft[name]['min_s'] * 1e3:.1f}", f"{ft[name]['median_s'] * 1e3:.1f}"]
            for name in ("least_squares", "huber", "csv_read_and_fit")
        ],
    )
    lines[0] = lines[0].replace("fit of the paper's sample count", f"fit of {ft['n_samples']} samples")
    rec = data["recovery"]
    lines += ["", "Recovery of the paper's c(v) from synthetic samples with traction noise:", ""]
    lines += _table(
        [
            "noise (mN)",
            "worst \\|Δc\\| (mean over seeds)",
            "worst \\|Δc\\| (worst seed)",
            "relative to min c",
        ],
        [
            [
                f"{r['traction_noise_n'] * 1e3:g}",
                f"{r['max_c_error_mean']:.2e}",
                f"{r['max_c_error_worst']:.2e}",
                f"{100 * r['max_c_error_rel_to_c_min']:.2f} %",
            ]
            for r in rec["noise"]
        ],
    )
    o = rec["outliers_5pct"]
    lines += [
        "",
        f"With 5 % gross outliers: worst |Δc| {o['least_squares_max_c_error']:.2e} by least squares, "
        f"{o['huber_max_c_error']:.2e} with the Huber loss.",
    ]
    e2e = data.get("end_to_end")
    if e2e:
        speeds = list(e2e["plant_c_at"])
        rows = [[f"plant (a {MINUS} b form)", *(f"{e2e['plant_c_at'][v]:.4f}" for v in speeds), "n/a", "n/a"]]
        rows.append(["paper's polynomial", *(f"{e2e['paper_c_at'][v]:.4f}" for v in speeds), "n/a", "n/a"])
        for name, f in e2e["fits"].items():
            rows.append(
                [
                    f"learned: {name.replace('_', ' ')}",
                    *(f"{f['c_at'][v]:.4f}" for v in speeds),
                    str(f["n_samples"]),
                    f"{f['rmse']:.4f}",
                ]
            )
        lines += [
            "",
            f"End to end: {e2e['n_runs']} `follow` demonstrations ({e2e['n_frames']} frames), c(v) learned "
            "from the camera (and from the true positions) with each force model:",
            "",
        ]
        lines += _table(["c at v (m/s)", *speeds, "samples", "RMSE"], rows)
    demos = data.get("demonstrations")
    if demos:
        statuses = ", ".join(f"{v} {k}" for k, v in sorted(demos["statuses"].items()))
        lines += ["", f"The demonstrations: {demos['runs']} runs ({statuses})."]
    held = data.get("held_out")
    if held:
        models = list(held["rows"][0]["error_mm"])
        lines += [
            "",
            f"Held out: c(v) fitted on {', '.join(map(str, held['train_speeds_mps']))} m/s, the steady "
            f"EPM{MINUS}capsule lead predicted at {', '.join(map(str, held['held_out_speeds_mps']))} m/s "
            "on the straight runs; |error| against the simulator, mm:",
            "",
        ]
        lines += _table(
            ["run", *(m.replace("_", " ") for m in models)],
            [
                [f"{r['path']} {r['speed_mps']:g} m/s", *(f"{r['error_mm'][m]:.2f}" for m in models)]
                for r in held["rows"]
            ],
        )
    return lines


def fault_table(data: dict[str, Any]) -> pd.DataFrame:
    """The run table of a fault campaign's report: each seed with and without faults."""
    rows = []
    for run in data["per_run"]:
        for variant, suffix in (("faults", ""), ("no faults", "_no_faults")):
            metrics = {m: run[m + suffix] for m in ("tracking_rms_mm", "final_error_mm")}
            rows.append({"seed": run["seed"], "variant": variant, "controller": "mpc", **metrics})
    return pd.DataFrame(rows)


def render_faults(data: dict[str, Any]) -> list[str]:
    """Solver-fault campaign (``benchmarks/fault_campaign.py``)."""
    checks = data["command_checks"]
    kinds = data["solver_faults_by_kind"]
    twin = data["recovery_vs_fault_free_s"]["all"]
    stats = aggregate(fault_table(data), by=["variant"])
    n = len(data["per_run"])
    return [
        f"{data['solver_faults_injected']} solver faults injected ("
        + ", ".join(f"{v} {k.replace('solver_', '').replace('_', ' ')}" for k, v in kinds.items())
        + f"; probability {data['fault_probability_per_frame']:g} per frame each) over {data['runs']} "
        f"`{data['scenario']}` runs of the MPC, deadline enforced.",
        "",
        *_table(
            ["check over every command", "count"],
            [[k.replace("_", " "), str(v)] for k, v in checks.items()]
            + [["decoupled runs", str(data["decoupled_runs"])], ["dropped runs", str(data["dropped_runs"])]],
        ),
        "",
        *_table(
            ["", "with faults", "same seeds without faults"],
            [
                [label, _cell(stats.loc["faults"], m, n), _cell(stats.loc["no faults"], m, n)]
                for label, m in (
                    ("tracking RMS (mm)", "tracking_rms_mm"),
                    ("final error (mm)", "final_error_mm"),
                )
            ],
        ),
        "",
        "Time lost against the fault-free run of the same seed (until the tracking error is back within "
        "0.5 mm of it, or below 1 mm): " + _distribution(twin) + ".",
    ]


def _distribution(d: dict[str, Any]) -> str:
    keys = [("median", "median"), ("p99", "p99"), ("max", "worst")]
    present = [(label, d[k]) for k, label in keys if d.get(k) is not None]
    if not present:
        return "no recovery measured"
    return ", ".join(f"{label} {value:.2f} s" for label, value in present) + f" over {d.get('n', '?')} faults"


def _span(values: list[float], spec: str) -> str:
    """The range of ``values`` (least, a dash, greatest), each formatted with ``spec``."""
    return f"{min(values):{spec}}{DASH}{max(values):{spec}}"


def render_hpipm(data: dict[str, Any]) -> list[str]:
    """HPIPM's initial barrier parameter (``benchmarks/hpipm_mu0.py``)."""
    cases = data["cases"]
    mu0s = [r["mu0"] for r in cases[0]["results"]]
    frames = sum(c["frames"] for c in cases)
    rows = []
    for i, mu0 in enumerate(mu0s):
        res = [c["results"][i] for c in cases]
        total = data["totals"][str(mu0)] if str(mu0) in data["totals"] else None
        rows.append(
            [
                f"{mu0:g}" + (" (default)" if mu0 == data["hpipm_options"].get("mu0") else ""),
                _span([r["iterations_mean"] for r in res], ".1f"),
                f"{sum(r['not_solved'] for r in res)} of {frames}",
                f"{max(r['first_command_error_max_mmps'] for r in res):.2g}",
                _span([r["qp_ms_median"] for r in res], ".2f"),
            ]
        )
        if total is not None and total["not_solved"] != sum(r["not_solved"] for r in res):
            raise ValueError(f"hpipm_mu0: totals of mu0 {mu0} disagree with its cases")
    return [
        f"{frames} QPs recorded in closed loop ({len(cases)} cases: "
        + ", ".join(c["case"] for c in cases)
        + f"; plant seed {data['seed']}), each re-solved at every mu0 and against a tight reference solve.",
        "",
        *_table(
            [
                "mu0",
                "iterations per QP (mean, range over cases)",
                "QPs not solved",
                "first command's worst error (mm/s)",
                "QP median (ms, range over cases)",
            ],
            rows,
        ),
    ]


def _node_rows(rows: Sequence[dict[str, Any]]) -> list[list[str]]:
    out = []
    for r in rows:
        nodes, local = r["nodes"], r["in_process"]
        out.append(
            [
                str(r["seed"]),
                str(nodes["node_deadline_misses_motion"]),
                _num(nodes["tracking_rms_mm"], 3),
                str(local["deadline_misses_motion"]),
                _num(local["tracking_rms_mm"], 3),
                f"{100 * r['tracking_rms_rel_diff']:.1f} %",
            ]
        )
    return out


def _zenoh_alone(base: dict[str, Any] | None) -> str:
    if not base:
        return ""
    return (
        f" For reference, a bare Zenoh ping to an echoing process, paced the same way, at the same "
        f"time: median {base['round_trip_ms_median']:.2f} ms, p99 {base['round_trip_ms_p99']:.2f} ms."
    )


def render_nodes(data: dict[str, Any]) -> list[str]:
    """The loop over nodes (``benchmarks/nodes_latency.py``)."""
    lat = data["latency_follow_ideal"]
    header = [
        "seed",
        "nodes: misses in motion",
        "nodes: tracking RMS (mm)",
        "in process: misses in motion",
        "in process: tracking RMS (mm)",
        "RMS difference",
    ]
    lines = [
        f"Transport latency from frame to command (`follow` on the `ideal` rectangle, {lat['frames']} "
        f"frames; the round trip less the controller's step): median "
        f"{lat['node_transport_ms_median']:.2f} ms, p99 {lat['node_transport_ms_p99']:.2f} ms, max "
        f"{lat['node_transport_ms_max']:.2f} ms. The whole round trip, the step included: median "
        f"{lat['node_round_trip_ms_median']:.2f} ms, p99 {lat['node_round_trip_ms_p99']:.2f} ms."
        + _zenoh_alone(data.get("zenoh_round_trip")),
        "",
        "The MPC on `lab` draws of the rectangle at 30 Hz, over nodes and in process (real time, same "
        "seed). A miss over nodes is a frame whose command had not come by its deadline (the rig held "
        "the previous command); in process, a command ready after its slot (applied all the same).",
        "",
        *_table(header, _node_rows(data["mpc_30hz_lab"])),
    ]
    if data.get("mpc_100hz_lab"):
        lines += [
            "",
            "The same at 100 Hz (`configs/rectangle_100hz.yaml`):",
            "",
            *_table(header, _node_rows(data["mpc_100hz_lab"])),
        ]
    return lines


def _provenance(entry: dict[str, Any], data: dict[str, Any], data_dir: Path) -> list[str]:
    """The command, date, machine and load of a section's data.

    The command and date come from the ``manifest.json`` a ``capsule-mpc`` command left beside its
    output when ``entry`` names one (``manifest``), else from the data file when it records its
    command line, else from ``entry``; two sources that disagree are an error.
    """
    command = data.get("command") if isinstance(data.get("command"), str) and " " in data["command"] else None
    date = entry.get("date")
    if entry.get("manifest"):
        manifest = json.loads((data_dir / entry["manifest"]).read_text(encoding="utf-8"))
        if manifest.get("status") != "complete":
            raise ValueError(f"{entry['manifest']}: the command did not complete ({manifest.get('status')})")
        command = "capsule-mpc " + " ".join(shlex.quote(a) for a in manifest["argv"])
        date = f"{manifest['started']} to {manifest['finished']}"
    if entry.get("command"):
        if command and entry["command"] != command:
            raise ValueError(f"{entry['file']}: sources.json and the data disagree on the command")
        command = entry["command"]
    if not command or not date:
        raise ValueError(f"{entry['file']}: no command or no date recorded")
    lines = [f"- command: `{command}`", f"- date: {date}", f"- machine: {entry['machine']}"]
    if entry.get("load"):
        lines.append(f"- load average (1, 5, 15 min): {entry['load']}")
    if entry.get("note"):
        lines.append(f"- note: {entry['note']}")
    for label, key in (("data", "file"), ("manifest", "manifest")):
        if entry.get(key):
            lines.append(f"- {label}: [`docs/results/{entry[key]}`](results/{entry[key]})")
    return lines


#: The renderers a section of the template names.
RENDERERS: dict[str, Callable[[dict[str, Any]], list[str]]] = {
    name.removeprefix("render_"): fn for name, fn in globals().items() if name.startswith("render_")
}


def read_template(data_dir: Path) -> tuple[str, list[tuple[str, str, str, str]]]:
    """The template's opening text and its sections: (key, renderer, title, text)."""
    text = (data_dir / TEMPLATE).read_text(encoding="utf-8")
    text = text[text.index("-->") + 3 :] if text.startswith("<!--") else text
    opening, *blocks = text.split("\n## ")
    sections = []
    for block in blocks:
        heading, _, prose = block.partition("\n")
        key, renderer, title = (part.strip() for part in heading.split("|", 2))
        if renderer not in RENDERERS:
            known = sorted(RENDERERS)
            raise ValueError(f"{TEMPLATE}: section {key}: no renderer {renderer!r}; one of {known}")
        sections.append((key, renderer, title, prose.strip()))
    return opening.strip(), sections


def render(data_dir: Path) -> str:
    """docs/results.md from the files in ``data_dir`` (its ``sources.json``, template and data)."""
    sources = json.loads((data_dir / SOURCES).read_text(encoding="utf-8"))["sections"]
    opening, sections = read_template(data_dir)
    unknown = set(sources) - {key for key, *_ in sections}
    if unknown:
        raise ValueError(f"{SOURCES}: sections without a renderer: {sorted(unknown)}")
    out = [
        "# Results (simulated rig)",
        "",
        f"<!-- Generated by `{COMMAND}` from docs/results/*.json; do not edit by hand. -->",
        "",
        opening,
        "",
    ]
    present = [s for s in sections if s[0] in sources]
    out += [f"- [{title}](#{_anchor(title)})" for _, _, title, _ in present]
    for key, renderer, title, what in present:
        entry = sources[key]
        data = json.loads((data_dir / entry["file"]).read_text(encoding="utf-8"))
        rendered = RENDERERS[renderer](data)
        out += ["", f"## {title}", "", what, "", *rendered, "", *_provenance(entry, data, data_dir)]
    return "\n".join(out) + "\n"


def _anchor(title: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    kept = "".join(c for c in title.lower() if c.isalnum() or c in " -_")
    return kept.replace(" ", "-")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA, help="folder of the JSON and sources.json")
    parser.add_argument("--out", type=Path, default=OUT, help="the Markdown file to write")
    parser.add_argument("--check", action="store_true", help="write nothing; exit 1 if --out is stale")
    args = parser.parse_args(argv)
    text = render(args.data)
    if args.check:
        current = args.out.read_text(encoding="utf-8") if args.out.exists() else ""
        if current != text:
            print(f"{args.out} is not up to date: run `{COMMAND}`", file=sys.stderr)
            return 1
        return 0
    args.out.write_text(text, encoding="utf-8")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
