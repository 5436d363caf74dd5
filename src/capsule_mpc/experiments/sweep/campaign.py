"""The sweep itself (:func:`sweep`: its runs on Dask, each written as it finishes, then the
summary), and ``capsule-mpc sweep`` around it (:func:`run_sweep`: the checks before any work, the
output folder, the report)."""

from __future__ import annotations

import json
import os
import shutil
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextlib import ExitStack, closing
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tqdm import tqdm

from ...atomic import atomic_path, json_ready, write_text_atomic
from ...budget import Workload, check_processes
from ...config import ConfigError, Scenario
from ...outputs import output_folder
from ...paths import ReferencePath
from ...sim import RunResult
from ..compare import (
    RUNS_FOLDER,
    aggregate_runs,
    check_controllers,
    run_figures,
    summary_markdown,
    summary_table,
)
from ..runs import PREDICTION_FIGURE, prepare_run
from ..table import TABLE_FILE, table_from_entries, write_table
from .results import SPEC_FILE, WORST_COUNT, check_resume, finished_runs, sweep_spec, worst_runs, worst_table
from .results import write_figures as write_figures
from .tasks import Outcome, SeedTask, Variant, dask_client, run_here, run_on_dask, run_seed
from .vary import VaryRange, check_vary

if TYPE_CHECKING:
    from distributed import Client

__all__ = ["compare_controllers", "local_workers", "run_sweep", "sweep", "sweep_failures"]


