"""Compare controllers on the same plant, path and seeds (what ``capsule-mpc compare`` runs).

A comparison is a campaign on the sweep's runner (:mod:`capsule_mpc.experiments.sweep`, with
``command="compare"``) that also writes one run folder per controller and seed (``OUT/NAME/`` for
one run, ``OUT/runs/seed_<S>/NAME/`` for several) and the first seed's figures, and does not resume.
A controller that raises on a seed has ``{"error", "traceback"}`` instead of metrics there. Exit
status: 0 when every controller ran on every seed, 1 when any failed (each named on stderr), 2 on
bad input, 130 on Ctrl-C (each run in progress keeps its log so far and a finalised ``run.mcap``).
The runs are not paced to the wall clock, so they are deterministic.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from ..budget import Workload
from ..config import ConfigError, Scenario
from ..interfaces import available_controllers
from ..metrics import START_WINDOW_S
from ..paths import ReferencePath
from .aggregate import aggregate
from .inputs import refuse_repeats
from .sweep.tasks import PLANNING_CONTROLLER
from .table import run_label, table_from_entries

__all__ = [
    "CONTROLLER_ORDER",
    "PREDICTING_CONTROLLER",
    "RUNS_FOLDER",
    "SUMMARY_COLUMNS",
    "aggregate_runs",
    "check_controllers",
    "run_figures",
    "summary_markdown",
    "summary_table",
]

#: Columns of summary.md: (metric key, header, format of one value). Flags counted over runs
#: (``decoupled``, ``dropped``, ``stalled``) and integer counts use ``"{}"``.
SUMMARY_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("tracking_rms_mm", "tracking RMS (mm)", "{:.2f}"),
    ("tracking_max_mm", "tracking max (mm)", "{:.2f}"),
    ("start_tracking_rms_mm", f"start RMS, first {START_WINDOW_S:g} s (mm)", "{:.2f}"),
    ("cross_track_rms_mm", "cross-track RMS (mm)", "{:.2f}"),
    ("cross_track_max_mm", "cross-track max (mm)", "{:.2f}"),
    ("final_error_mm", "final error (mm)", "{:.1f}"),
    ("arrival_time_s", "arrival (s)", "{:.2f}"),
    ("paper_std_mm", "paper STD (mm)", "{:.2f}"),
    ("epm_jerk_rms_mps3", "EPM jerk RMS (m/s³)", "{:.3g}"),
    ("decoupled", "decoupled", "{}"),
    ("dropped", "dropped", "{}"),
    ("stalled", "stalled", "{}"),
    ("solver_failures", "solver failures", "{}"),
    ("deadline_misses", "deadline misses", "{}"),
)
#: The controller whose predictions are drawn in ``mpc_prediction.png``.
PREDICTING_CONTROLLER = "mpc"
#: Order of the runs and of the table rows; other registered controllers follow.
CONTROLLER_ORDER = ("follow", "paper_0.8v", "plan", "mpc")
#: Sub-folder of ``--out`` holding the run folders when there are several runs per controller.
RUNS_FOLDER = "runs"


def aggregate_runs(per_seed: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per-run statistics over the draws (``per_seed``: ``summary.json``'s ``runs``), as its ``controllers``.

    For each run label, from :func:`capsule_mpc.experiments.aggregate.aggregate` of the run table:
    every metric's mean and every flag's count over the successful runs, ``spread`` ``{metric:
    {"sd", "min", "max", "n"}}``, ``n_runs``, ``n_failed``, ``status`` (``"ok"``, ``"failed"`` or
    ``"failed on k of N runs"``), ``errors`` when any and ``error`` (the first) when no run
    succeeded, with no metrics then.
    """
    table = table_from_entries(per_seed)
    stats = aggregate(table)
    metrics = [m for m, stat in stats.columns if stat == "mean"]
    flags = [f for f, stat in stats.columns if stat == "count"]
    errors = table[table["error"] != ""].groupby(["variant", "controller"], sort=False)["error"].agg(list)
    out: dict[str, dict[str, Any]] = {}
    for key, row in stats.iterrows():
        n_ok, n_failed = int(row[("runs", "n")]), int(row[("failed", "n")])
        entry: dict[str, Any] = {}
        if n_ok:
            entry.update({m: float(row[(m, "mean")]) for m in metrics})
            entry.update({f: int(row[(f, "count")]) for f in flags})
            entry["spread"] = {
                m: {
                    "sd": row[(m, "sd")],
                    "min": row[(m, "min")],
                    "max": row[(m, "worst")],
                    "n": int(row[(m, "n")]),
                }
                for m in metrics
            }
        status = "failed" if not n_ok else f"failed on {n_failed} of {n_ok + n_failed} runs"
        entry.update(n_runs=n_ok, n_failed=n_failed, status=status if n_failed else "ok")
        if n_failed:
            entry["errors"] = errors[key]
        if not n_ok:
            entry["error"] = errors[key][0]
        out[run_label(*key)] = entry
    return out


