"""Compare controllers on the same plant, path and seeds (what ``capsule-mpc compare`` runs).

Each run ``k`` of ``--runs N`` uses the seed ``seed + k``; a seed fixes the plant drawn
around the nominal scenario, the start offset and the camera noise, and every controller
runs on it. A run ends when its capsule is at rest after the path's end (or at the tail
cut-off), so the runs of one seed end at different times: they are all re-scored on a
common window, from t = 0 to the latest end among that seed's runs
(:func:`capsule_mpc.metrics.run_metrics` holds an earlier run's last state up to it).

Writes, into the output folder: one run folder per controller and seed (``log.csv``,
``config.yaml``, ``run.json``; ``predictions.npz`` for the MPC) -- ``OUT/NAME/`` for one
run, ``OUT/runs/seed_<S>/NAME/`` for several -- ``summary.json``, ``summary.md`` (a
table; ``mean ± sd`` over the runs when there are several) and the figures
``trajectories.png`` (paper Fig. 7a), ``errors.png`` (Fig. 8) and, when an ``mpc`` run is
present, ``mpc_prediction.png`` (its predicted vs actual capsule path at the first corner),
all of the first seed; and ``metrics.png`` (bars for one run, the distribution over the
runs for several).

``summary.json``: ``controllers.NAME.METRIC`` is the mean over that controller's successful
runs of every numeric metric (NaN values left out), true/false flags (``decoupled``,
``dropped``, ``stalled``, ...) are the number of runs where they were true;
``controllers.NAME.spread.METRIC`` holds ``sd`` (ddof 1; 0 for a single value), ``min``,
``max`` and ``n`` (the number of finite values); ``n_runs`` and ``n_failed`` count the
runs that finished and those whose controller raised (:func:`aggregate_runs`). ``runs``
lists every seed's runs as the runner reported them, re-scored.

A controller fails on a seed when it raises instead of running: e.g. the ``plan`` controller
when the planner's solve does not converge (:class:`capsule_mpc.planner.PlanError`). Such a run
has no metrics (``runs[k].controllers.NAME`` is ``{"error", "traceback"}``), its controller's
``status`` says ``failed``, and a controller that failed on every seed reads ``failed: <why>`` in
the table instead of numbers. Exit status: 0 when every controller ran on every seed, 1 when
any failed (each failure is also printed on stderr), 2 on bad input, 130 on Ctrl-C (the runs in
progress are dropped: nothing is recorded for them, and summary.json / summary.md are written
only by a finished comparison).

Solver figures per controller (from the run log; NaN / ``n/a`` for controllers that
report no solve): ``solve_ms_median``, ``solve_ms_p99``, ``solve_ms_max``,
``solver_failures`` (steps the controller reported as failed), ``deadline_misses``
(solves longer than the camera frame period, settle phase included) and ``step_ms_max``.
The runs are not paced to the wall clock (see ``simulate --realtime`` for that), so
the MPC accepts late solves here and the runs are deterministic.
"""

from __future__ import annotations

import contextlib
import json
import math
import traceback
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from ..atomic import write_text_atomic
from ..budget import Workload
from ..config import ConfigError, Scenario
from ..interfaces import available_controllers
from ..interrupt import raise_if_interrupted
from ..metrics import START_WINDOW_S, run_metrics, stack_predictions
from ..paths import ReferencePath
from ..planner import cached_plan
from ..plots import plot_errors, plot_metrics, plot_trajectories
from ..sim import CapsulePlant, Observer, RunResult, draw_plant_truth, simulate, write_run
from ..telemetry.observer import Telemetry
from ..telemetry.options import MCAP_NAME
from ..telemetry.partial import PartialRun
from .inputs import refuse_repeats
from .runs import PREDICTION_FIGURE, write_prediction_figure