def sweep(
    scenario: Scenario,
    path: ReferencePath,
    out: str | Path,
    seed: int,
    runs: int,
    *,
    controllers: Sequence[str] | None = None,
    vary: Sequence[VaryRange] = (),
    variants: Sequence[Variant] = (),
    workers: int | None = None,
    client: Client | None = None,
    meta: dict[str, Any] | None = None,
    progress: bool = True,
    task: Callable[[SeedTask], dict[str, Any]] = run_seed,
    measure: Callable[[Mapping[str, RunResult]], Mapping[str, Mapping[str, Any]]] | None = None,
    command: str = "sweep",
) -> dict[str, Any]:
    """Run a campaign into ``out`` (resuming the one there), write its runs, table, summary and figures.

    ``scenario`` and ``path`` as for :func:`capsule_mpc.sim.simulate`; run ``k`` of ``runs`` (>= 1,
    else ValueError) uses the seed ``seed + k``. The ``controllers`` (default every registered one,
    :func:`~capsule_mpc.experiments.compare.check_controllers`) run on each draw in each of the
    ``variants`` (default the scenario as given), the ``vary`` fields drawn from their ranges
    (:mod:`.vary`). The draws run on ``client``, else on a ``LocalCluster`` of ``workers`` processes
    (default the CPU count, no more than the runs); ``task`` runs one seed and must be importable by
    the workers; ``measure`` adds entries to a draw's runs from their results; ``meta`` is the
    provenance (``config``, ``waypoints_file``). ``command="compare"`` writes each run's folder (under
    ``out`` for one run, ``out/runs/seed_<S>/`` for several) and the first seed's figures, runs a
    single local worker's draws in this process, and does not resume. Returns the summary written to
    ``summary.json``; a ConfigError for an unknown controller or a folder of other arguments.
    """
    if runs < 1:
        raise ValueError(f"runs: must be an integer >= 1, got {runs}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta = dict(meta or {})
    names = check_controllers(controllers)
    seeds = [seed + k for k in range(runs)]
    compare = command == "compare"
    done: dict[int, dict[str, Any]] = {}
    if not compare:
        spec = sweep_spec(scenario, path, seed, runs, names, vary, variants)
        check_resume(out, spec)
        write_text_atomic(out / SPEC_FILE, json.dumps(spec, indent=2) + "\n")
        done = finished_runs(out, seeds)

    def folders(s: int) -> tuple[str | None, str | None]:
        if not compare:
            return None, None
        return str(out if runs == 1 else out / RUNS_FOLDER / f"seed_{s}"), str(out) if s == seed else None

    todo = [
        SeedTask(scenario, path, s, tuple(names), tuple(vary), meta, tuple(variants), *folders(s), measure)
        for s in seeds
        if s not in done
    ]
    local = min(workers or os.cpu_count() or 1, len(todo))
    # a comparison on one local worker runs here: a cluster would only add its start-up
    here = compare and client is None and local == 1
    try:
        _run(todo, out, done, runs, local, client, progress, task, here)
    finally:  # also when stopped: the workers' runs then keep what they recorded (RunLogs)
        if compare and not here:
            _adopt(out, [Path(f) for t in todo for f in (t.runs_dir, t.figures_dir) if f is not None])
    per_seed = [done[s] for s in seeds]
    write_table(table_from_entries(per_seed), out / TABLE_FILE)
    summary: dict[str, Any] = {
        "config": meta.get("config"), "seed": seed, "speed_mps": path.speed_mps,
        "waypoints_file": meta.get("waypoints_file"), "path_length_m": path.length_m,
        "runs_requested": runs, "seeds": seeds, "controllers": aggregate_runs(per_seed),
    }  # fmt: skip
    if compare:
        if runs == 1:  # one run: its text entries (run_dir, failure, traceback) beside its metrics
            for name, entry in summary["controllers"].items():
                entry.update({k: v for k, v in per_seed[0]["controllers"][name].items() if k not in entry})
        figures = [n for n in ("trajectories.png", "errors.png") if (out / n).exists()]
        figures += write_figures(out, per_seed, distributions=False)
        figures += [PREDICTION_FIGURE] if (out / PREDICTION_FIGURE).exists() else []
    else:
        vary_ranges = {v.field: [v.lo, v.hi] for v in vary}
        summary.update(plant_preset=scenario.plant.preset, vary=vary_ranges, worst=worst_runs(per_seed))
        figures = write_figures(out, per_seed)
    summary.update(runs=per_seed, figures=figures)
    write_text_atomic(out / "summary.json", json.dumps(json_ready(summary), indent=2) + "\n")
    markdown = summary_markdown(command, scenario, path, summary)
    if not compare:
        markdown += (
            f"\n## Worst runs\n\nPer controller and metric, the seeds of the {WORST_COUNT} largest values; "
            "flags and failures: every seed where raised.\n\n" + worst_table(summary["worst"])
        )
    write_text_atomic(out / "summary.md", markdown)
    return summary


def _adopt(out: Path, folders: Sequence[Path]) -> None:
    """Put the files the workers wrote under ``folders`` into place again from this process, so
    that the output folder's manifest (:func:`capsule_mpc.outputs.output_folder`) lists them."""
    names = ("trajectories.png", "errors.png", PREDICTION_FIGURE)
    files = {
        f
        for d in set(folders)
        for f in d.rglob("*")
        if f.is_file() and f.parent != out and not f.name.startswith(".")  # not a killed write's temporary
    }
    files |= {out / n for n in names if (out / n).is_file()}
    for file in sorted(files):
        with atomic_path(file) as tmp:
            shutil.copyfile(file, tmp)


def _run(
    todo: Sequence[SeedTask],
    out: Path,
    done: dict[int, dict[str, Any]],
    runs: int,
    local: int,
    client: Client | None,
    progress: bool,
    task: Callable[[SeedTask], dict[str, Any]],
    in_process: bool = False,
) -> None:
    """Run ``todo`` (on ``client``, a ``LocalCluster`` of ``local`` workers, or here), writing each
    draw's entry to ``runs/seed_<S>.json`` and into ``done``."""
    with ExitStack() as stack:
        outcomes: Iterable[Outcome] = ()
        if todo and in_process:
            outcomes = run_here(task, [replace(t, progress=progress) for t in todo])
        elif todo:
            client = client if client is not None else stack.enter_context(dask_client(None, local))
            outcomes = stack.enter_context(closing(run_on_dask(task, todo, client)))
        bar = stack.enter_context(
            tqdm(total=runs, initial=len(done), desc="runs", unit="draw", disable=not progress)
        )
        for finished, entry in outcomes:
            write_text_atomic(
                out / RUNS_FOLDER / f"seed_{finished.seed}.json", json.dumps(entry, indent=2) + "\n"
            )
            done[finished.seed] = entry
            bar.set_postfix_str(f"seed {finished.seed}")
            bar.update(1)


def local_workers(runs: int, workers: int | None, scheduler: str | None) -> int | None:
    """The worker processes a sweep starts on this machine: ``--workers`` (default the CPU count),
    no more than ``runs``; None with ``--scheduler``. A ConfigError for both, or for more workers than
    half the memory available holds (:func:`capsule_mpc.budget.check_processes`)."""
    if scheduler is not None:
        if workers is not None:
            raise ConfigError("--workers: not with --scheduler (the cluster's workers are its own)")
        return None
    local = min(workers or os.cpu_count() or 1, runs)
    check_processes(local)
    return local


def sweep_failures(summary: Mapping[str, Any]) -> list[str]:
    """What failed in a sweep: each crashed run, and each controller that failed on a seed."""
    failures = []
    for entry in summary["runs"]:
        if "crashed" in entry:
            failures.append(f"run of seed {entry['seed']} crashed: {entry['crashed']}")
            continue
        for name, result in entry["controllers"].items():
            if "error" in result:
                failures.append(f"controller {name!r} failed (seed {entry['seed']}): {result['error']}")
    return failures


def run_sweep(
    config: str | Path | None,
    out: str | Path,
    runs: int,
    controllers: Sequence[str] | None = None,
    *,
    waypoints: str | Path | None = None,
    speed: float | None = None,
    plant: str | None = None,
    seed: int | None = None,
    vary: Sequence[VaryRange] = (),
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
) -> int:
    """``capsule-mpc sweep`` (its options are the arguments): check the input (a ConfigError before
    anything is written), run :func:`sweep` into ``out`` (resuming the one there), print its table,
    its worst runs and what failed; the exit status, 0 or 1 (a controller failed or a run crashed)."""
    names = check_controllers(controllers)
    local = local_workers(runs, workers, scheduler)
    work = replace(run_figures(names, 1), processes=local) if local else Workload(runs=0)
    scenario, path, meta = prepare_run(config, waypoints, speed, plant, work)
    check_vary(scenario, vary)
    seed = scenario.sim.seed if seed is None else seed
    resume = check_resume(out, sweep_spec(scenario, path, seed, runs, names, vary))
    if resume:
        done = len(finished_runs(Path(out), [seed + k for k in range(runs)]))
        print(f"capsule-mpc sweep: resuming the sweep in {out}: {done} of {runs} runs done")
    inputs = {"--config": config, "--waypoints": waypoints}  # the folder must not hold them
    with ExitStack() as stack:
        client = stack.enter_context(dask_client(scheduler, None)) if scheduler else None
        folder = stack.enter_context(
            output_folder(out, "sweep", replace_previous=not resume, resume=resume, inputs=inputs)
        )
        summary = sweep(
            scenario,
            path,
            folder.path,
            seed,
            runs,
            controllers=names,
            vary=vary,
            workers=local,
            client=client,
            meta=meta,
            progress=progress,
        )
        failures = sweep_failures(summary)
        folder.status = 1 if failures else 0
    print(summary_table(summary["controllers"], runs), end="")
    print(worst_table(summary["worst"]), end="")
    for failure in failures:
        print(f"capsule-mpc sweep: {failure}", file=sys.stderr)
    print(f"results in {Path(out).resolve()} (summary.json, summary.md, *.png, {RUNS_FOLDER}/seed_<S>.json)")
    return folder.status


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
    workers: int | None = None,
    client: Client | None = None,
    task: Callable[[SeedTask], dict[str, Any]] = run_seed,
) -> dict[str, Any]:
    """Run controllers on the same plant, path and seeds (:mod:`capsule_mpc.experiments.compare`):
    :func:`sweep` with ``command="compare"``, its parameters; the summary."""
    return sweep(
        scenario, path, out, seed, runs, controllers=controllers, workers=workers, client=client, meta=meta,
        progress=progress, task=task, command="compare",
    )  # fmt: skip
