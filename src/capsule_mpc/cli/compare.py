"""``capsule-mpc compare``: every available controller on the same plant, path and seed.

Writes, into ``--out``: one run folder per controller (``log.csv``, ``config.yaml``,
``run.json``; ``predictions.npz`` for the MPC), ``summary.json``, ``summary.md`` (a
table) and the figures ``trajectories.png`` (paper Fig. 7a), ``errors.png`` (Fig. 8),
``metrics.png`` and, when an ``mpc`` run is present, ``mpc_prediction.png`` (its
predicted vs actual capsule path at the first corner).

Solver figures per controller (from the run log; NaN / ``n/a`` for controllers that
report no solve): ``solve_ms_median``, ``solve_ms_p99``, ``solve_ms_max``,
``solver_failures`` (steps the controller reported as failed), ``deadline_misses``
(solves longer than the camera frame period, settle phase included) and ``step_ms_max``.
The runs are not paced to the wall clock (see ``simulate --realtime`` for that), so
the MPC accepts late solves here and the runs are deterministic.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..config import Scenario
from ..control import available_controllers
from ..paths import ReferencePath
from .simulate import PREDICTION_FIGURE, add_run_arguments, prepare_run, write_prediction_figure

__all__ = [
    "CONTROLLER_ORDER",
    "PREDICTING_CONTROLLER",
    "SUMMARY_COLUMNS",
    "compare_controllers",
    "register",
    "run",
    "summary_table",
]

#: Columns of summary.md: (metric key, header, format).
SUMMARY_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("cross_track_rms_mm", "cross-track RMS (mm)", "{:.2f}"),
    ("cross_track_max_mm", "cross-track max (mm)", "{:.2f}"),
    ("paper_std_mm", "paper STD (mm)", "{:.2f}"),
    ("completion_time_s", "completion (s)", "{:.2f}"),
    ("nominal_time_s", "nominal (s)", "{:.2f}"),
    ("final_error_mm", "final error (mm)", "{:.1f}"),
    ("decoupled", "decoupled", "{}"),
    ("dropped", "dropped", "{}"),
    ("solve_ms_median", "solve median (ms)", "{:.2f}"),
    ("solve_ms_p99", "solve p99 (ms)", "{:.2f}"),
    ("solver_failures", "solver failures", "{}"),
    ("deadline_misses", "deadline misses", "{}"),
)
#: The controller whose predictions are drawn in ``mpc_prediction.png``.
PREDICTING_CONTROLLER = "mpc"
#: Order of the runs and of the table rows (the issue's order); other registered controllers follow.
CONTROLLER_ORDER = ("follow", "paper_0.8v", "plan", "mpc")


def register(sub: Any) -> None:
    """Add the ``compare`` command."""
    p = sub.add_parser(
        "compare",
        help="run every available controller on the same plant and seed",
        description=(
            "Run controllers (default: every registered one: follow, paper_0.8v, plan if available, mpc) on "
            "the same plant, path and seed. Writes one run folder per controller, summary.json, summary.md, "
            "trajectories.png, errors.png, metrics.png and, with mpc, mpc_prediction.png."
        ),
    )
    add_run_arguments(p)
    p.add_argument(
        "--controllers", nargs="+", default=None, help="only these controllers (default: all available)"
    )
    p.set_defaults(func=run)


def _json_value(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _json_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_value(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "item"):  # numpy scalars
        return _json_value(value.item())
    return value


def summary_table(controllers: dict[str, dict[str, Any]]) -> str:
    """A markdown table of the per-controller metrics (``n/a`` for missing / non-finite values)."""

    def cell(entry: dict[str, Any], key: str, fmt: str) -> str:
        v = entry.get(key)
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            return "n/a"
        return fmt.format(v)

    head = "| controller | " + " | ".join(h for _, h, _ in SUMMARY_COLUMNS) + " |"
    rule = "|---|" + "---|" * len(SUMMARY_COLUMNS)
    lines = [head, rule]
    for name, entry in controllers.items():
        if "error" in entry:
            lines.append(f"| {name} | error: {entry['error']} |" + " |" * (len(SUMMARY_COLUMNS) - 1))
            continue
        lines.append(f"| {name} | " + " | ".join(cell(entry, k, f) for k, _, f in SUMMARY_COLUMNS) + " |")
    return "\n".join(lines) + "\n"


def compare_controllers(
    scenario: Scenario,
    path: ReferencePath,
    out: str | Path,
    seed: int,
    *,
    controllers: Sequence[str] | None = None,
    meta: dict[str, Any] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Run controllers on the same plant, path and seed; write runs, summary and figures.

    Parameters
    ----------
    scenario, path, seed
        As for :func:`capsule_mpc.sim.simulate`.
    out : str or Path
        Output folder (created).
    controllers : sequence of str, optional
        Names to run, in this order; default every registered controller
        (:func:`available_controllers`) in :data:`CONTROLLER_ORDER`, then the others.
    meta : dict, optional
        Provenance (``config``, ``waypoints_file``) for the summary and each run.json.
    progress : bool
        Progress bars on runs longer than a second.

    Returns
    -------
    dict
        The summary written to ``summary.json``: ``{"config", "seed", "speed_mps",
        "waypoints_file", "path_length_m", "controllers": {name: metrics + flags + limit
        counts + run_dir + realtime_factor, or {"error": text}}, "figures": [file names]}``.
    """
    from ..atomic import write_text_atomic
    from ..plots import plot_errors, plot_metrics, plot_trajectories
    from ..sim import simulate, write_run

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta = dict(meta or {})
    if controllers is not None:
        names = list(controllers)
    else:
        known = available_controllers()
        names = [n for n in CONTROLLER_ORDER if n in known] + [n for n in known if n not in CONTROLLER_ORDER]
    entries: dict[str, dict[str, Any]] = {}
    logs = {}
    prediction_figure = None
    for name in names:
        try:
            result = simulate(scenario, name, path, seed, progress=progress, meta=meta)
        except Exception as exc:  # one broken controller must not hide the others' results
            entries[name] = {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
            continue
        run_dir = write_run(result, out / name.replace("/", "_"))
        entries[name] = {
            **result.metrics,
            "failure": result.flags.failure,
            "run_dir": str(run_dir),
            "realtime_factor": result.realtime_factor,
        }
        logs[name] = result.log
        if name == PREDICTING_CONTROLLER:
            prediction_figure = write_prediction_figure(result, out / PREDICTION_FIGURE)
    figures = ["trajectories.png", "errors.png", "metrics.png"] if logs else []
    if prediction_figure is not None:
        figures.append(prediction_figure.name)
    summary = {
        "config": meta.get("config"),
        "seed": seed,
        "speed_mps": path.speed_mps,
        "waypoints_file": meta.get("waypoints_file"),
        "path_length_m": path.length_m,
        "controllers": entries,
        "figures": figures,
    }
    write_text_atomic(out / "summary.json", json.dumps(_json_value(summary), indent=2) + "\n")
    title = f"# compare: {scenario.name}, v = {path.speed_mps} m/s, seed {seed}\n\n"
    write_text_atomic(out / "summary.md", title + summary_table(entries))
    if logs:
        ok = {n: e for n, e in entries.items() if "error" not in e}
        plot_trajectories(logs, path, out / "trajectories.png")
        plot_errors(logs, path, out / "errors.png", {n: e["motion_end_s"] for n, e in ok.items()})
        plot_metrics(ok, out / "metrics.png")
    return summary


def run(args: argparse.Namespace) -> int:
    """Compare the controllers; exit status 1 if any controller raised."""
    scenario, path, meta = prepare_run(args.config, args.waypoints, args.speed)
    seed = scenario.sim.seed if args.seed is None else args.seed
    known = available_controllers()
    unknown = [n for n in args.controllers or [] if n not in known]
    if unknown:
        print(f"capsule-mpc compare: --controllers: unknown {unknown}; available: {known}", file=sys.stderr)
        return 2
    summary = compare_controllers(
        scenario, path, args.out, seed, controllers=args.controllers, meta=meta, progress=not args.no_progress
    )
    print(summary_table(summary["controllers"]), end="")
    errors = [n for n, e in summary["controllers"].items() if "error" in e]
    for name in errors:
        print(f"capsule-mpc compare: controller {name!r} failed: {summary['controllers'][name]['error']}")
    print(
        f"results in {Path(args.out).resolve()} (summary.json, summary.md, *.png, one folder per controller)"
    )
    return 1 if errors else 0
