"""Render docs/results.md from the result JSON files in docs/results/.

Every number in docs/results.md comes from a JSON file written by a benchmark or a ``capsule-mpc``
command, copied into ``docs/results/``. ``docs/results/sources.json`` lists, per section, the file
it is rendered from and the provenance the file itself may not record (the command that wrote
it, the date, the machine, its load). Tables over plant draws are computed here from the per-draw
values, as mean ± sd (worst): the sample standard deviation (ddof 1) and the largest value. The
output depends on the JSON only, so running this twice gives the same file.

    python benchmarks/results_doc.py            # write docs/results.md
    python benchmarks/results_doc.py --check    # exit 1 if docs/results.md is not up to date
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import statistics
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "docs" / "results"
OUT = ROOT / "docs" / "results.md"
#: The manifest in the data folder: per section, its JSON file and provenance.
SOURCES = "sources.json"
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
#: Typography of the Markdown, spelled out (ruff flags these characters in literals).
DASH, TIMES, MINUS = "\u2013", "\u00d7", "\u2212"


# ------------------------------------------------------------------------------------ arithmetic
def spread(values: Sequence[float]) -> tuple[float, float, float]:
    """(mean, sample sd with ddof 1 (0 for one value), worst = largest) of ``values``."""
    if not values:
        raise ValueError("spread: no values")
    mean = statistics.fmean(values)
    sd = statistics.stdev(values) if len(values) > 1 else 0.0
    return mean, sd, max(values)


def mean_sd_worst(values: Sequence[float], digits: int = 2) -> str:
    """``mean ± sd (worst)`` of ``values``, each with ``digits`` decimals."""
    mean, sd, worst = spread(values)
    return f"{mean:.{digits}f} ± {sd:.{digits}f} ({worst:.{digits}f})"


def _num(value: Any, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return f"{value:.{digits}f}"


def _finite(values: Sequence[Any]) -> list[float]:
    return [float(v) for v in values if isinstance(v, (int, float)) and math.isfinite(float(v))]


def _cell(values: Sequence[Any], digits: int = 2) -> str:
    """mean ± sd (worst) of the finite ``values``, with how many were finite when some were not."""
    finite = _finite(values)
    if not finite:
        return "n/a"
    text = mean_sd_worst(finite, digits)
    return text if len(finite) == len(values) else f"{text} [{len(finite)}/{len(values)}]"


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
    runs = data["runs"]
    names = sorted({n for r in runs for n in r["controllers"]})
    names = [n for n in CONTROLLER_ORDER if n in names] + [n for n in names if n not in CONTROLLER_ORDER]
    n = len(runs)
    rows = []
    for name in names:
        per = [r["controllers"][name] for r in runs if name in r["controllers"]]

        def values(key: str, per: list[dict[str, Any]] = per) -> list[Any]:
            return [m.get(key) for m in per]

        finals = _finite(values("final_error_mm"))
        rows.append(
            [
                f"`{name}`",
                _cell(values("tracking_rms_mm")),
                _cell(values("cross_track_rms_mm")),
                _cell(values("final_error_mm")),
                f"{sum(f <= FINAL_TOL_MM for f in finals)}/{len(per)}",
                f"{sum(bool(m.get('stalled')) for m in per)}/{len(per)}",
                f"{sum(bool(m.get('decoupled')) for m in per)} / {sum(bool(m.get('dropped')) for m in per)}",
                _cell(values("epm_jerk_rms_mps3")),
                _cell(values("paper_std_mm")),
                f"{sum(bool(m.get('arm_ok')) for m in per)}/{len(per)}",
            ]
        )
    seeds = [r["seed"] for r in runs]
    config = data.get("config")
    config = Path(config).name if isinstance(config, str) else "?"
    varied = "".join(
        f"; plant.{f} drawn from U({lo:g}, {hi:g})" for f, (lo, hi) in data.get("vary", {}).items()
    )
    head = [
        f"{n} plant draws of `{data.get('plant_preset', '?')}` (seeds {_seeds(seeds)}){varied}; the path "
        f"of `{config}`, {data['path_length_m'] * 1e3:.0f} mm at {data['speed_mps']:g} m/s. Every controller "
        "runs on each draw, and the runs of a draw are scored on their common window.",
        "",
    ]
    return head + _table(
        [
            "controller",
            "tracking RMS (mm)",
            "cross-track RMS (mm)",
            "final error (mm)",
            f"final ≤ {FINAL_TOL_MM:g} mm",
            "stalled",
            "decoupled / dropped",
            "EPM jerk RMS (m/s³)",
            "paper's STD (mm)",
            "arm check passed",
        ],
        rows,
    )


def render_ablation(data: dict[str, Any]) -> list[str]:
    """The friction ablation (``benchmarks/friction_ablation.py``), per variant over the draws:
    mean ± sd (worst), and the paired difference to ``paper`` (mean, better on k of n)."""
    draws = data["draws"]
    n = len(draws)
    variants = [v for v in ABLATION_VARIANTS if all(v in d["runs"] for d in draws)]
    rows = []
    for v in variants:
        cells = [ABLATION_VARIANTS[v]]
        for metric in ABLATION_METRICS:
            text = _cell([d["runs"][v][metric] for d in draws])
            if v != "paper" and "paper" in variants:
                diff = [d["runs"][v][metric] - d["runs"]["paper"][metric] for d in draws]
                text += f"; {statistics.fmean(diff):+.2f} ({sum(x < 0 for x in diff)})"
            cells.append(text)
        per = [d["runs"][v] for d in draws]
        cells += [
            f"{sum(r['final_error_mm'] <= FINAL_TOL_MM for r in per)}/{n}",
            f"{sum(bool(r['stalled']) for r in per)}/{n}",
            str(int(sum(r.get("solver_failures") or 0 for r in per))),
        ]
        rows.append(cells)
    seeds = [d["seed"] for d in draws]
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
    lines = head + _table(
        [
            "friction model",
            *ABLATION_METRICS.values(),
            f"final ≤ {FINAL_TOL_MM:g} mm",
            "stalled",
            "solver failures",
        ],
        rows,
    )
    lines += _breakaway_lines(draws)
    partial = sum(bool(d.get("learning", {}).get("demonstrations_failed")) for d in draws)
    if partial:
        lines += [
            "",
            f"On {partial} draws some demonstrations failed; the model was learned from those that ran.",
        ]
    return lines


def _breakaway_lines(draws: list[dict[str, Any]]) -> list[str]:
    """The learned breakaway coefficient against the plant's at the path's start, after 2 s at rest
    and (where recorded) after the rest the draw's capsule had before its run."""
    learning = [d["learning"] for d in draws if d.get("learning")]
    learned = [x for x in learning if x.get("breakaway_mu_learned") is not None]
    if not learned:
        return []
    lines = [""]
    checks = [("after 2 s at rest", "breakaway_mu_learned", "breakaway_mu_plant")]
    if all("breakaway_mu_plant_start" in x for x in learned):
        checks.append(
            ("after the rest before the draw's run", "breakaway_mu_learned_start", "breakaway_mu_plant_start")
        )
    for when, mine, plant in checks:
        rel = [abs(x[mine] / x[plant] - 1) for x in learned]
        lines.append(
            f"Learned breakaway friction {when}, against the plant's at the path's start: within 10 % "
            f"on {sum(r <= 0.1 for r in rel)} of {len(rel)} draws; |relative error| "
            f"{mean_sd_worst([100 * r for r in rel], 1)} %."
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


def render_faults(data: dict[str, Any]) -> list[str]:
    """Solver-fault campaign (``benchmarks/fault_campaign.py``)."""
    checks = data["command_checks"]
    kinds = data["solver_faults_by_kind"]
    twin = data["recovery_vs_fault_free_s"]["all"]
    per_run = data["per_run"]
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
                [
                    "tracking RMS (mm)",
                    _cell([r["tracking_rms_mm"] for r in per_run]),
                    _cell([r["tracking_rms_mm_no_faults"] for r in per_run]),
                ],
                [
                    "final error (mm)",
                    _cell([r["final_error_mm"] for r in per_run]),
                    _cell([r["final_error_mm_no_faults"] for r in per_run]),
                ],
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


# ---------------------------------------------------------------------------------------- layout
#: Sections in the order they appear: (key in sources.json, title, renderer, what it measures).
SECTIONS: tuple[tuple[str, str, Callable[[dict[str, Any]], list[str]], str], ...] = (
    (
        "controllers_rectangle_lab",
        "Controllers on the rectangle (`lab` plant)",
        render_sweep,
        f"The 100 {TIMES} 60 mm rectangle at 0.02 m/s with the UR5 in the loop (`sim.actuator: robot`). "
        f"Tracking = |p(t) {MINUS} ref(t)| against the time-parameterised reference; cross-track = distance "
        "to the path; final = distance to the last waypoint once at rest; stalled = came to rest "
        "farther than `sim.completion_tol_m` from the end; arm check = the joint commands of the run "
        "passed the checks of an arm export (`arm_ok`).",
    ),
    (
        "controllers_pipe_0.005",
        "Controllers on the pipe at 0.005 m/s (`lab` plant)",
        render_sweep,
        "The pipe-like centreline with three bends (`configs/pipe.yaml`), the UR5 in the loop, at the "
        "slowest speed of the paper's range; metrics as above.",
    ),
    (
        "controllers_pipe_0.02",
        "Controllers on the pipe at 0.02 m/s (`lab` plant)",
        render_sweep,
        "The same pipe at the paper's operating speed.",
    ),
    (
        "controllers_pipe_0.045",
        "Controllers on the pipe at 0.045 m/s (`lab` plant)",
        render_sweep,
        "The same pipe at 0.045 m/s, where the bends ask the most of the arm.",
    ),
    (
        "controllers_rectangle_jerk10",
        "Jerk limit 10 m/s³ (rectangle, `lab`)",
        render_sweep,
        "The rectangle with the EPM jerk limit `limits.jerk_mps3` doubled from 5 to 10 m/s³ "
        "(`benchmarks/configs/rectangle_jerk10.yaml`); same draws as the rectangle's table above, so "
        "the two tables compare draw for draw.",
    ),
    (
        "controllers_rectangle_jerk20",
        "Jerk limit 20 m/s³ (rectangle, `lab`)",
        render_sweep,
        "The rectangle with the EPM jerk limit at 20 m/s³ (`benchmarks/configs/rectangle_jerk20.yaml`).",
    ),
    (
        "controllers_rectangle_arm125hz",
        "Arm at 125 Hz (rectangle, `lab`)",
        render_sweep,
        "The rectangle with the arm's setpoints streamed at 125 Hz, a CB3 UR5's RTDE rate (the default "
        "is an e-Series' 500 Hz; `benchmarks/configs/rectangle_arm125hz.yaml`).",
    ),
    (
        "controllers_rectangle_100hz",
        "Localisation at 100 Hz (rectangle, `lab`)",
        render_sweep,
        "The rectangle with the capsule measured at 100 Hz with one frame of latency, as magnetic "
        "localisation gives it (`configs/rectangle_100hz.yaml`: the MPC plans 21 stages, the first one "
        "frame long, the others 20 ms).",
    ),
    (
        "controllers_friction_step",
        "A friction step (rectangle, `lab`)",
        render_sweep,
        "The rectangle with the plate's friction 50 % higher for x ≥ 0 (a raised-cosine edge 3 mm "
        "wide), which only the plant knows: the controller must find the change from the "
        "measurements (`configs/friction_step.yaml`).",
    ),
    (
        "friction_ablation_lab",
        "What the friction model is worth (`lab`)",
        render_ablation,
        "The MPC on the same plant draws with no friction model, the paper's c(v), the model learned "
        "on each draw (demonstrations and breakaway experiments on that draw, then `learn-friction`), "
        "learned + online (`mpc.adaptation.mode: rls` with the disturbance estimator as a "
        "residual) and the plant's own friction (an oracle no real rig gives). The controller uses "
        "the finite-magnet force map (`force_model: lookup`); the arm is in the loop.",
    ),
    (
        "friction_ablation_hard",
        "What the friction model is worth (`hard`)",
        render_ablation,
        "The same ablation on the `hard` preset: wider spreads of friction, drag and its growth, and "
        "larger magnet and camera errors.",
    ),
    (
        "friction_ablation_hard100",
        "Stalls on 100 `hard` draws: the paper's c(v) against the learned model",
        render_ablation,
        "The `hard` ablation's paper and learned variants on 100 draws: the 38 draws above and 62 more "
        "(seeds 38-99) run later with the same code for these two variants, merged with "
        "`friction_ablation.py --merge`.",
    ),
    (
        "breakaway_lab",
        "The learned breakaway against the plant's (`lab`)",
        render_breakaway,
        "On each draw, `capsule-mpc demonstrate` (the follow runs and the breakaway experiments at the "
        "path's start) and `capsule-mpc learn-friction`; the learned breakaway coefficient "
        "μ_s(T) against the plant's own at the path's start, its friction field included "
        "([friction.md](friction.md)). No controller runs.",
    ),
    (
        "breakaway_hard",
        "The learned breakaway against the plant's (`hard`)",
        render_breakaway,
        "The same on the `hard` preset: larger magnet and camera errors, a friction field of 15-30 %, "
        "and rigs whose static friction is barely above their sliding friction, where the capsule "
        "creeps off rather than slips.",
    ),
    (
        "friction_options_lab",
        "Static friction in the controller beyond the approach (`lab`)",
        render_ablation,
        "The learned model with the two optional uses of its breakaway: static friction in the MPC's "
        "prediction of a resting capsule (`mpc.stick_prediction`) and the start's pre-load to 0.9 of "
        "the believed breakaway (`mpc.start_preload: 0.9`); see [friction.md](friction.md).",
    ),
    (
        "start_preload_lab",
        "The start's pre-load (`lab`)",
        render_ablation,
        "The MPC with and without the start's pre-load (`mpc.start_preload: 1`, arriving at 0.9 of the "
        "fastest speed the limits reach, `mpc.start_preload_arrival`), with the paper's c(v), whose "
        "believed breakaway is μ0 F_N + f_s, and with the model learned on the draw, whose breakaway "
        "is learned; see [friction.md](friction.md). Force map `lookup`, the arm in the loop.",
    ),
    (
        "start_preload_hard",
        "The start's pre-load (`hard`)",
        render_ablation,
        "The same on the `hard` preset.",
    ),
    (
        "start_preload_rectangle_dipole",
        "The start's pre-load with the point dipole (rectangle, `lab`)",
        render_ablation,
        "The paper's c(v) with and without the start's pre-load in the default controller "
        "(`configs/rectangle.yaml`: the point-dipole force model), the arm in the loop. The MPC's own "
        "start from rest is already closer with the dipole than with the force map (the first 1.5 s "
        "of the paper's c(v) here against the section on the `lab` pre-load, draws 0-19 of the same "
        "rigs), so the pre-load has less to gain.",
    ),
    (
        "start_preload_pipe_dipole",
        "The start's pre-load with the point dipole (pipe at 0.02 m/s, `lab`)",
        render_ablation,
        "The same on the pipe's centreline (`configs/pipe.yaml`).",
    ),
    (
        "sharp_friction_lab",
        "The learned friction held up closer to rest (`lab`)",
        render_ablation,
        "The learned model with the MPC's friction smoothed over 2 mm/s instead of 5 "
        "(`mpc.friction_smoothing_eps_mps: 0.002`): its friction force then falls off only close to "
        "rest, so the MPC keeps pushing a capsule that slows down near the end instead of expecting "
        "it to coast; see [friction.md](friction.md). Force map `lookup`, the arm in the loop.",
    ),
    (
        "sharp_friction_hard",
        "The learned friction held up closer to rest (`hard`)",
        render_ablation,
        "The same on the `hard` preset.",
    ),
    (
        "sharp_preload_lab",
        "The learned friction with the start's pre-load and held up closer to rest (`lab`)",
        render_ablation,
        "Both options with the learned model (`mpc.start_preload: 1`, "
        "`mpc.friction_smoothing_eps_mps: 0.002`) against the default controller with the paper's "
        "c(v), on the same `lab` draws as the section on the held-up friction.",
    ),
    (
        "final_stop_lab",
        "The final stop planned with the friction held up closer to rest (`lab`)",
        render_ablation,
        "The MPC's friction smoothed over 2 mm/s only once its horizon reaches the path's end "
        "(`mpc.final_friction_smoothing_eps_mps: 0.002`, a second solver; the run's solver keeps "
        "5 mm/s): the final stop is planned for a capsule that sticks rather than coasts, while the "
        "path in between keeps the smoothing the real-time steps need; see [friction.md](friction.md). "
        "With the paper's c(v) it does harm (the capsule overshoots the end: 1.6-1.9 mm past it on "
        "the five draws it harms most, traced); with the learned model it pays. Force map `lookup`, "
        "the arm in the loop.",
    ),
    (
        "final_stop_lab_new_draws",
        "The final stop and the pre-load on new `lab` draws",
        render_ablation,
        "The combination of the section above on 30 `lab` draws none of the earlier sections ran "
        "(seeds 50-79; the option's ε was chosen on draws 0-19), each with friction learned on it.",
    ),
    (
        "final_stop_hard",
        "The final stop planned with the friction held up closer to rest (`hard`)",
        render_ablation,
        "The same on the `hard` preset (the paper's c(v) without the option). Here the option ends "
        "closer on as many draws as it ends farther and stalls more: a stick-slip lurch near the end "
        "can carry the capsule past it, and it sticks there (traced on draw 39: 4.5 mm past the end, "
        "where the wider smoothing's capsule still crept and was pulled back).",
    ),
    (
        "oracle_options_lab",
        "The plant's own friction with the same options (`lab`)",
        render_ablation,
        "The learned model with the pre-load and the final stop against the plant's own friction "
        "(an oracle no real rig gives: its steady law and breakaway at the path's start) with the "
        "same two options: what a perfect friction model would add to this controller on these rigs.",
    ),
    (
        "oracle_options_hard",
        "The plant's own friction with the pre-load (`hard`)",
        render_ablation,
        "The plant's own friction, alone and with the start's pre-load, against the paper's c(v) on "
        "the `hard` preset (the final stop stays off: it does not pay on these rigs, section above). "
        "The learned model's figures on the same draws are in the section on the start's pre-load "
        "(`hard`).",
    ),
    (
        "dipole_vs_finite",
        "Point dipole against finite magnets",
        render_dipole,
        "How far the controller's default force model is from the plant's ([physics.md](physics.md)).",
    ),
    (
        "mpc_bench",
        "MPC step time",
        render_mpc_bench,
        "Build and start-up times and the per-frame step of the MPC on the rectangle. Step times "
        "depend on the machine and on what else runs on it (the load average is given); on a shared "
        "virtual machine they drift between runs of the same benchmark, so the spread of the repeats "
        "is shown beside the median run.",
    ),
    (
        "sim_speed",
        "Simulator speed",
        render_sim_speed,
        "How many times faster than real time a closed-loop run is: the 1 kHz plant with the UR5 in the "
        "loop (the default actuator), the `follow` baseline as the controller.",
    ),
    (
        "nodes_latency",
        "The loop over nodes",
        render_nodes,
        "The rig node and the controller node as two processes on this machine over Zenoh on the "
        "loopback ([nodes.md](nodes.md)): the transport's latency, and the MPC over nodes against the "
        "in-process loop on the same seeds. Wall-clock figures: they depend on the machine's load.",
    ),
    (
        "planner_bench",
        "Offline planner",
        render_planner,
        "Multiple shooting with IPOPT on the controller's model, fixed time and minimum time.",
    ),
    (
        "arm_bench",
        "Arm: Ruckig and inverse kinematics",
        render_arm,
        "Wall time and accuracy of the arm chain over 30 s of motion.",
    ),
    (
        "learning_bench",
        "Friction learning",
        render_learning,
        "Fitting time, recovery of a known c(v) from noisy samples, and c(v) learned end to end from "
        "simulated demonstrations.",
    ),
    (
        "fault_campaign",
        "Injected solver faults",
        render_faults,
        "Solver failures, NaN solutions and late solves injected into the MPC; every command sent "
        "checked against the limits from the logs.",
    ),
    (
        "hpipm_mu0",
        "HPIPM's initial barrier parameter",
        render_hpipm,
        "Interior-point iterations and accuracy of the QP at several starting barrier parameters.",
    ),
)


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


def render(data_dir: Path) -> str:
    """docs/results.md from the JSON in ``data_dir`` (its ``sources.json`` and the files it lists)."""
    sources = json.loads((data_dir / SOURCES).read_text(encoding="utf-8"))["sections"]
    unknown = set(sources) - {key for key, *_ in SECTIONS}
    if unknown:
        raise ValueError(f"{SOURCES}: sections without a renderer: {sorted(unknown)}")
    out = [
        "# Results (simulated rig)",
        "",
        f"<!-- Generated by `{COMMAND}` from docs/results/*.json; do not edit by hand. -->",
        "",
        f"This file is generated by `{COMMAND}` from the JSON files in `docs/results/`; edit those "
        "(or the script), not this file. Every section gives the command that wrote its data, the "
        "date, the machine and the load it ran under. Tables over plant draws give mean ± sd (worst): "
        "the sample standard deviation and the worst draw. The runs are deterministic for a seed; only "
        "wall-clock figures (step and solve times, real-time factors) depend on the machine and its "
        "load. The physics behind the simulated rig is in [physics.md](physics.md).",
        "",
    ]
    present = [s for s in SECTIONS if s[0] in sources]
    out += [f"- [{title}](#{_anchor(title)})" for _, title, _, _ in present]
    for key, title, renderer, what in present:
        entry = sources[key]
        data = json.loads((data_dir / entry["file"]).read_text(encoding="utf-8"))
        out += ["", f"## {title}", "", what, "", *renderer(data), "", *_provenance(entry, data, data_dir)]
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