def _cell(entry: Mapping[str, Any], key: str, fmt: str, runs: int) -> str:
    value = entry.get(key)
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"

    def number(v: float) -> str:
        if fmt == "{}":  # counts: no ".0" on whole numbers
            return str(int(v)) if float(v).is_integer() else f"{v:.1f}"
        return fmt.format(v)

    spread = entry.get("spread", {}).get(key)
    n_runs = int(entry.get("n_runs", 1))
    if runs > 1 and spread is not None:
        text = f"{number(value)} ± {number(spread['sd'])}"
        return text if spread["n"] >= n_runs else f"{text} ({spread['n']}/{n_runs})"
    if runs > 1 and isinstance(value, int):  # a flag's count
        return f"{value}/{n_runs}"
    return number(value)


def summary_table(controllers: Mapping[str, Mapping[str, Any]], runs: int = 1) -> str:
    """A markdown table of ``summary.json``'s ``controllers`` (``n/a`` for missing or non-finite values).

    With ``runs`` > 1 a metric reads ``mean ± sd`` (with ``(n/N)`` when only ``n`` of the ``N``
    successful runs had a finite value, e.g. arrived), a flag ``k/N`` (true in ``k`` of ``N`` runs),
    and a first column gives the successful runs.
    """
    several = runs > 1
    head = (
        "| controller | "
        + ("runs | " if several else "")
        + " | ".join(h for _, h, _ in SUMMARY_COLUMNS)
        + " |"
    )
    lines = [head, "|---|" + "---|" * (len(SUMMARY_COLUMNS) + several)]
    for name, entry in controllers.items():
        done = f"{entry.get('n_runs', 0)}/{runs} | " if several else ""
        if "error" in entry:  # no run finished: no numbers, the reason instead
            reason = " ".join(str(entry["error"]).split()).replace("|", "\\|")
            lines.append(f"| {name} | {done}failed: {reason} |" + " |" * (len(SUMMARY_COLUMNS) - 1))
            continue
        cells = " | ".join(_cell(entry, k, f, runs) for k, _, f in SUMMARY_COLUMNS)
        lines.append(f"| {name} | {done}{cells} |")
    return "\n".join(lines) + "\n"


def summary_markdown(
    command: str, scenario: Scenario, path: ReferencePath, summary: Mapping[str, Any]
) -> str:
    """``summary.md`` of a comparison or a sweep: the title, what was varied, the table and a note."""
    seeds = summary["seeds"]
    runs = len(seeds)
    plant = f", plant {scenario.plant.preset}" if command == "sweep" else ""
    which = f"seed {seeds[0]}" if runs == 1 else f"seeds {seeds[0]}..{seeds[-1]}"
    title = f"# {command}: {scenario.name}{plant}, v = {path.speed_mps} m/s, {which}\n\n"
    varied = ", ".join(f"plant.{f} ~ U({lo:g}, {hi:g})" for f, (lo, hi) in summary.get("vary", {}).items())
    what = f"Varied: {varied}.\n\n" if varied else ""
    note = (
        f"\nMean ± sd (ddof 1) over the {runs} seeds; `(n/N)`: only n runs had a value (e.g. arrived); "
        "flags: runs where true. Each seed's runs are scored on a common window (t = 0 to the "
        "latest end among them).\n"
    )
    return title + what + summary_table(summary["controllers"], runs) + (note if runs > 1 else "")


def check_controllers(controllers: Sequence[str] | None) -> list[str]:
    """The controllers a campaign runs: ``controllers``, or every registered one in
    :data:`CONTROLLER_ORDER`, then the others; a ConfigError for an unknown or repeated name."""
    known = available_controllers()
    if controllers is None:
        return [n for n in CONTROLLER_ORDER if n in known] + [n for n in known if n not in CONTROLLER_ORDER]
    unknown = [n for n in controllers if n not in known]
    if unknown:
        raise ConfigError(f"--controllers: unknown {unknown}; available: {known}")
    refuse_repeats("--controllers", controllers)
    return list(controllers)


def run_figures(names: Sequence[str], runs: int) -> Workload:
    """What a comparison of ``names`` over ``runs`` seeds holds in memory at once in a worker (for
    :func:`capsule_mpc.budget.check_run`): every controller's run of a seed; the offline plan for the
    ``plan`` controller."""
    return Workload(
        runs=len(names),
        predicting=sum(n == PREDICTING_CONTROLLER for n in names),
        plan="fixed" if PLANNING_CONTROLLER in names else None,
    )