__all__ = [
    "CONTROLLER_ORDER",
    "PLANNING_CONTROLLER",
    "PREDICTING_CONTROLLER",
    "RUNS_FOLDER",
    "SUMMARY_COLUMNS",
    "aggregate_runs",
    "check_controllers",
    "compare_controllers",
    "controller_names",
    "failed_runs",
    "failure_line",
    "json_value",
    "rescore_on_common_window",
    "run_figures",
    "run_seed_controllers",
    "summary_header",
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
#: The controller that needs the offline plan: it is solved once, with a progress bar, before its
#: first run (the runs take it from :func:`capsule_mpc.planner.cached_plan`).
PLANNING_CONTROLLER = "plan"
#: Order of the runs and of the table rows; other registered controllers follow.
CONTROLLER_ORDER = ("follow", "paper_0.8v", "plan", "mpc")
#: Sub-folder of ``--out`` holding the run folders when there are several runs per controller.
RUNS_FOLDER = "runs"


def json_value(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): json_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_value(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if hasattr(value, "item"):  # numpy scalars
        return json_value(value.item())
    return value


def _is_flag(value: Any) -> bool:
    return isinstance(value, (bool, np.bool_))


def _is_number(value: Any) -> bool:
    return value is None or (isinstance(value, (int, float, np.integer, np.floating)) and not _is_flag(value))


def _spread(values: list[float]) -> dict[str, float | int]:
    if not values:
        return {"sd": math.nan, "min": math.nan, "max": math.nan, "n": 0}
    sd = float(np.std(values, ddof=1)) if len(values) >= 2 else 0.0
    return {"sd": sd, "min": float(min(values)), "max": float(max(values)), "n": len(values)}


def _status(n_ok: int, n_failed: int) -> str:
    if not n_failed:
        return "ok"
    return "failed" if not n_ok else f"failed on {n_failed} of {n_ok + n_failed} runs"


def _aggregate_controller(entries: list[Mapping[str, Any]]) -> dict[str, Any]:
    ok = [e for e in entries if "error" not in e]
    failed = [e for e in entries if "error" in e]
    keys = list(dict.fromkeys(k for e in ok for k in e))
    out: dict[str, Any] = {}
    spread: dict[str, dict[str, float | int]] = {}
    for key in keys:
        values = [e[key] for e in ok if key in e]
        if all(_is_flag(v) for v in values):
            out[key] = sum(bool(v) for v in values)
        elif all(_is_number(v) for v in values):
            finite = [float(v) for v in values if v is not None and math.isfinite(float(v))]
            out[key] = float(np.mean(finite)) if finite else math.nan
            spread[key] = _spread(finite)
    out.update(n_runs=len(ok), n_failed=len(failed), spread=spread, status=_status(len(ok), len(failed)))
    if failed:
        out["errors"] = [str(e["error"]) for e in failed]
    if not ok:
        out["error"] = str(failed[0]["error"])
    return out


def aggregate_runs(per_seed: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per-controller statistics over the runs of several seeds.

    Parameters
    ----------
    per_seed : sequence of mapping
        One entry per seed, as in ``summary.json``'s ``runs``: ``{"controllers": {name: the
        run's metrics and flags, or {"error": text}}}`` (other keys are ignored). A JSON null
        counts as NaN.

    Returns
    -------
    dict of str to dict
        For each controller, in order of first appearance: every numeric entry's mean over
        the successful runs (NaN values left out; NaN if none is left), every true/false
        entry as the number of runs where it was true, ``spread`` ``{key: {"sd" (ddof 1, 0
        for one value), "min", "max", "n" (finite values)}}`` for the numeric entries,
        ``n_runs`` (successful runs), ``n_failed`` (runs whose controller raised), ``status``
        (``"ok"``; ``"failed"`` when no run finished; else ``"failed on k of N runs"``),
        ``errors`` (their messages, when any) and ``error`` (the first message) when no run
        succeeded. Text entries (``failure``, ``run_dir``, ...) are left out.
    """
    names = list(dict.fromkeys(n for seed in per_seed for n in seed["controllers"]))
    return {
        name: _aggregate_controller(
            [seed["controllers"][name] for seed in per_seed if name in seed["controllers"]]
        )
        for name in names
    }


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
    if runs > 1 and key not in entry.get("spread", {}) and isinstance(value, int):  # a flag's count
        return f"{value}/{n_runs}"
    return number(value)


def summary_table(controllers: Mapping[str, Mapping[str, Any]], runs: int = 1) -> str:
    """A markdown table of the per-controller metrics (``n/a`` for missing / non-finite values).

    Parameters
    ----------
    controllers : mapping of controller name to dict
        ``summary.json``'s ``controllers`` (:func:`aggregate_runs`); a plain metrics dict per
        controller also works for one run.
    runs : int
        Runs per controller. Above 1 a metric reads ``mean ± sd`` (with ``(n/N)`` when only
        ``n`` of the ``N`` successful runs had a finite value, e.g. arrived), a flag reads
        ``k/N`` (true in ``k`` of ``N`` runs), and a first column gives the successful runs.
    """
    several = runs > 1
    head = (
        "| controller | "
        + ("runs | " if several else "")
        + " | ".join(h for _, h, _ in SUMMARY_COLUMNS)
        + " |"
    )
    rule = "|---|" + "---|" * (len(SUMMARY_COLUMNS) + several)
    lines = [head, rule]
    for name, entry in controllers.items():
        done = f"{entry.get('n_runs', 0)}/{runs} | " if several else ""
        if "error" in entry:  # no run finished: no numbers, the reason instead
            reason = " ".join(str(entry["error"]).split()).replace("|", "\\|")
            lines.append(f"| {name} | {done}failed: {reason} |" + " |" * (len(SUMMARY_COLUMNS) - 1))
            continue
        cells = " | ".join(_cell(entry, k, f, runs) for k, _, f in SUMMARY_COLUMNS)
        lines.append(f"| {name} | {done}{cells} |")
    return "\n".join(lines) + "\n"


def rescore_on_common_window(
    results: Mapping[str, RunResult], path: ReferencePath, scenario: Scenario
) -> float:
    """Re-score one seed's runs on a common window; returns its end, s (NaN without runs).

    The window ends at the latest ``motion_end_s`` (the time a run ended at rest) among the
    runs; each run's metrics are recomputed on it with :func:`capsule_mpc.metrics.run_metrics`
    (arrival tolerance ``sim.completion_tol_m``, deadline one camera period) and written into
    its ``metrics`` dict, which keeps the runner's other entries (flags, limit counts).
    """
    ends = [float(r.metrics["motion_end_s"]) for r in results.values()]
    ends = [e for e in ends if math.isfinite(e)]
    if not ends:
        return math.nan
    common = max(ends)
    for result in results.values():
        result.metrics.update(
            run_metrics(
                result.log,
                path,
                window_end_s=common,
                arrival_tol_m=scenario.sim.completion_tol_m,
                deadline_ms=1e3 / scenario.camera.rate_hz,
            )
        )
    return common


def check_controllers(controllers: Sequence[str] | None) -> list[str]:
    """The controllers a comparison runs (:func:`controller_names`), after refusing an unknown one
    or one given twice.

    Raises
    ------
    ConfigError
        ``--controllers: unknown [...]; available: [...]`` or ``--controllers: 'x' is given more than once``.
    """
    known = available_controllers()
    unknown = [n for n in controllers or [] if n not in known]
    if unknown:
        raise ConfigError(f"--controllers: unknown {unknown}; available: {known}")
    refuse_repeats("--controllers", controllers or [])
    return controller_names(controllers)


def controller_names(controllers: Sequence[str] | None) -> list[str]:
    if controllers is not None:
        return list(controllers)
    known = available_controllers()
    return [n for n in CONTROLLER_ORDER if n in known] + [n for n in known if n not in CONTROLLER_ORDER]


def run_seed_controllers(
    scenario: Scenario,
    path: ReferencePath,
    seed: int,
    names: Sequence[str],
    *,
    meta: dict[str, Any] | None = None,
    progress: bool = False,
    bar: Any = None,
    plant_scenario: Scenario | None = None,
    observers: Callable[[str], Sequence[Observer]] | None = None,
) -> tuple[dict[str, RunResult], dict[str, dict[str, Any]], float]:
    """Run controllers on one seed and re-score their runs on the seed's common window.

    Parameters
    ----------
    scenario, path
        As for :func:`capsule_mpc.sim.simulate` (what the controllers believe).
    seed : int
        The seed of every run.
    names : sequence of str
        The controllers, in this order.
    meta : dict, optional
        Provenance for each run.
    progress : bool
        Show the planner's progress bar before the ``plan`` controller's first run.
    bar : tqdm, optional
        A progress bar over the runs: its postfix names the run, and it advances after each.
    plant_scenario : Scenario, optional
        The scenario the plant's truth is drawn from with ``seed`` (default ``scenario``), e.g.
        with plant fields overridden by ``sweep --vary``; the controllers are given ``scenario``.
    observers : callable, optional
        The observers of each controller's run, by name (e.g. its MCAP log, :class:`RunLogs`).

    Returns
    -------
    (dict, dict, float)
        The runs that finished by controller name; ``{"error", "traceback"}`` for each
        controller that raised instead; the end of the common window, s
        (:func:`rescore_on_common_window`).
    """
    truth = None if plant_scenario is None else draw_plant_truth(plant_scenario, seed)
    results: dict[str, RunResult] = {}
    entries: dict[str, dict[str, Any]] = {}
    for name in names:
        if bar is not None:
            bar.set_postfix_str(f"seed {seed}, {name}")
        try:
            if name == PLANNING_CONTROLLER:  # the planner stage, with its own progress bar
                cached_plan(scenario, path, progress=progress)
            plant = None if plant_scenario is None else CapsulePlant(plant_scenario, truth=truth)
            watching = () if observers is None else observers(name)
            results[name] = simulate(
                scenario, name, path, seed, progress=False, meta=meta, plant=plant, observers=watching
            )
        except Exception as exc:  # one broken controller must not hide the others' results
            raise_if_interrupted()  # ... but Ctrl-C (which CasADi may turn into any error) stops all
            entries[name] = {"error": failure_line(name, exc), "traceback": traceback.format_exc()}
        if bar is not None:
            bar.update(1)
    return results, entries, rescore_on_common_window(results, path, scenario)


class RunLogs:
    """The MCAP logs of one seed's runs, each in its run's folder under ``base``
    (:func:`run_folder`, :data:`MCAP_NAME`).

    A log is kept when :meth:`keep` is called once its run's files are written; the others (a run
    that raised) are removed on exit with the folders made for them, so an unrecorded run leaves
    nothing behind. When a signal stops the seed, each of its runs keeps its log so far and its
    finalised MCAP (:class:`~capsule_mpc.telemetry.partial.PartialRun`).
    """

    def __init__(self, base: Path) -> None:
        self.base = base
        self.logs: dict[str, Telemetry] = {}
        self.partial: dict[str, PartialRun] = {}

    def observers(self, name: str) -> list[Observer]:
        """The observers of controller ``name``'s run: its MCAP log and what a stopped run keeps."""
        log = self.logs[name] = Telemetry(run_folder(self.base, name) / MCAP_NAME, hold=True)
        partial = self.partial[name] = PartialRun()
        return [log, partial]

    def keep(self, name: str) -> None:
        """Close ``name``'s log into its run folder."""
        self.logs.pop(name).close(complete=True)

    def __enter__(self) -> RunLogs:
        return self

    def __exit__(self, *exc: Any) -> None:
        for name, log in self.logs.items():
            if isinstance(exc[1], KeyboardInterrupt) and self.partial[name].write(
                run_folder(self.base, name)
            ):
                log.__exit__(*exc)  # the MCAP so far, finalised
                continue
            log.close(complete=False)
            with contextlib.suppress(OSError):  # refused unless empty: the folder only held the log
                run_folder(self.base, name).rmdir()
        self.logs.clear()


def run_folder(base: Path, name: str) -> Path:
    """The folder of controller ``name``'s run under ``base``."""
    return base / name.replace("/", "_")


#: Longest reason kept in a failure line, characters.
_REASON_CHARS = 240
#: Markers of the informative line in a CasADi error (the rest is its call stack).
_CASADI_REASON = ("returned flag", "Error in Function::", "error:")


def failure_line(name: str, exc: BaseException) -> str:
    """One line saying which controller failed, why, and what to try; never a solver's dump.

    A CasADi error is a stack of ``Error in Function::call ...`` lines with the cause deep
    inside (e.g. a root finder's status flag); the line with the cause is kept, cut to a
    readable length. The full traceback stays in ``summary.json``.
    """
    lines = [" ".join(line.split()) for line in str(exc).splitlines() if line.strip()]
    reason = lines[0] if lines else type(exc).__name__
    flagged = [line for line in lines if "returned flag" in line or "returned status" in line]
    if flagged:
        reason = flagged[-1]
    elif len(lines) > 1 and any(m in lines[0] for m in _CASADI_REASON):
        reason = lines[-1]
    if len(reason) > _REASON_CHARS:
        reason = reason[: _REASON_CHARS - 1] + "…"
    return (
        f"{type(exc).__name__}: {reason} (traceback in summary.json; to see it alone: "
        f"capsule-mpc simulate --controller {name} with the same config and seed)"
    )


def failed_runs(summary: Mapping[str, Any]) -> list[tuple[str, int, str]]:
    """``(controller, seed, error)`` of every run of a comparison's ``summary`` whose controller raised."""
    return [
        (name, seed_entry["seed"], entry["error"])
        for seed_entry in summary["runs"]
        for name, entry in seed_entry["controllers"].items()
        if "error" in entry
    ]


def summary_header(
    meta: Mapping[str, Any], seed: int, path: ReferencePath, runs: int, seeds: Sequence[int]
) -> dict[str, Any]:
    """The head of a ``summary.json`` (``compare --runs`` and ``sweep``): provenance and the runs."""
    return {
        "config": meta.get("config"),
        "seed": seed,
        "speed_mps": path.speed_mps,
        "waypoints_file": meta.get("waypoints_file"),
        "path_length_m": path.length_m,
        "runs_requested": runs,
        "seeds": list(seeds),
    }


def compare_controllers(
    scenario: Scenario,
    path: ReferencePath,
    out: str | Path,
    seed: int,
    *,
    controllers: Sequence[str] | None = None,
    meta: dict[str, Any] | None = None,
    progress: bool = True,
    runs: int = 1,
) -> dict[str, Any]:
    """Run controllers on the same plant, path and seeds; write runs, summary and figures.

    Parameters
    ----------
    scenario, path
        As for :func:`capsule_mpc.sim.simulate`.
    out : str or Path
        Output folder (created).
    seed : int
        Seed of the first run; run ``k`` uses ``seed + k``.
    controllers : sequence of str, optional
        Names to run, in this order; default every registered controller
        (:func:`available_controllers`) in :data:`CONTROLLER_ORDER`, then the others.
    meta : dict, optional
        Provenance (``config``, ``waypoints_file``) for the summary and each run.json.
    progress : bool
        A progress bar over the runs.
    runs : int
        Seeds per controller, >= 1.

    Returns
    -------
    dict
        The summary written to ``summary.json``: ``{"config", "seed", "speed_mps",
        "waypoints_file", "path_length_m", "runs_requested", "seeds", "controllers": {name:
        :func:`aggregate_runs` entry (for one run also the run's text entries: ``failure``,
        ``run_dir``, or ``traceback`` if it raised)}, "runs": [{"seed", "window_end_s", "controllers": {name:
        metrics + flags + limit counts + failure + run_dir + realtime_factor, or {"error",
        "traceback"}}}], "figures": [file names]}``.

    Raises
    ------
    ValueError
        If ``runs`` < 1.
    """
    if runs < 1:
        raise ValueError(f"runs: must be an integer >= 1, got {runs}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta = dict(meta or {})
    names = controller_names(controllers)
    seeds = [seed + k for k in range(runs)]
    per_seed: list[dict[str, Any]] = []
    first: dict[str, RunResult] = {}
    prediction_figure = None
    with tqdm(total=runs * len(names), desc="compare", unit="run", disable=not progress) as bar:
        for k, s in enumerate(seeds):
            base = out if runs == 1 else out / RUNS_FOLDER / f"seed_{s}"
            with RunLogs(base) as logs:
                results, entries, window_end = run_seed_controllers(
                    scenario, path, s, names, meta=meta, progress=progress, bar=bar, observers=logs.observers
                )
                for name, result in results.items():
                    run_dir = write_run(result, run_folder(base, name))
                    logs.keep(name)
                    entries[name] = {
                        **result.metrics,
                        "failure": result.flags.failure,
                        "run_dir": str(run_dir),
                        "realtime_factor": result.realtime_factor,
                    }
            per_seed.append(
                {"seed": s, "window_end_s": window_end, "controllers": {n: entries[n] for n in names}}
            )
            if k == 0:
                first = results
                predicting = results.get(PREDICTING_CONTROLLER)
                if predicting is not None and stack_predictions(predicting.predictions) is not None:
                    prediction_figure = write_prediction_figure(predicting, out / PREDICTION_FIGURE)
    aggregated = aggregate_runs(per_seed)
    if runs == 1:  # one run: its text entries (run_dir, failure, traceback) beside its metrics
        for name, entry in aggregated.items():
            single = per_seed[0]["controllers"][name]
            entry.update({key: value for key, value in single.items() if key not in entry})
    figures = _write_figures(out, path, per_seed, first, runs)
    if prediction_figure is not None:
        figures.append(prediction_figure.name)
    summary = {
        **summary_header(meta, seed, path, runs, seeds),
        "controllers": aggregated,
        "runs": per_seed,
        "figures": figures,
    }
    write_text_atomic(out / "summary.json", json.dumps(json_value(summary), indent=2) + "\n")
    write_text_atomic(out / "summary.md", _summary_markdown(scenario, path, seeds, aggregated))
    return summary


def _summary_markdown(
    scenario: Scenario,
    path: ReferencePath,
    seeds: Sequence[int],
    controllers: Mapping[str, Mapping[str, Any]],
) -> str:
    runs = len(seeds)
    if runs == 1:
        title = f"# compare: {scenario.name}, v = {path.speed_mps} m/s, seed {seeds[0]}\n\n"
        note = ""
    else:
        title = f"# compare: {scenario.name}, v = {path.speed_mps} m/s, seeds {seeds[0]}..{seeds[-1]}\n\n"
        note = (
            f"\nMean ± sd (ddof 1) over the {runs} seeds; `(n/N)`: only n runs had a value (e.g. arrived); "
            "flags: runs where true. Each seed's runs are scored on a common window (t = 0 to the "
            "latest end among them).\n"
        )
    return title + summary_table(controllers, runs) + note


def _write_figures(
    out: Path,
    path: ReferencePath,
    per_seed: Sequence[Mapping[str, Any]],
    first: Mapping[str, RunResult],
    runs: int,
) -> list[str]:
    """trajectories.png and errors.png of the first seed, metrics.png of every run; the file names."""
    if not first:  # no controller ran on the first seed
        return []
    logs = {n: r.log for n, r in first.items()}
    ends = {n: r.metrics["motion_end_s"] for n, r in first.items()}
    done: dict[str, list[Mapping[str, Any]]] = {}
    for seed in per_seed:
        for name, entry in seed["controllers"].items():
            if "error" not in entry:
                done.setdefault(name, []).append(entry)
    bars = {n: v[0] for n, v in done.items()} if runs == 1 else done
    draw: dict[str, Callable[[Path], Any]] = {
        "trajectories.png": lambda file: plot_trajectories(logs, path, file),
        "errors.png": lambda file: plot_errors(logs, path, file, ends),
        "metrics.png": lambda file: plot_metrics(bars, file),
    }
    for name, plot in draw.items():  # each figure complete or absent (written atomically)
        plot(out / name)
    return list(draw)


def run_figures(names: Sequence[str], runs: int) -> Workload:
    """What a comparison of ``names`` over ``runs`` seeds holds in memory at once (for
    :func:`capsule_mpc.budget.check_run`): every controller's run of a seed, and of the first seed
    too when there are several; the offline plan for the ``plan`` controller."""
    copies = 2 if runs > 1 else 1
    return Workload(
        runs=len(names) * copies,
        predicting=sum(n == PREDICTING_CONTROLLER for n in names) * copies,
        plan="fixed" if PLANNING_CONTROLLER in names else None,
    )
